"""Cascade FOC core (speed PI, d/q current PIs, voltage limiting), PI tuning (no rclpy), and the
controller node."""
