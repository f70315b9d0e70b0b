"""`python -m cdpr_controller SCENARIO [options]`: the controller node as its own process (as `cdpr controller`)."""

from cdpr.runtime.main import node_main

if __name__ == "__main__":
    node_main("controller")
