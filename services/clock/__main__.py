"""`python -m cdpr_clock SCENARIO [--connect ...]`: the same as `cdpr clock`."""

from cdpr.cli import service_main

if __name__ == "__main__":
    service_main("clock")
