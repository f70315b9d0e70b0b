#!/bin/sh
# Usage: gl-libs.sh DIR  (in a throw-away build stage of docker/Dockerfile, as root)
#
# dartpy's bundled libraries link two system libraries that python:*-slim lacks, libGL.so.1 and
# libX11.so.6: without them `import dartpy` fails (ImportError: libGL.so.1). The sim never draws, so
# only what the dynamic linker needs is kept: this installs Debian's libgl1 and libx11-6, then copies
# into DIR, under their sonames, the libraries of the two closures that the base image did not have.
# Mesa's drivers, which libgl1 depends on (LLVM among them, ~170 MB), are left behind in this stage.
set -eu
out=$1
mkdir -p "$out"
dpkg-query -W -f '${Package}\n' | sed 's/:.*//' | sort -u >/tmp/base-packages
apt-get update -qq
DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends libgl1 libx11-6 >/dev/null
roots=$(ldconfig -p | awk '$1 == "libGL.so.1" || $1 == "libX11.so.6" { print $NF }')
[ "$(echo "$roots" | wc -l)" = 2 ] || { echo "gl-libs.sh: libGL.so.1 or libX11.so.6 not found" >&2; exit 1; }
# Each library: "soname path" for the two roots and everything they link.
{ for r in $roots; do echo "$(basename "$r") $r"; done
  ldd $roots | awk '$2 == "=>" && $3 ~ /^\// { print $1, $3 }'; } | sort -u |
while read -r soname path; do
  real=$(readlink -f "$path")
  pkg=
  for p in "$path" "$real" "${real#/usr}" "/usr$path"; do  # dpkg knows a file by one path (merged /usr)
    pkg=$(dpkg -S "$p" 2>/dev/null | head -1 | cut -d: -f1) && [ -n "$pkg" ] && break
  done
  [ -n "$pkg" ] || { echo "gl-libs.sh: no package owns $path" >&2; exit 1; }
  grep -qx "$pkg" /tmp/base-packages && continue  # the base image has it already
  cp -L "$path" "$out/$soname"
  echo "gl-libs.sh: $soname ($pkg)"
done
