"""`python -m cdpr_clock SCENARIO [options]`: the clock node as its own process (as `cdpr clock`)."""

from cdpr.runtime.main import node_main

if __name__ == "__main__":
    node_main("clock")
