"""`python -m cdpr_recorder SCENARIO [options]`: the recorder node as its own process (as `cdpr recorder`)."""

from cdpr.runtime.main import node_main

if __name__ == "__main__":
    node_main("recorder")
