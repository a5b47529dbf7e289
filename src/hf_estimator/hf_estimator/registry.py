"""Importing this module registers every estimator core."""
from . import conventional, flux_observer, full_speed, improved, injection_frame, sensored, synchronous  # noqa: F401
from .interface import describe, estimator_names, known_estimator, make_estimator, plugin_errors  # noqa: F401
