"""Numba kernels shared by the drive's cores: reference frames, digital filters, the PI regulator and table
lookup (no rclpy)."""
