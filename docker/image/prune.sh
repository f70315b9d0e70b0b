#!/bin/sh
# Usage: prune.sh VENV [--no-viewer]   (docker/Dockerfile, once cdpr is installed in VENV)
#
# Removes from an image's virtualenv what no service runs: pip, setuptools and wheel (nothing is
# installed later), the packages' own test suites, C/C++ headers and Cython sources, and with
# --no-viewer the Rerun viewer binary that rerun-sdk ships (280 MB: the recorder writes files and
# `cdpr report` reads them; `cdpr replay` opens them in a viewer on a desktop, outside the container).
set -eu
venv=$1
site=$(echo "$venv"/lib/python3*/site-packages)
[ -d "$site" ] || { echo "prune.sh: no site-packages in $venv" >&2; exit 1; }
"$venv/bin/python" -m pip uninstall -y -q pip setuptools wheel 2>/dev/null || true
find "$site" -depth -type d -name tests -exec rm -rf {} +
find "$site" -type f \( -name '*.h' -o -name '*.hpp' -o -name '*.pyx' -o -name '*.pxd' -o -name '*.pxi' \) -delete
rm -rf "$site"/pyarrow/include "$site"/pyarrow/_pyarrow_cpp_tests.*
if [ "${2:-}" = --no-viewer ]; then
  rm -f "$site"/rerun_cli/rerun
fi
find "$site" -depth -type d -empty -delete
echo "prune.sh: $venv now $(du -sm "$venv" | cut -f1) MB"
