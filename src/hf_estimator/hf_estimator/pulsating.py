"""What the papers' pulsating-injection estimators share: their state layout, the q̂-axis demodulation,
and the step after demodulation (tracking loop, admittance monitor, next injection)."""
import numpy as np
from numba import njit

from control_math.filters import sos_step
from control_math.frames import rotate

from .admittance_monitor import monitor_size, monitor_step
from .startup import startup_reset, startup_size
from .tracking_loop import pi_tracking_loop

# State layout of the papers' pulsating-injection estimators: θ̂, the PI integrator, the monitor, then
# the start-up state (startup.py).
THETA, INTEGRAL, MONITOR = 0, 1, 2


def startup_base(monitor):
    """Where the start-up state begins in a pulsating-injection estimator's x."""
    return MONITOR + monitor_size(monitor)


def pulsating_state(monitor, startup):
    """Fresh state (θ̂ = 0, ω̂ = 0, aligning) for a pulsating-injection estimator with monitor parameters
    ``monitor`` and start-up parameters ``startup``."""
    x = np.zeros(startup_base(monitor) + startup_size(startup))
    startup_reset(x, startup)
    return x


@njit(cache=True)
def q_axis_demodulation(z, bandpass, lowpass, i_alpha, i_beta, theta, amplitude, carrier):
    """The q̂-axis demodulation of Wang §II (Eq. 8-11) and Szabó §2.3 (Eq. 15-21): î_q in the θ̂ frame →
    band-pass (state z[0]) → × amplitude·carrier → low-pass (state z[1])."""
    _, i_q = rotate(i_alpha, i_beta, -theta)
    return sos_step(lowpass, z[1], sos_step(bandpass, z[0], i_q) * amplitude * carrier)


@njit(cache=True)
def pulsating_track_and_inject(x, monitor, k, i_alpha, i_beta, carrier, injection_amplitude_V, kp, ki, T_s,
                               error):
    """What the papers' methods do after demodulating ε: the PI tracking loop, the HF admittance
    monitor, and the next injection U_h·carrier along the new d̂ (Wang Eq. 7, Szabó Eq. 6).
    Returns (ω_PI, u_inj_α, u_inj_β, signal, observable)."""
    omega = pi_tracking_loop(x, THETA, INTEGRAL, kp, ki, T_s, error)
    signal, observable = monitor_step(x, MONITOR, monitor, k, i_alpha, i_beta, carrier, x[THETA])
    u_alpha, u_beta = rotate(injection_amplitude_V * carrier, 0.0, x[THETA])
    return omega, u_alpha, u_beta, signal, observable
