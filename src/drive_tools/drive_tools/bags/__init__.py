"""Recordings: rosbag2 directories with MCAP storage, written from the graph or the runner, read back,
and rebuilt when cut (imports neither the runner nor the estimators)."""
