"""Composition of the cores: the one-process runner, scenarios, metrics, benchmarks and the CLI."""
