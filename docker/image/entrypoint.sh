#!/bin/sh
# The recorder's and the study driver's entrypoint: `cdpr ARGS`, run as the owner of /recordings (or of
# $CDPR_OWNED_DIR: the study driver's /runs).
#
# /recordings is a host folder (compose.yaml: $CDPR_RECORDINGS): the recorder runs as the user who owns
# it, so that the recordings it writes there belong to that user on the host (a folder made with
# `mkdir runs` by you: you; one Docker made because it was missing: root). Without a mounted folder, or
# when the container is started as another user than root, it runs as it was started.
set -eu
dir=${CDPR_OWNED_DIR:-/recordings}
if [ "$(id -u)" = 0 ] && [ -d "$dir" ]; then
  uid=$(stat -c %u "$dir") gid=$(stat -c %g "$dir")
  if [ "$uid" != 0 ]; then
    export HOME=/tmp  # the folder's owner has no home in the image (matplotlib's cache, if any)
    exec setpriv --reuid="$uid" --regid="$gid" --clear-groups cdpr "$@"
  fi
fi
exec cdpr "$@"
