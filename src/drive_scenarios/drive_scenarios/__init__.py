"""Scenarios: the schema of a scenario file (motor, estimator, speed and load tables, duration, sampling
period, non-idealities), the shipped scenarios, and how a node takes a scenario as ROS parameters."""
