"""`python -m cdpr_controller SCENARIO [--connect ...]`: the same as `cdpr controller`."""

from cdpr.cli import service_main

if __name__ == "__main__":
    service_main("controller")
