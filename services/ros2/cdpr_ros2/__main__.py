"""`python -m cdpr_ros2 SCENARIO [options]`: the ros2 node as its own process (as `cdpr ros2`)."""

from cdpr.runtime.main import node_main

if __name__ == "__main__":
    node_main("ros2")
