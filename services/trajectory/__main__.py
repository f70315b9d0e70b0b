"""`python -m cdpr_trajectory SCENARIO [--connect ...]`: the same as `cdpr trajectory`."""

from cdpr.cli import service_main

if __name__ == "__main__":
    service_main("trajectory")
