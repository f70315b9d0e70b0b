#!/bin/sh
# Usage: cdpr-health listening|joined [PORT]   (compose.yaml's healthchecks; PORT defaults to 7447)
#
#   listening  the router: healthy once it accepts connections on PORT
#   joined     a session service: healthy while it holds a connection to the router's PORT, i.e. it has
#              joined the session (a service that cannot reach the router, or is still starting, is not)
#
# Reads the container's own TCP table (/proc/net/tcp, tcp6): no Zenoh session, no Python, ~1 ms.
set -eu
port=$(printf ':%04X' "${2:-7447}")
case "${1:-}" in
  listening) field=2 state=0A ;;  # local address ends with :PORT, state LISTEN
  joined) field=3 state=01 ;;     # remote address ends with :PORT, state ESTABLISHED
  *) echo "usage: cdpr-health listening|joined [PORT]" >&2; exit 2 ;;
esac
if cat /proc/net/tcp /proc/net/tcp6 2>/dev/null |
   awk -v f="$field" -v p="$port" -v s="$state" 'substr($f, length($f) - 4) == p && $4 == s { ok = 1 } END { exit !ok }'
then
  echo "$1 on port ${2:-7447}"
else
  echo "not $1 on port ${2:-7447}"; exit 1
fi
