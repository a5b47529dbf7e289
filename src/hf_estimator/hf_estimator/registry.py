"""Importing this module registers every estimator core."""
from . import (  # noqa: F401
    conventional,
    flux_observer,
    full_speed,
    if_observer,
    improved,
    injection_frame,
    sensored,
    square_wave,
    synchronous,
)
from .interface import describe, estimator_names, known_estimator, make_estimator, plugin_errors  # noqa: F401
