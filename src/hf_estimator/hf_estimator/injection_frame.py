"""``injection_frame`` — our estimator: the incremental admittance identified from current steps in
the injection frame, with an alternating injection axis (docs/hf-demodulation.md §2-4 turned into a
design).

1. Carrier synchronous with sampling: c_k = cos(2πk/N), N = round(f_s/f_h) samples per period
   (900 Hz at 10 kHz becomes 909.1 Hz), injected along θ_axis ± δ (δ = π/8, sign alternating every
   carrier period), θ_axis = θ̂ + ω̂(d + ½)T_s predicted to the middle of the period in which the
   voltage is applied (d = computation delay).
2. Exact pairing, no carrier-phase error: the current step i[k] − i[k−1] answers the voltage applied
   during that period, i.e. the command issued d + 1 samples earlier. That whole voltage (fundamental +
   injection, from `voltage_command`) is known, so nothing of it leaks: Δi = T_s·Γ·(u − R̂·ī) + r,
   with ī the period's mean current (mean of its end samples) and r the slow back-EMF/offset drift.
   The resistive drop must be in the regressor: the current loop makes u follow i, so left in r it
   biases Γ̂ (under rated load and fast current-loop action the fit lost the angle without it). With
   the setting ``dead_time_model`` the commissioned dead-time voltage at the phase currents of the
   period's start (drive_common.math.dead_time) is subtracted too: where a phase current crosses zero the loss
   switches with the HF current and turns the measured axis, by up to its share of the saliency's share of the
   carrier voltage, U_h·|Δ|/Σ (dead_time_share). ``auto`` (the default) subtracts it wherever the commissioning
   measured it (docs/hf-demodulation.md §5).
3. In the frame θ_axis of each period, the last 2N samples (one + and one − carrier period) give a
   least-squares fit of Γ̂ = [[g_dd, g_dq], [g_dq, g_qq]] and r (intercepts removed by centring, a 3 × 3
   normal system). On a salient rotor Γ̂ = Σ·I + Δ·[[cos 2e, sin 2e], [sin 2e, −cos 2e]], e = θ − θ_axis:
   the Σ term stays on the diagonal (no Σ-term bias), e = ½ atan2(2s·g_dq, s·(g_dd − g_qq)) is measured
   in radians whatever the saliency (s = −1 where the commissioning found L_dh > L_qh), and
   |Δ̂| = ½ hypot(g_dd − g_qq, 2g_dq) against Σ̂ = ½(g_dd + g_qq) is a model-free observability measure.
   The ±δ axes make g_qq and g_dq identifiable.
3b. Any other excitation whose voltage is known (a recording's): where the window's voltage excites one
   axis φ only (a pulsating injection on another estimator's d̂), the admittance along φ, Σ + Δ cos 2(e − φ),
   cannot tell Σ from Δ; across φ it is Δ sin 2(e − φ), free of Σ. The same sums give both (with the
   commissioned Σ: (Δ cos 2e)·(aa + bb) = a·y₁ − b·y₂ − Σ(aa − bb), (Δ sin 2e)·(aa + bb) = b·y₁ + a·y₂ −
   2Σ·ab, y in units of T_s·U_h, turned by −2φ); e − φ is taken from the cross term and the commissioned
   |Δ| (the along term gives only the sign). An error in Σ taken along φ would pull e towards φ by its
   share of Δ (0.12 of the 0.1 rad offset of `improved`'s axis, measured); an error in |Δ| scales e − φ
   by its own share only. Replay uses this (docs/recordings.md).
4. Load turns the saliency axis (cross-saturation: 0.09 rad at rated current on `wang_spmsm`, 0.3 rad
   at 1.5× rated). The commissioned shift δ(i_q) is subtracted at the q current of the fit window
   (ε = e − δ(î_q), î_q low-passed in the θ̂ frame). Load also makes the axis turn back as the rotor
   turns under a still current vector, so ε moves by only F = 1 + i_q·∂δ/∂i_d per radian of angle
   error (0.91 at rated current, −0.2 at 1.5× rated: no angle information); the drive keeps the current
   where F ≥ ¾ (Commissioning.tracking_current_limit_A).
4b. Ours' own error under load, which the standstill tables do not hold (its fit on a flux map that curves
   over the HF ripple: 0.022 rad at rated current on a robot joint at 5 samples per carrier period), is
   measured by the optional loaded test (shaft held, hf_estimator.commissioning.loaded) and added to the shift
   table where ours runs the test's carrier and amplitude (loaded_correction).
5. The amplitude is the scenario's, raised where the commissioned motor needs it: a weak saliency gives a
   weak angle signal, the saliency current I_Δ = U_h·|Δ|/ω_h at no load or at rated current, whichever
   is smaller (|Δ| there from the commissioned |Δ|/Σ table: the q axis saturating under load takes some
   away), against the commissioned sensor noise σ.
   Below ``saliency_snr_min`` σ (8, at an 18 Hz loop; × √(bandwidth/18 Hz) for a wider one, whose noise
   grows so: a light rotor's loops scale up, docs/motors-and-control.md) the error grows faster than 1/I_Δ
   (noise and dead-time voltage near the phase currents' zero crossings), so U_h is raised to reach it,
   at most to HF_RIPPLE_MAX_PER_RATED
   of the rated current in HF ripple and HF_VOLTAGE_MAX_PER_LINEAR of the linear voltage range
   (docs/results.md, "A plant off its nameplate").
5b. Where the angle error predicted from the saliency current, the noise and the loop misses ours' targets,
   the drive refuses to run unless ``run_refused`` (hf_estimator.build, docs/hf-demodulation.md §5).
6. A type-2 loop (PI + integrator) on ε with ω_n, ζ placed directly (ε has unit slope); its integrator
   state is the speed handed to the speed loop (the proportional path stays out of it). While |Δ̂|/Σ̂ is
   below the threshold the loop is held (ε = 0) and the flag says so. A type-2 loop lags a constant
   acceleration a by a/ω_n² (0.1 rad at 4000 rpm/s on `szabo_ipmsm`); with ``pll_type`` 3 an acceleration
   integrator ahead of the speed integrator removes that lag: s³ + k_p s² + k_i s + k_a = (s + p)(s² +
   2ζω_n s + ω_n²), p = ACCELERATION_POLE_RATIO·ω_n (tracking_loop.py). Its acceleration is zero whenever ours is not
   tracking (start-up, hold): the estimate then coasts at constant speed. ``pll_type`` "auto"
   (tracking_loop_type) takes type 3 where the signal has the noise margin for it.
6b. ``injection_by_rule`` (the motor's own experiments set it): the loops' rule chooses the square wave in its
   place where it serves the motor (hf_estimator.build.chosen_estimator, square_wave.square_wave_serves).
7. Start-up (startup.py): while aligning, a fit that finds the axis further than ALIGN_JUMP_RAD away
   moves θ̂ onto it at once (ε is in radians) and the next fit waits for a window of fresh samples; the
   loop settles the rest. Ours aligns in a few carrier periods instead of the loop's settling time.
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.estimator_states import ALIGNING, TRACKING
from drive_common.math.dead_time import MIN_SMOOTHING_A, SMOOTHING_PER_RATED_CURRENT, net_of_dead_time
from drive_common.math.frames import clarke_contract, rotate
from drive_common.math.tables import table_value

from .interface import (
    MAX_CARRIER_SAMPLES,
    MAX_DELAY_PERIODS,
    Estimator,
    check_settings,
    register,
    ring_capacity,
    stator_resistance,
)
from .outputs import write_injecting_estimate
from .startup import DEFAULTS as STARTUP_DEFAULTS
from .startup import fresh_startup, make_startup, startup_code, startup_step
from .startup_state import STARTUP, StartupParams
from .tracking_loop import tracking_loop, unit_slope_gains

N_SUMS = 10
"""Sliding sums of the fit: a, b, y1, y2, aa, bb, ab, a·y1, b·y2, b·y1 + a·y2."""


INJECTION_FRAME = np.dtype([
    *[(name, np.float64) for name in ("theta", "omega", "prev_ia", "prev_ib", "count", "delta_smooth", "i_q_smooth",
                                      "acceleration")],
    ("sums", np.float64, N_SUMS), ("issued", np.float64, MAX_DELAY_PERIODS + 2),
    ("regressors", np.float64, (2 * MAX_CARRIER_SAMPLES, 4)), ("startup", STARTUP)])
"""Ours' state: θ̂ [rad], the loop's integrator ω̂ [rad/s], the previous currents (αβ) [A], the fit's sample
count, the smoothed |Δ̂| [1/H] and î_q [A], the type-3 loop's acceleration [rad/s²], the fit's sliding sums,
the ring of the injection axis issued in the last d + 2 samples, the regressor ring (a, b, y1, y2) of two
carrier periods (the rings' first entries used), and the start-up's."""


def injection_frame_state():
    """Fresh state of ours (θ̂ = 0, ω̂ = 0, aligning): INJECTION_FRAME."""
    state = np.zeros(1, INJECTION_FRAME)
    fresh_startup(state[0]["startup"])
    return state

DEFAULTS = {"frequency_Hz": 1000.0, "amplitude_V": 5.0, "dither_rad": math.pi / 8.0,
            "pll_bandwidth_Hz": 18.0, "pll_damping": 0.9, "observable_ratio": 0.02,
            "signal_smoothing_Hz": 20.0, "dead_time_model": "auto", "saliency_snr_min": 8.0, "pll_type": 2,
            "injection_by_rule": False, **STARTUP_DEFAULTS}
ALIGN_JUMP_RAD = 0.2
"""While aligning, a measured error beyond this (or 4 × the alignment tolerance) is jumped over at once
(well above one fit's noise). The commands of d + 1 samples are then still aimed at the old axis: the
next fit waits until at most half its window (N of 2N samples) holds them, or with the long delay of
blocks it would measure the old error again and jump twice."""
MIN_EXCITATION_SPREAD = 0.1
"""4 det/trace² of the fit window's voltage covariance (0: one axis excited, 1: both alike; ours' ±δ axes
give 0.5): below this the window cannot tell g_qq apart and Σ is taken from the commissioning (item 3b)."""
SNR_REFERENCE_HZ = 18.0
"""``saliency_snr_min`` holds for this tracking bandwidth; a wider loop passes more noise (its variance
grows with the bandwidth), so the wanted ratio grows as √(bandwidth / this)."""
HF_RIPPLE_MAX_PER_RATED = 0.5
"""The largest HF current ripple U_h·Σ/ω_h ours allows itself when it raises its amplitude, per rated
current (Wang's own reversal runs at 0.38)."""
HF_VOLTAGE_MAX_PER_LINEAR = 0.8
"""The largest amplitude ours raises itself to, per linear voltage range U_dc/√3 (the rest is the current
loop's at low speed)."""
LOADED_TEST_MATCH = 0.02
"""Ours adds the loaded test's correction where it runs within this share of the test's carrier and
amplitude (its error under load grows in proportion to the amplitude: docs/motors-and-control.md)."""


def loaded_correction(commissioning, frequency_Hz, injection_amplitude_V):
    """(ours' shift table [rad] over commissioning.saliency_shift_i_q_A, what ours says of it): the standstill
    shift plus the loaded test's correction (item 4b) where ours runs within LOADED_TEST_MATCH of the test's
    carrier and amplitude, else the standstill shift alone and a note saying why."""
    shift, correction = commissioning.saliency_shift_rad, commissioning.estimator_shift_rad
    if correction is None:
        return shift, ""
    tested_Hz, tested_V = commissioning.loaded_test_frequency_Hz, commissioning.loaded_test_amplitude_V
    if (abs(frequency_Hz / tested_Hz - 1.0) <= LOADED_TEST_MATCH
            and abs(injection_amplitude_V / tested_V - 1.0) <= LOADED_TEST_MATCH):
        return shift + correction, ""
    return shift, (f"the loaded test's correction left out: it was measured at {tested_Hz:.0f} Hz, {tested_V:.3g} V, "
                   f"ours runs at {frequency_Hz:.0f} Hz, {injection_amplitude_V:.3g} V (`drive commission --loaded` "
                   f"with this drive measures it again)")


def dead_time_share(commissioning, injection_amplitude_V):
    """The commissioned dead-time voltage over the saliency's share of the carrier voltage, u_dt·Σ/(U_h·|Δ|):
    how far the dead time's loss, switching with the HF current at the zero crossings, turns the measured axis
    against the saliency that sets it (0 where no dead-time voltage is known, ∞ where no saliency is)."""
    if commissioning.dead_time_voltage_V <= 0.0:
        return 0.0
    if commissioning.delta == 0.0:
        return math.inf
    return commissioning.dead_time_voltage_V * abs(commissioning.sigma / commissioning.delta) / injection_amplitude_V


def dead_time_modelled(setting, commissioning, injection_amplitude_V):
    """(whether ours subtracts the dead-time voltage, what it says of it): the setting ``dead_time_model``, or
    for ``auto`` wherever a commissioned salient motor has a measured dead-time voltage."""
    if setting != "auto":
        return bool(setting), ""
    if not (commissioning.salient() and commissioning.dead_time_voltage_V > 0.0):
        return False, ""
    u_dt, share = commissioning.dead_time_voltage_V, dead_time_share(commissioning, injection_amplitude_V)
    return True, (f"dead-time model on: the {u_dt:.3g} V dead-time voltage is {share:.2f} of the saliency's "
                  f"{u_dt / share:.3g} V share of the carrier (U_h·|Δ|/Σ)")


def saliency_snr(injection_amplitude_V, commissioning, omega_h):
    """The saliency current U_h·|Δ|/ω_h in commissioned sensor-noise σ (0 where the noise is not measured)."""
    noise = commissioning.sensor_noise_A
    return injection_amplitude_V * abs(commissioning.delta) / omega_h / noise if noise > 0.0 else 0.0


def raised_injection_amplitude(requested_V, commissioning, nameplate, inverter, omega_h, snr_min):
    """Ours' HF amplitude [V] and what it says of it: ``requested_V`` raised so that the saliency current
    U_h·|Δ|/ω_h, at no load and at rated current (|Δ| as much smaller as the commissioned table of |Δ|/Σ
    shows there), reaches ``snr_min`` times the commissioned sensor noise, within the ripple and voltage
    caps; unchanged when the saliency or the noise is not measured, or ``snr_min`` is 0."""
    retained = min(1.0, commissioning.saliency_retained(nameplate.rated_current_A))
    noise, delta = commissioning.sensor_noise_A, abs(commissioning.delta) * retained
    if snr_min <= 0.0 or noise <= 0.0 or not commissioning.salient():
        return requested_V, ""
    wanted = snr_min * noise * omega_h / delta
    if wanted <= requested_V:
        return requested_V, ""
    caps = {"HF ripple": HF_RIPPLE_MAX_PER_RATED * nameplate.rated_current_A * omega_h / abs(commissioning.sigma)}
    if math.isfinite(inverter.U_dc_V):
        caps["voltage"] = HF_VOLTAGE_MAX_PER_LINEAR * inverter.U_dc_V / math.sqrt(3.0)
    cap_name = min(caps, key=caps.get)
    injection_amplitude_V = max(requested_V, min(wanted, caps[cap_name]))
    reached = saliency_snr(injection_amplitude_V, commissioning, omega_h) * retained
    limited = f"; held by the {cap_name} cap" if wanted > injection_amplitude_V else ""
    at = " at rated current" if retained < 1.0 else ""
    return injection_amplitude_V, (f"raised from {requested_V:g} V: saliency current{at} {reached:.1f} σ of the "
                                   f"commissioned sensor noise, {snr_min:g} wanted{limited}")


def tracking_loop_type(requested, injection_amplitude_V, commissioning, omega_h, snr_min):
    """(2 or 3, what the drive says of it) for ``pll_type`` ``requested``: "auto" (set where the rotor's
    acceleration sets the bandwidth, hf_estimator.build) takes the type-3 loop, which follows a constant
    acceleration without lag but passes more noise, where the saliency current U_h·|Δ|/ω_h reaches
    ``snr_min`` times the commissioned sensor noise; else type 2."""
    if requested != "auto":
        return requested, ""
    reached = saliency_snr(injection_amplitude_V, commissioning, omega_h)
    if commissioning.salient() and reached >= snr_min * (1.0 - 1e-9):
        return 3, f"type-3 tracking loop: the rotor's acceleration sets its bandwidth, {reached:.1f} σ of signal"
    return 2, (f"type-2 tracking loop: {reached:.1f} σ of signal leaves no noise margin for type 3"
               if commissioning.sensor_noise_A > 0.0 else "type-2 tracking loop: sensor noise not commissioned")


class InjectionFrameParams(NamedTuple):
    T_s_s: float
    N: int
    injection_amplitude_V: float
    R_s_ohm: float
    """Commissioned stator resistance (the nameplate's when not commissioned)."""
    dither_rad: float
    delay_periods: int
    kp: float
    ki: float
    ka: float
    """The type-3 loop's acceleration gain (0: type 2)."""
    observable_ratio: float
    smoothing: float
    current_smoothing: float
    """First-order smoothing per sample of î_q (window-centred: time constant N/2 samples)."""
    shift_i_q_A: np.ndarray
    shift_rad: np.ndarray
    dead_time_voltage_V: float
    """Commissioned per-phase dead-time voltage subtracted from the applied voltage (0: not modelled)."""
    dead_time_smoothing_A: float
    sigma_per_H: float
    """Commissioned Σ = ½(1/L_dh + 1/L_qh) [1/H] and |Δ| = ½|1/L_dh − 1/L_qh|, for windows that excite one
    axis only (item 3b)."""
    delta_abs_per_H: float
    saliency_sign: float
    """+1 when the commissioned L_dh < L_qh (or no saliency known), −1 when L_dh > L_qh: the d axis is then
    the axis of the smaller admittance."""
    startup: StartupParams


@njit(cache=True, _nrt=False)
def _fit_error(x, n, p):
    """Least-squares Γ̂ from the sliding sums → (e [rad], |Δ̂| [1/H], Σ̂ [1/H])."""
    sums = x.sums
    s_a, s_b, s_y1, s_y2 = sums[0], sums[1], sums[2], sums[3]
    aa = sums[4] - s_a * s_a / n
    bb = sums[5] - s_b * s_b / n
    ab = sums[6] - s_a * s_b / n
    ay1 = sums[7] - s_a * s_y1 / n
    by2 = sums[8] - s_b * s_y2 / n
    mixed = sums[9] - (s_b * s_y1 + s_a * s_y2) / n
    # Normal equations for (g_dd, g_qq, g_dq): [[aa, 0, ab], [0, bb, ab], [ab, ab, aa + bb]].
    if aa + bb <= 0.0:
        return 0.0, 0.0, 0.0
    scale = 1.0 / (p.T_s_s * p.injection_amplitude_V)
    s = p.saliency_sign
    if 4.0 * (aa * bb - ab * ab) < MIN_EXCITATION_SPREAD * (aa + bb) ** 2:
        # One axis φ excited (item 3b): Δ sin 2(e − φ) across it is Σ-free; along it the commissioned |Δ|.
        sigma = p.sigma_per_H
        half_difference = (scale * (ay1 - by2) - sigma * (aa - bb)) / (aa + bb)
        g_dq = (scale * mixed - 2.0 * sigma * ab) / (aa + bb)
        phi = 0.5 * math.atan2(2.0 * ab, aa - bb)
        c2, s2 = math.cos(2.0 * phi), math.sin(2.0 * phi)
        across = g_dq * c2 - half_difference * s2
        along = half_difference * c2 + g_dq * s2
        if abs(across) < p.delta_abs_per_H:
            along = math.copysign(math.sqrt(p.delta_abs_per_H ** 2 - across ** 2), along)
        return phi + 0.5 * math.atan2(s * across, s * along), math.hypot(half_difference, g_dq), sigma
    m00, m02, m11, m12, m22 = aa, ab, bb, ab, aa + bb
    det = m00 * (m11 * m22 - m12 * m12) - m02 * m02 * m11
    g_dd = scale * (ay1 * (m11 * m22 - m12 * m12) + m02 * (by2 * m12 - m11 * mixed)) / det
    g_qq = scale * (m00 * (by2 * m22 - m12 * mixed) + m02 * (m12 * ay1 - m02 * by2)) / det
    g_dq = scale * (m00 * (m11 * mixed - by2 * m12) - m02 * m11 * ay1) / det
    half_difference = 0.5 * (g_dd - g_qq)
    return (0.5 * math.atan2(s * g_dq, s * half_difference), math.hypot(half_difference, g_dq),
            0.5 * (g_dd + g_qq))


@njit(cache=True, _nrt=False)
def injection_frame_step(x, p, k, sample, out):
    """One sample (interface.py): the currents and the voltage applied in the period before → ``out``:
    θ̂_e, ω̂_e = the loop's integrator, the injection, ε [rad], signal |Δ̂| [1/H], the start-up's state.
    State x: injection_frame_state; p: InjectionFrameParams."""
    i_alpha, i_beta = clarke_contract(sample.i_a, sample.i_b, sample.i_c)
    depth = p.delay_periods + 2
    window = 2 * p.N

    # The voltage applied in period k−1 was issued at k−1−d, aimed at the axis of then.
    axis_then = x.issued[(k - 1 - p.delay_periods) % depth]
    d_alpha = i_alpha - x.prev_ia
    d_beta = i_beta - x.prev_ib
    R_s = stator_resistance(p.R_s_ohm, sample.R_s_ohm)
    drive_alpha, drive_beta = net_of_dead_time(sample.u_applied_alpha - R_s * 0.5 * (i_alpha + x.prev_ia),
                                               sample.u_applied_beta - R_s * 0.5 * (i_beta + x.prev_ib),
                                               x.prev_ia, x.prev_ib, p.dead_time_voltage_V, p.dead_time_smoothing_A)
    x.prev_ia = i_alpha
    x.prev_ib = i_beta

    _, i_q = rotate(i_alpha, i_beta, -x.theta)
    x.i_q_smooth += p.current_smoothing * (i_q - x.i_q_smooth)
    eps = 0.0
    observable = 0.0
    if k >= p.delay_periods + 2:
        y1, y2 = rotate(d_alpha, d_beta, -axis_then)
        v_d, v_q = rotate(drive_alpha, drive_beta, -axis_then)
        a = v_d / p.injection_amplitude_V
        b = v_q / p.injection_amplitude_V
        new = (a, b, y1, y2, a * a, b * b, a * b, a * y1, b * y2, b * y1 + a * y2)
        regressor = x.regressors[k % window]
        old_a, old_b, old_y1, old_y2 = regressor[0], regressor[1], regressor[2], regressor[3]
        old = (old_a, old_b, old_y1, old_y2, old_a * old_a, old_b * old_b, old_a * old_b,
               old_a * old_y1, old_b * old_y2, old_b * old_y1 + old_a * old_y2)
        for j in range(N_SUMS):
            x.sums[j] += new[j] - old[j]
        regressor[0] = a
        regressor[1] = b
        regressor[2] = y1
        regressor[3] = y2
        x.count += 1.0
        if x.count >= window:
            error, delta, sigma = _fit_error(x, float(window), p)
            x.delta_smooth += p.smoothing * (delta - x.delta_smooth)
            if x.delta_smooth > p.observable_ratio * abs(sigma):
                observable = 1.0
                eps = error - table_value(x.i_q_smooth, p.shift_i_q_A, p.shift_rad)
                jump = max(ALIGN_JUMP_RAD, 4.0 * p.startup.align_tolerance_rad)
                if startup_code(x) == ALIGNING and abs(eps) > jump:
                    x.theta += eps
                    x.count = -max(0.0, p.delay_periods + 1.0 - p.N)
                    eps = 0.0
                    observable = 0.0

    tracking_loop(x, p.kp, p.ki, p.ka, p.T_s_s, eps)
    omega = x.omega

    carrier_now = math.cos(2.0 * math.pi * (k % p.N) / p.N)
    sign_now = 1.0 if (k // p.N) % 2 == 0 else -1.0
    axis_now = x.theta + omega * (p.delay_periods + 0.5) * p.T_s_s
    x.issued[k % depth] = axis_now
    u_alpha, u_beta = rotate(p.injection_amplitude_V * carrier_now, 0.0, axis_now + sign_now * p.dither_rad)
    u_alpha, u_beta, state = startup_step(x, p.startup, k, sample, (i_alpha, i_beta), (u_alpha, u_beta),
                                          eps, observable)
    if state != TRACKING:
        x.acceleration = 0.0
    write_injecting_estimate(out, x.theta, x.omega, (u_alpha, u_beta), eps, x.delta_smooth, state,
                             p.injection_amplitude_V)


@register("injection_frame", "ours: incremental admittance fitted from current steps and the applied "
                             "voltage in the injection frame; alternating axis; model-free observability",
          "ours, after docs/hf-demodulation.md §2-4", excitation="any", injection_kind="alternating")
def make_injection_frame(nameplate, T_s, settings, commissioning, inverter):
    s = check_settings("injection_frame", settings, DEFAULTS, T_s)
    N = int(round(1.0 / (float(s["frequency_Hz"]) * T_s)))
    if N < 3:
        raise ValueError(f"frequency_Hz {s['frequency_Hz']} leaves fewer than 3 samples per carrier period")
    ring_capacity(N, inverter.delay_periods)
    omega_h = 2.0 * math.pi / (N * T_s)
    snr_min = float(s["saliency_snr_min"]) * math.sqrt(max(1.0, float(s["pll_bandwidth_Hz"]) / SNR_REFERENCE_HZ))
    injection_amplitude_V, note = raised_injection_amplitude(float(s["amplitude_V"]), commissioning, nameplate,
                                                             inverter, omega_h, snr_min)
    loop_type, loop_note = tracking_loop_type(s["pll_type"], injection_amplitude_V, commissioning, omega_h, snr_min)
    shift_rad, loaded_note = loaded_correction(commissioning, 1.0 / (N * T_s), injection_amplitude_V)
    modelled, dead_time_note = dead_time_modelled(s["dead_time_model"], commissioning, injection_amplitude_V)
    note = "; ".join(n for n in (note, loop_note, loaded_note, dead_time_note) if n)
    kp, ki, ka = unit_slope_gains(float(s["pll_bandwidth_Hz"]), float(s["pll_damping"]), loop_type)
    delay_periods = inverter.delay_periods
    startup = make_startup(nameplate, commissioning, T_s, inverter, 1.0, s)
    params = InjectionFrameParams(
        T_s_s=T_s, N=N, injection_amplitude_V=injection_amplitude_V, R_s_ohm=commissioning.R_s_ohm,
        dither_rad=float(s["dither_rad"]),
        delay_periods=int(delay_periods), kp=kp, ki=ki, ka=ka,
        observable_ratio=float(s["observable_ratio"]),
        smoothing=1.0 - math.exp(-2.0 * math.pi * float(s["signal_smoothing_Hz"]) * T_s),
        current_smoothing=1.0 - math.exp(-2.0 / N),
        shift_i_q_A=commissioning.saliency_shift_i_q_A, shift_rad=shift_rad,
        dead_time_voltage_V=commissioning.dead_time_voltage_V if modelled else 0.0,
        dead_time_smoothing_A=max(SMOOTHING_PER_RATED_CURRENT * nameplate.rated_current_A, MIN_SMOOTHING_A),
        sigma_per_H=commissioning.sigma, delta_abs_per_H=abs(commissioning.delta),
        saliency_sign=1.0 if commissioning.delta >= 0.0 else -1.0, startup=startup)
    return Estimator("injection_frame", injection_frame_step, params, injection_frame_state(),
                     1.0 / (N * T_s), float(s["pll_bandwidth_Hz"]), injection_amplitude_V=injection_amplitude_V,
                     injection_note=note, tracking_loop=(kp, ki, ka, (N + 0.5) * T_s))
