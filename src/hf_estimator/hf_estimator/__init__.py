"""Rotor angle estimators by HF injection (the papers' methods and ours) and a sensored pass-through as
numba cores, their PLL models and tuning (no rclpy), and the estimator node."""
from drive_common.contract import numba_records  # noqa: F401  (its kernels take records: cached safely)
