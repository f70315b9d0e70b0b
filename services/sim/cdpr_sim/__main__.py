"""`python -m cdpr_sim SCENARIO [options]`: the sim node as its own process (as `cdpr sim`)."""

from cdpr.runtime.main import node_main

if __name__ == "__main__":
    node_main("sim")
