"""Importing this module registers every estimator core."""
from . import injection_frame, sensored, szabo, wang  # noqa: F401
from .interface import describe, estimator_names, make_estimator  # noqa: F401

DEFAULT_ESTIMATOR = "injection_frame"
