"""The estimates the commissioning procedure makes from its recorded samples (docs/commissioning.md §2):
sensor offsets and relative gains, R_s and the dead-time voltage from DC points, and the incremental
admittance Γ from HF current steps. Plain numpy: it runs once per segment."""
import math

import numpy as np

from drive_common.math.dead_time import dead_time_direction


def relative_gains(readings):
    """Relative gains (mean 1) of three current sensors from offset-free readings at DC points
    (n × 3, n ≥ 2 with independent current directions): the true phase currents sum to zero, so
    Σ_x m_x / g_x = 0 at every point; solved for 1/g_b, 1/g_c with 1/g_a = 1 by least squares."""
    m = np.asarray(readings, dtype=float)
    weights, *_ = np.linalg.lstsq(m[:, 1:], -m[:, 0], rcond=None)
    gains = 1.0 / np.array([1.0, weights[0], weights[1]])
    return gains / gains.mean()


def resistance_and_dead_time(currents_ab, commands_ab, phase_currents):
    """(R_s [Ω], dead-time voltage per phase [V]) from steady DC points: the mean command balances the
    resistive drop and the dead-time voltage, u = R·i + V_dt·K(i) (K: dead_time_direction), fitted by
    least squares over both components of every point (K: drive_common.math.dead_time), V_dt ≥ 0 (a loss:
    where the free fit gives less, an inverter with no dead time measured within its noise, V_dt is 0 and R
    is fitted alone). currents_ab, commands_ab: n × 2; phase_currents: n × 3 (for the signs)."""
    i = np.asarray(currents_ab, dtype=float)
    k_a, k_b = dead_time_direction.py_func(*np.asarray(phase_currents, dtype=float).T, 0.0)
    design = np.vstack([np.column_stack([i[:, 0], k_a]), np.column_stack([i[:, 1], k_b])])
    u = np.asarray(commands_ab, dtype=float)
    commands = np.concatenate([u[:, 0], u[:, 1]])
    (R, V), *_ = np.linalg.lstsq(design, commands, rcond=None)
    if V < 0.0:
        (R,), *_ = np.linalg.lstsq(design[:, :1], commands, rcond=None)
        V = 0.0
    return float(R), float(V)


def admittance(currents_ab, applied_ab, R_s_ohm, T_s):
    """Incremental admittance Γ = ∂i/∂ψ (2 × 2 symmetric, stationary frame) [1/H] from HF current steps:
    i[k] − i[k−1] = T_s·Γ·(u[k] − R·½(i[k] + i[k−1])) + r, with u[k] the voltage applied during that
    period and r a constant drift (back-EMF, offsets). Fitted summed up: i[k] = i[0] + Γ·ψ[k] + r·k with
    ψ[k] = T_s·Σ(u − R·ī), so the sensor noise enters once per sample instead of differenced (a fifth of
    the variance at 10 samples per carrier period). currents_ab: (n + 1) × 2 samples; applied_ab: n × 2
    (the commands less the dead-time voltage)."""
    i = np.asarray(currents_ab, dtype=float)
    v = T_s * (np.asarray(applied_ab, dtype=float) - R_s_ohm * 0.5 * (i[1:] + i[:-1]))
    psi = np.cumsum(v, axis=0)
    n = psi.shape[0]
    zero, one, ramp = np.zeros(n), np.ones(n), np.arange(1.0, n + 1.0)
    design = np.vstack([np.column_stack([psi[:, 0], zero, psi[:, 1], one, zero, ramp, zero]),
                        np.column_stack([zero, psi[:, 1], psi[:, 0], zero, one, zero, ramp])])
    solution, *_ = np.linalg.lstsq(design, np.concatenate([i[1:, 0], i[1:, 1]]), rcond=None)
    g_aa, g_bb, g_ab = solution[:3]
    return np.array([[g_aa, g_ab], [g_ab, g_bb]])


def in_frame(gamma, angle):
    """Γ seen in the frame turned by ``angle`` [rad]: (g_dd, g_qq, g_dq)."""
    c, s = math.cos(angle), math.sin(angle)
    rotation = np.array([[c, -s], [s, c]])
    g = rotation.T @ gamma @ rotation
    return g[0, 0], g[1, 1], g[0, 1]


def saliency_axis(gamma):
    """The angle [rad] of Γ's larger eigenvalue's axis (the smaller inductance: the d axis of a PMSM),
    modulo π, and the inductances (1/larger, 1/smaller eigenvalue) [H]."""
    g_aa, g_bb, g_ab = gamma[0, 0], gamma[1, 1], gamma[0, 1]
    half_difference = math.hypot(0.5 * (g_aa - g_bb), g_ab)
    mean = 0.5 * (g_aa + g_bb)
    return 0.5 * math.atan2(2.0 * g_ab, g_aa - g_bb), 1.0 / (mean + half_difference), 1.0 / (mean - half_difference)


def saliency_ratio_of(gamma):
    """|Δ|/Σ of an admittance Γ: half the difference of its eigenvalues over their mean (any frame)."""
    return math.hypot(0.5 * (gamma[0, 0] - gamma[1, 1]), gamma[0, 1]) / (0.5 * (gamma[0, 0] + gamma[1, 1]))


def axis_shift(gamma, d_axis, saliency_sign=1.0):
    """The saliency axis's angle from ``d_axis`` [rad]: ½·atan2(2s·g_dq, s·(g_dd − g_qq)) in that frame,
    s = ``saliency_sign`` (+1 where the d axis has the larger admittance, −1 where L_dh > L_qh)."""
    g_dd, g_qq, g_dq = in_frame(gamma, d_axis)
    return 0.5 * math.atan2(2.0 * saliency_sign * g_dq, saliency_sign * (g_dd - g_qq))


SURFACE_Q_ORDERS = (1, 3, 5)
SURFACE_D_ORDERS = (0, 1, 2)


def _surface_basis(i_d, i_q):
    i_d, i_q = np.atleast_1d(np.asarray(i_d, dtype=float)), np.atleast_1d(np.asarray(i_q, dtype=float))
    return np.column_stack([np.ones_like(i_q)] + [i_q ** m * i_d ** n for m in SURFACE_Q_ORDERS
                                                  for n in SURFACE_D_ORDERS])


def saliency_surface(i_d_A, i_q_A, shifts_rad):
    """Least-squares fit of the measured saliency-axis angles over the test grid by
    δ(i_d, i_q) = c + i_q·P(i_d, i_q²), P quadratic in i_d and in i_q² (odd in i_q: the rotor is symmetric
    about its d axis; c the d-axis error of the frame measured in). Returns (δ at (0, i_q) − c, the
    convergence slope 1 + i_q·∂δ/∂i_d at (0, i_q), the fit's residual RMS [rad]) as functions of i_q."""
    basis = _surface_basis(i_d_A, i_q_A)
    coefficients, *_ = np.linalg.lstsq(basis, np.asarray(shifts_rad, dtype=float), rcond=None)
    residual = float(np.sqrt(np.mean((basis @ coefficients - shifts_rad) ** 2)))

    def shift(i_q):
        return _surface_basis(np.zeros_like(i_q), i_q) @ coefficients - coefficients[0]

    def slope(i_q, step=1e-3):
        i_q = np.asarray(i_q, dtype=float)
        return 1.0 + i_q * (_surface_basis(np.full_like(i_q, step), i_q) @ coefficients
                            - _surface_basis(np.full_like(i_q, -step), i_q) @ coefficients) / (2.0 * step)
    return shift, slope, residual
