"""The recorder service: subscribes to a whole session and logs it to Rerun (.rrd file and/or viewer)."""
