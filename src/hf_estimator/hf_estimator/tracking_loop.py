"""The PI tracking loop every saliency tracker closes on its error signal, and its gain rule."""
import math

from numba import njit


@njit(cache=True)
def pi_tracking_loop(x, kp, ki, T_s, error):
    """PI + integrator (Wang Fig. 6, Szabó Fig. 3): ω_PI = k_p ε + ∫k_i ε, θ̂ = ∫ω_PI, in the estimator
    state x (θ̂ its ``theta``, the integrator its ``omega``).

    Returns ω_PI; the integrator x.omega is the smoother speed estimate. Which one an
    estimator hands the speed loop is its choice: the proportional part carries the demodulation ripple
    (hundreds of rad/s behind a 300 Hz low-pass), which fed to the speed loop and the back-EMF
    decoupling closes an unstable loop through the estimator (docs/hf-demodulation.md §3)."""
    x.omega += T_s * ki * error
    omega = kp * error + x.omega
    x.theta += T_s * omega
    return omega


def loop_gains(gain_per_rad, bandwidth_Hz, damping):
    """PI gains (k_p, k_i) placing the linearised loop ε = g·(θ − θ̂) at ω_n = 2π·bandwidth, ζ:
    s² + g k_p s + g k_i (Wang Eq. 24 with k_h = g)."""
    omega_n = 2.0 * math.pi * bandwidth_Hz
    return 2.0 * damping * omega_n / gain_per_rad, omega_n ** 2 / gain_per_rad
