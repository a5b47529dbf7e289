"""Cascade FOC core (speed PI, d/q current PIs, voltage limiting) and PI tuning (no rclpy)."""
