"""Rotor angle estimators (HF-injection and a sensored pass-through) as numba cores (no rclpy)."""
