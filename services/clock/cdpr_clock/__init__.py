"""The lock-step clock service: the only thing that advances simulated time."""
