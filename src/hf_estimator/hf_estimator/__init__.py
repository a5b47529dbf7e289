"""Rotor angle estimators by HF injection (the papers' methods and ours) and a sensored pass-through as
numba cores, their PLL models and tuning (no rclpy), and the estimator node."""
