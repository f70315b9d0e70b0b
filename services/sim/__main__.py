"""`python -m cdpr_sim SCENARIO [--connect ...]`: the same as `cdpr sim`."""

from cdpr.cli import service_main

if __name__ == "__main__":
    service_main("sim")
