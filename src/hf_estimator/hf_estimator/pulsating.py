"""What the papers' pulsating-injection estimators share: their state record, the q̂-axis demodulation,
and the step after demodulation (tracking loop, admittance monitor, next injection)."""
import numpy as np
from numba import njit

from drive_common.math.filters import sos_step
from drive_common.math.frames import rotate

from .admittance_monitor import MONITOR, monitor_step
from .startup import fresh_startup
from .startup_state import STARTUP
from .tracking_loop import pi_tracking_loop

MAX_SECTIONS = 8
"""Second-order sections a filter of the papers' estimators may have (order 8: interface's checks)."""
PULSATING = np.dtype([("theta", np.float64), ("omega", np.float64), ("monitor", MONITOR), ("startup", STARTUP),
                      ("filters", np.float64, (2, MAX_SECTIONS, 2))])
"""A pulsating-injection estimator's state: θ̂ [rad], the PI integrator ω̂ [rad/s], the admittance
monitor's, the start-up's, and the two filters' section states (band-pass or α low-pass, low-pass or β
low-pass; their first sections used)."""


def pulsating_state():
    """Fresh state (θ̂ = 0, ω̂ = 0, aligning) of a pulsating-injection estimator (PULSATING)."""
    state = np.zeros(1, PULSATING)
    fresh_startup(state[0]["startup"])
    return state


@njit(cache=True, _nrt=False)
def q_axis_demodulation(z, bandpass, lowpass, i_alpha, i_beta, theta, amplitude, carrier):
    """The q̂-axis demodulation of Wang §II (Eq. 8-11) and Szabó §2.3 (Eq. 15-21): î_q in the θ̂ frame →
    band-pass (filter state z[0]) → × amplitude·carrier → low-pass (z[1])."""
    _, i_q = rotate(i_alpha, i_beta, -theta)
    return sos_step(lowpass, z[1], sos_step(bandpass, z[0], i_q) * amplitude * carrier)


@njit(cache=True, _nrt=False)
def pulsating_track_and_inject(x, p, k, i_alpha_beta_A, carrier, error):
    """What the papers' methods do after demodulating ε: the PI tracking loop (p.kp, p.ki, p.T_s_s), the HF
    admittance monitor (p.monitor) on the measured currents (α, β) [A], and the next injection
    p.injection_amplitude_V·carrier along the new d̂ (Wang Eq. 7, Szabó Eq. 6).
    Returns (ω_PI, u_inj_α, u_inj_β, signal, observable)."""
    i_alpha, i_beta = i_alpha_beta_A
    omega = pi_tracking_loop(x, p.kp, p.ki, p.T_s_s, error)
    signal, observable = monitor_step(x.monitor, p.monitor, k, i_alpha, i_beta, carrier, x.theta)
    u_alpha, u_beta = rotate(p.injection_amplitude_V * carrier, 0.0, x.theta)
    return omega, u_alpha, u_beta, signal, observable
