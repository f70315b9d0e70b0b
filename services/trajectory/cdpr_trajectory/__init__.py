"""The trajectory service: publishes the desired pose, twist and acceleration for every tick."""
