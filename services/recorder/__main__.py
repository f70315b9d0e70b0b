"""`python -m cdpr_recorder SCENARIO --rrd FILE [--spawn] [--connect-viewer URL]`: as `cdpr recorder`."""

from cdpr.cli import service_main

if __name__ == "__main__":
    service_main("recorder")
