"""``python -m cdpr.runtime NAME SCENARIO [options]``: any registered node as its own process (``NAME+NAME…``:
several sharing it, :func:`cdpr.runtime.main.node_main`)."""

import sys

from cdpr.runtime.main import node_main

if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1].startswith("-"):
        print("usage: python -m cdpr.runtime NAME[+NAME...] SCENARIO [options]  (NAME: a registered node)",
              file=sys.stderr)
        sys.exit(2)
    node_main(sys.argv[1], sys.argv[2:])
