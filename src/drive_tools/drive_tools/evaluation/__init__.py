"""Evaluating the drive: run metrics and plots, replay and comparison of recordings, benchmarks, and the
closed-loop check of a tuned PLL."""
