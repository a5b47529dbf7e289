"""The PI tracking loop every saliency tracker closes on its error signal, ours' type-3 extension of it, and
their gain rules."""
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


ACCELERATION_POLE_RATIO = 0.5
"""The type-3 loop's third pole, real, at this share of ω_n (injection_frame item 6)."""


@njit(cache=True)
def tracking_loop(x, kp, ki, ka, T_s, error):
    """pi_tracking_loop on ``error`` [rad], with an acceleration integrator ahead of its speed integrator where
    ``ka`` ≠ 0 (type 3; x.acceleration [rad/s²]): s³ + k_p s² + k_i s + k_a. Returns ω_PI."""
    if ka != 0.0:
        x.acceleration += T_s * ka * error
        x.omega += T_s * x.acceleration
    return pi_tracking_loop(x, kp, ki, T_s, error)


def unit_slope_gains(bandwidth_Hz, damping, loop_type):
    """(k_p, k_i, k_a) of tracking_loop on an error of unit slope: type 2 at ω_n = 2π·bandwidth, ζ (k_a = 0);
    type 3 with its third pole p = ACCELERATION_POLE_RATIO·ω_n: (s + p)(s² + 2ζω_n s + ω_n²)."""
    omega_n = 2.0 * math.pi * bandwidth_Hz
    pole = ACCELERATION_POLE_RATIO * omega_n if loop_type == 3 else 0.0
    return (2.0 * damping * omega_n + pole, omega_n ** 2 + 2.0 * damping * omega_n * pole, pole * omega_n ** 2)


def loop_gains(gain_per_rad, bandwidth_Hz, damping):
    """PI gains (k_p, k_i) placing the linearised loop ε = g·(θ − θ̂) at ω_n = 2π·bandwidth, ζ:
    s² + g k_p s + g k_i (Wang Eq. 24 with k_h = g)."""
    omega_n = 2.0 * math.pi * bandwidth_Hz
    return 2.0 * damping * omega_n / gain_per_rad, omega_n ** 2 / gain_per_rad
