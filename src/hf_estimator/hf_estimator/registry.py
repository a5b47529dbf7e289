"""Importing this module registers every estimator core."""
from . import sensored  # noqa: F401
from .interface import describe, estimator_names, make_estimator  # noqa: F401
