"""`python -m cdpr_trajectory SCENARIO [options]`: the trajectory node as its own process (as `cdpr trajectory`)."""

from cdpr.runtime.main import node_main

if __name__ == "__main__":
    node_main("trajectory")
