#!/bin/sh
# The recorder image's entrypoint: `cdpr ARGS`, run as the owner of /recordings.
#
# /recordings is a host folder (compose.yaml: $CDPR_RECORDINGS): the recorder runs as the user who owns
# it, so that the recordings it writes there belong to that user on the host (a folder made with
# `mkdir runs` by you: you; one Docker made because it was missing: root). Without a mounted folder, or
# when the container is started as another user than root, it runs as it was started.
set -eu
if [ "$(id -u)" = 0 ] && [ -d /recordings ]; then
  uid=$(stat -c %u /recordings) gid=$(stat -c %g /recordings)
  if [ "$uid" != 0 ]; then
    export HOME=/tmp  # the folder's owner has no home in the image (matplotlib's cache, if any)
    exec setpriv --reuid="$uid" --regid="$gid" --clear-groups cdpr "$@"
  fi
fi
exec cdpr "$@"
