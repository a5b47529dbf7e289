"""PI tuning by closed-loop natural frequency and damping (the cut-off/damping method of Szabó ref. [16]).

Current loop: the PI k_p + k_i/s around the R-L axis 1/(L s + R) gives the closed-loop polynomial
L s² + (R + k_p) s + k_i, so for poles at ω_n, ζ:  k_p = 2 ζ ω_n L − R,  k_i = ω_n² L.
Speed loop: the PI around the rigid shaft k_t/(J s + B), with the current loop taken as ideal, gives
J s² + (B + k_p k_t) s + k_i k_t:  k_p = (2 ζ ω_n J − B)/k_t,  k_i = ω_n² J / k_t, with k_t = 1.5 p ψ_f.
Both need the inner loop several times faster than the outer one. Below ω_n = R/(2ζL) the current rule
has no positive k_p; there the internal-model rule k_p = ω_b L, k_i = ω_b R (the PI zero cancels the
axis pole, leaving a first-order loop of bandwidth ω_b) takes over.
"""
from typing import NamedTuple


class PIGains(NamedTuple):
    kp: float
    ki: float


def current_pi_gains(L_H, R_s_ohm, omega_n_rad_s, zeta):
    """Current PI gains [V/A, V/(A·s)] for closed-loop poles ω_n, ζ."""
    kp = 2.0 * zeta * omega_n_rad_s * L_H - R_s_ohm
    if kp <= 0.0:
        raise ValueError(f"current bandwidth {omega_n_rad_s} rad/s too low for L={L_H} H, R={R_s_ohm} Ω")
    return PIGains(kp, omega_n_rad_s ** 2 * L_H)


def current_pi_gains_any_bandwidth(L_H, R_s_ohm, omega_n_rad_s, zeta):
    """``current_pi_gains``, or the internal-model gains at ω_b = ω_n where that rule has no positive k_p
    (the slow current loops of large blocks: docs/architecture.md "Block transport")."""
    if 2.0 * zeta * omega_n_rad_s * L_H > R_s_ohm:
        return current_pi_gains(L_H, R_s_ohm, omega_n_rad_s, zeta)
    return PIGains(omega_n_rad_s * L_H, omega_n_rad_s * R_s_ohm)


def speed_pi_gains(J_kgm2, B_Nms, k_t_Nm_per_A, omega_n_rad_s, zeta):
    """Speed PI gains [A·s/rad, A/rad] (output: q-current reference) for poles ω_n, ζ."""
    kp = (2.0 * zeta * omega_n_rad_s * J_kgm2 - B_Nms) / k_t_Nm_per_A
    if kp <= 0.0:
        raise ValueError(f"speed bandwidth {omega_n_rad_s} rad/s too low for J={J_kgm2} kg·m²")
    return PIGains(kp, omega_n_rad_s ** 2 * J_kgm2 / k_t_Nm_per_A)


def current_bandwidth_damping(L_H, R_s_ohm, gains):
    """The (ω_n, ζ) that ``current_pi_gains`` maps to ``gains``: its inverse."""
    omega_n = (gains.ki / L_H) ** 0.5
    return omega_n, (gains.kp + R_s_ohm) / (2.0 * omega_n * L_H)


def speed_bandwidth_damping(J_kgm2, B_Nms, k_t_Nm_per_A, gains):
    """The (ω_n, ζ) that ``speed_pi_gains`` maps to ``gains``: its inverse."""
    omega_n = (gains.ki * k_t_Nm_per_A / J_kgm2) ** 0.5
    return omega_n, (gains.kp * k_t_Nm_per_A + B_Nms) / (2.0 * omega_n * J_kgm2)


def from_gain_and_integral_time(A_p, T_i_s):
    """Szabó Eq. (22), G_PI = A_p (1 + 1/(s T_i)), as parallel gains."""
    return PIGains(A_p, A_p / T_i_s)


SZABO_TABLE2 = {
    "d": from_gain_and_integral_time(11.49, 1.8e-3),
    "q": from_gain_and_integral_time(23.92, 4.2e-3),
    "speed": from_gain_and_integral_time(0.287, 36e-3),
}
"""Szabó & Veszprémi Table 2 cascade gains (current: V/A; speed: A·s/rad)."""
