"""``square_wave`` — square-wave HF injection at up to half the sampling rate, demodulated from successive
current steps (docs/hf-demodulation.md §6). After Kim, Ha & Sul, "PWM switching frequency signal
injection sensorless method in IPMSM", IEEE Trans. Ind. Appl. 2012 (motulator's SignalInjectionObserver
implements it: ε from the second difference of the q̂ flux over the injected voltage), as the firmware
drives VESC and MESC run their HFI.

1. Injection: u = ±U_h along θ_axis = θ̂ + ω̂(d + ½)T_s (d the drive's delay), its sign turning every m
   samples (``samples_per_half_period``; f_h = f_s/(2m), m = 1: f_s/2).
2. Model. The voltage that acted in period k (between samples k−1 and k) was issued at k−1−d, aimed at
   φ_k (the axis ring). Over that period the current steps by Δi_k = T_s·Γ(θ)·(u_k − R̂·ī_k − e_k) with
   ī_k the mean of its end samples, e_k the back-EMF, and, in the frame φ_k,
   Γ = Σ·I + Δ·[[cos 2θ̃, sin 2θ̃], [sin 2θ̃, −cos 2θ̃]], θ̃ = θ − φ_k, Σ = ½(1/L_dh + 1/L_qh),
   Δ = ½(1/L_dh − 1/L_qh). With y = Δi and w = u − R̂ī in the frame φ_k (w_d = a, w_q = b), the
   difference over one half-period, D = (·)_k − (·)_{k−m}, removes what is slow (back-EMF, the
   fundamental's drift, sensor offsets) and keeps the injection, D_a ≈ ±2U_h:
       D_yq = T_s·[Δ sin 2θ̃·D_a + (Σ − Δ cos 2θ̃)·D_b]
       D_yd = T_s·[(Σ + Δ cos 2θ̃)·D_a + Δ sin 2θ̃·D_b].
   The whole applied voltage is known (SAMPLE.u_applied), so the current loop's own answer to the
   ripple (D_b) is taken off with the q admittance near lock, Σ − Δ = 1/L̂_qh:
       z_q = (D_yq/T_s − D_b/L̂_qh)/D_a = Δ sin 2θ̃,  z_d = (D_yd/T_s)/D_a − Σ̂ = Δ cos 2θ̃,
   sign-corrected by D_a itself. The error ε = z_q/(2·s·|Δ̂|·r(î_q)) − δ(î_q) has unit slope (ε ≈ θ̃): s the
   commissioned saliency's sign, |Δ̂| its no-load |Δ|, r the share of it the saliency keeps at the smoothed q̂
   current (the commissioned |Δ|/Σ table over its no-load value), δ the commissioned cross-saturation shift
   (plus the loaded test's correction where the square wave ran that test at this carrier and amplitude:
   injection_frame.loaded_correction).
   Scaled by the no-load |Δ| alone, a q axis that saturates under load (r < 1) leaves θ − θ̂ = δ(1 − r)/r:
   +0.035 rad measured on docs/motors/joint_21pp_48v.yaml at rated current (δ 0.2 rad, r 0.85), 0.000 with r.
   (z_d, z_q) turned into the θ̂ frame and smoothed is the signal |Δ̂| [1/H], observable above
   ``observable_ratio``·Σ̂ (0.005: the ripple, far larger than the commissioning's, sees a d admittance a few %
   of Σ off 1/L̂_dh — 6 % on that joint — which z_d counts as saliency; at ours' 0.02 the joint's signal dipped
   below it in a speed step and the loop, held, lost the lock).
3. Noise: ε's sensor noise is s_k·(n_k − n_{k−1} − n_{k−m} + n_{k−m−1})/(4·T_s·U_h·|Δ|), s_k the carrier's sign:
   at m = 1 s_k·(n_k − 2n_{k−1} + n_{k−2}), whose power is 16σ² at low frequency and falls as cos⁴(ω/2) to none
   at f_s/2, so a wide loop passes less of it than a white noise of that power. The angle error it leaves is
   computed by stepping the loop (its gains, the delay, ε from the axes of d + 1 and d + 1 + m samples before)
   on that noise (square_wave_noise_gain, square_wave_predicted_error: docs/hf-demodulation.md §6); the drive
   refuses where it misses ours' targets (hf_estimator.build.refused_signal) unless ``run_refused`` (`drive run
   --force`). At low frequency the square wave carries the angle information of a sine carrier's saliency
   current I_Δ = U_h·T_s·|Δ|·√(m/2) (square_wave_saliency_current at m = 1), and ours' amplitude rule
   (injection_frame item 5) applies to that current: raised to ``saliency_snr_min``·√(B/18 Hz) σ of the
   commissioned sensor noise at the saliency left at rated current, within the ripple cap (the triangle's peak
   m·T_s·U_h·Σ/2 ≤ HF_RIPPLE_MAX_PER_RATED × rated current) and the voltage cap. Each step carries the same
   information whatever m, while the ripple grows as m: m = 1 costs least.
4. Tracking: ours' type-2 / type-3 loop (injection_frame item 6) on ε. Its bandwidth follows the rotor's
   acceleration as ours' (drive_common.motor.scaled_loops: √(a_e/0.25 rad), ≥ 18 Hz) but is capped by
   the demodulation's delay instead of the sine's fit window: square_wave_tracking_limit_Hz, the rule
   ω_n·τ ≤ TRACKING_PHASE_RAD with τ = (d + 1 + m/2)·T_s (docs/pll-tuning.md, "Square-wave injection").
5. Start-up: the shared one (startup.py), as it is.
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.estimator_states import TRACKING
from drive_common.math.dead_time import SMOOTHING_PER_RATED_CURRENT, net_of_dead_time
from drive_common.math.frames import clarke_contract, rotate
from drive_common.math.tables import table_value
from drive_common.motor.scaled_loops import (
    ACCELERATION_LAG_RAD,
    CARRIER_PER_TRACKING,
    MIN_SAMPLES_PER_CARRIER,
    MIN_TRACKING_HZ,
)

from .injection_frame import (
    HF_RIPPLE_MAX_PER_RATED,
    HF_VOLTAGE_MAX_PER_LINEAR,
    SNR_REFERENCE_HZ,
    loaded_correction,
)
from .interface import MAX_DELAY_PERIODS, Estimator, check_settings, register, ring_capacity, stator_resistance
from .outputs import write_injecting_estimate
from .pll_model import (
    CLARKE_NOISE_SHARE,
    NOISE_GAIN_SETTLE_PERIODS,
    PEAK_PER_RMS,
    TARGET_PEAK_RAD,
    TARGET_RMS_RAD,
    UNSETTLED_SHARE,
)
from .startup import DEFAULTS as STARTUP_DEFAULTS
from .startup import fresh_startup, make_startup, startup_step
from .startup_state import STARTUP, StartupParams
from .tracking_loop import tracking_loop, unit_slope_gains

MAX_HALF_PERIOD_SAMPLES = 8
"""The largest ``samples_per_half_period`` (f_h ≥ f_s/16): beyond, the sine carrier serves better."""
TRACKING_PHASE_RAD = 0.35
"""The phase the demodulation's delay may take at the tracking loop's ω_n: ω_n·τ ≤ this. The sine rule
(ours, f_h/CARRIER_PER_TRACKING at SAMPLES_PER_CARRIER = 5 samples per period and d = 1: τ ≈ (N + d + 1)T_s
= 7 T_s, 80 Hz at 10 kHz) is this same budget: 2π·80 Hz · 0.7 ms = 0.35 rad."""
HF_RIPPLE_DEFAULT_PER_RATED = 0.2
"""Where the sensor noise is not commissioned, the amplitude gives this triangle peak per rated current (as
scaled_loops' HF_RIPPLE_PER_RATED)."""

SQUARE_WAVE = np.dtype([
    *[(name, np.float64) for name in ("theta", "omega", "acceleration", "prev_ia", "prev_ib", "i_q_smooth",
                                      "z_d_smooth", "z_q_smooth", "delta_smooth", "smoothed_at")],
    ("issued", np.float64, MAX_DELAY_PERIODS + 2), ("steps", np.float64, (MAX_HALF_PERIOD_SAMPLES, 4)),
    ("startup", STARTUP)])
"""The state: θ̂ [rad], ω̂ [rad/s] (the loop's integrator), the type-3 loop's acceleration [rad/s²], the previous
currents (αβ) [A], î_q smoothed [A], the saliency vector (z_d, z_q) in the θ̂ frame and |Δ̂| smoothed [1/H], the θ̂
it was turned to [rad], the ring of the axes issued in the last d + 2 samples [rad], the ring of the last m steps
(y_d [A], y_q [A], a [V], b [V]) and the start-up's."""

DEFAULTS = {"samples_per_half_period": 1, "amplitude_V": None, "pll_bandwidth_Hz": None, "pll_damping": 0.9,
            "pll_type": "auto", "observable_ratio": 0.005, "signal_smoothing_Hz": 20.0, "saliency_snr_min": 8.0,
            "dead_time_model": True, **STARTUP_DEFAULTS}
"""``amplitude_V`` and ``pll_bandwidth_Hz`` None: from the rules (items 3, 4)."""


def square_wave_state():
    """Fresh state (θ̂ = 0, ω̂ = 0, aligning): SQUARE_WAVE."""
    state = np.zeros(1, SQUARE_WAVE)
    fresh_startup(state[0]["startup"])
    return state


def demodulation_delay_s(T_s, delay_periods, samples_per_half_period):
    """τ [s] from θ̂ to the error that measures it: the command's d + 1 samples to the step that answers it,
    and the difference over half a period centred m/2 samples back."""
    return (delay_periods + 1.0 + 0.5 * samples_per_half_period) * T_s


def square_wave_tracking_limit_Hz(T_s, delay_periods, samples_per_half_period=1):
    """The widest tracking bandwidth [Hz] the square wave's demodulation delay allows: TRACKING_PHASE_RAD/τ."""
    return TRACKING_PHASE_RAD / demodulation_delay_s(T_s, delay_periods, samples_per_half_period) / (2.0 * math.pi)


def sine_tracking_limit_Hz(T_s):
    """The widest tracking bandwidth [Hz] ours' sine carrier allows at the highest carrier the loops' rule
    gives it (f_s/MIN_SAMPLES_PER_CARRIER, drive_common.motor.scaled_loops)."""
    return 1.0 / (T_s * MIN_SAMPLES_PER_CARRIER) / CARRIER_PER_TRACKING


def square_wave_saliency_current(injection_amplitude_V, T_s, delta_per_H):
    """The sine-carrier saliency current [A] carrying the same angle information at low frequency as the square
    wave at m = 1 (item 3): U_h·T_s·|Δ|/√2."""
    return injection_amplitude_V * T_s * abs(delta_per_H) / math.sqrt(2.0)


def square_wave_noise_gain(gains, m, delay_periods, T_s):
    """Σθ̂² of the square wave's loop (items 2-4) per unit white noise in one current component, over the noise
    impulse's phase in the carrier's period: the noise enters ε as s_k·(n_k − n_{k−1} − n_{k−m} + n_{k−m−1}) (s_k the
    carrier's sign), ε sees the axes issued d + 1 and d + 1 + m samples before (each half), the loop (k_p, k_i, k_a)
    and the issued axis's prediction ω̂(d + ½)T_s as the estimator runs them. In units of (4·T_s·U_h·|Δ|)⁻²; ∞ where
    the loop does not settle (as pll_model.injection_frame_noise_gain)."""
    kp, ki, ka = gains
    steps = 2 * m + delay_periods + int(NOISE_GAIN_SETTLE_PERIODS * 2.0 * math.pi / (math.sqrt(ki) * T_s))
    lead = (delay_periods + 0.5) * T_s
    taps = ((0, 1.0), (1, -1.0), (m, -1.0), (m + 1, 1.0))
    total = tail = 0.0
    for phase in range(2 * m):
        axis = np.zeros(steps)
        theta = omega = acceleration = 0.0
        energy = np.zeros(steps)
        for k in range(steps):
            noise = sum(f for i, f in taps if i == k) * (1.0 if ((k + phase) // m) % 2 == 0 else -1.0)
            seen = [axis[k - 1 - delay_periods - lag] if k - 1 - delay_periods - lag >= 0 else 0.0 for lag in (0, m)]
            eps = noise - 0.5 * (seen[0] + seen[1])
            acceleration += T_s * ka * eps
            omega += T_s * acceleration + T_s * ki * eps
            theta += T_s * (kp * eps + omega)
            axis[k] = theta + omega * lead
            energy[k] = theta * theta
        total += float(np.sum(energy)) / (2 * m)
        tail += float(np.sum(energy[-(steps // 10):])) / (2 * m)
    return total if math.isfinite(total) and tail <= UNSETTLED_SHARE * total else math.inf


def square_wave_predicted_error(params, sensor_noise_A):
    """(RMS, peak) [rad] of the square wave's noise-driven angle error at no load, and its sine-equivalent saliency
    current I_Δ [A] (item 3), from its params (SquareWaveParams: amplitude, half-period, |Δ|, loop gains, delay) and
    the commissioned sensor noise of one phase current [A]: σ_αβ/(4·T_s·U_h·|Δ|)·√(square_wave_noise_gain), σ_αβ as
    ours' (pll_model.CLARKE_NOISE_SHARE), the peak PEAK_PER_RMS times it (docs/hf-demodulation.md §6)."""
    p = params
    current = square_wave_saliency_current(p.injection_amplitude_V, p.T_s_s, p.delta_abs_per_H)
    gain = square_wave_noise_gain((p.kp, p.ki, p.ka), p.half_period, p.delay_periods, p.T_s_s)
    scale = 4.0 * p.T_s_s * p.injection_amplitude_V * p.delta_abs_per_H
    rms = math.sqrt(CLARKE_NOISE_SHARE) * sensor_noise_A / scale * math.sqrt(gain) if scale > 0.0 else math.inf
    return rms, PEAK_PER_RMS * rms, current


def rotor_tracking_wanted_Hz(nameplate):
    """The tracking bandwidth [Hz] a rated-torque step's acceleration wants (scaled_loops' rule), 0 where J is
    not known."""
    a_e = nameplate.n_p * nameplate.rated_torque_Nm / nameplate.J_kgm2
    return math.sqrt(a_e / ACCELERATION_LAG_RAD) / (2.0 * math.pi) if math.isfinite(a_e) and a_e > 0.0 else 0.0


class SquareWaveChoice(NamedTuple):
    """What the rule says of a motor (square_wave_serves)."""

    serves: bool
    wanted_Hz: float
    """The tracking bandwidth the rotor's rated-torque acceleration wants."""
    sine_limit_Hz: float
    square_limit_Hz: float
    predicted_rms_rad: float
    """The square wave's predicted angle error RMS on its own rules (square_wave_predicted_error; ∞ where the
    saliency or the sensor noise is not measured)."""
    predicted_peak_rad: float
    reason: str


def square_wave_amplitude(requested_V, commissioning, nameplate, inverter, T_s, snr_wanted, m=1):
    """(U_h [V], the largest the caps allow [V], what the drive says) for a half-period of m samples:
    ``requested_V`` (None: the rule, item 3) within the ripple and voltage caps."""
    ripple_cap = HF_RIPPLE_MAX_PER_RATED * nameplate.rated_current_A * 2.0 / (m * T_s * abs(commissioning.sigma))
    caps = {"HF ripple": ripple_cap}
    if math.isfinite(inverter.U_dc_V):
        caps["voltage"] = HF_VOLTAGE_MAX_PER_LINEAR * inverter.U_dc_V / math.sqrt(3.0)
    cap_name = min(caps, key=caps.get)
    largest = caps[cap_name]
    if requested_V is not None:
        return min(requested_V, largest), largest, ""
    noise, retained = commissioning.sensor_noise_A, min(1.0, commissioning.saliency_retained(nameplate.rated_current_A))
    if noise <= 0.0 or not commissioning.salient():
        default = HF_RIPPLE_DEFAULT_PER_RATED * nameplate.rated_current_A * 2.0 / (m * T_s * abs(commissioning.sigma))
        return min(default, largest), largest, "square-wave amplitude for a 0.2 × rated ripple: sensor noise unknown"
    wanted = snr_wanted * noise / square_wave_saliency_current(1.0, T_s, commissioning.delta * retained) * math.sqrt(m)
    amplitude = min(wanted, largest)
    held = f"; held by the {cap_name} cap" if wanted > amplitude else ""
    return amplitude, largest, (f"square wave at {amplitude:.3g} V: saliency current "
                                f"{snr_wanted * amplitude / wanted:.1f} σ, {snr_wanted:.3g} wanted{held}")


def square_wave_serves(nameplate, commissioning, inverter, T_s):
    """The loops' rule for choosing the square wave over ours' sine carrier (docs/hf-demodulation.md §6): it serves
    a motor whose rated-torque acceleration wants a tracking bandwidth beyond what the sine carrier allows at this
    sampling, where the square wave's delay allows more, and where its angle error predicted on its own rules
    (amplitude, loop, delay: square_wave_predicted_error) meets ours' targets. → SquareWaveChoice."""
    wanted = rotor_tracking_wanted_Hz(nameplate)
    sine = sine_tracking_limit_Hz(T_s)
    square = square_wave_tracking_limit_Hz(T_s, inverter.delay_periods)
    rms = peak = math.inf
    if wanted > sine and square > sine and commissioning.salient() and commissioning.sensor_noise_A > 0.0:
        built = make_square_wave(nameplate, T_s, {"run_refused": True}, commissioning, inverter)
        rms, peak, _ = square_wave_predicted_error(built.params, commissioning.sensor_noise_A)

    def choice(serves, reason):
        return SquareWaveChoice(serves, wanted, sine, square, rms, peak, reason)
    if wanted <= sine:
        return choice(False, f"the sine carrier's {sine:.0f} Hz tracking covers the {wanted:.0f} Hz this rotor wants")
    if square <= sine:
        return choice(False, f"the drive's delay leaves the square wave no wider loop ({square:.0f} Hz)")
    if not (commissioning.salient() and commissioning.sensor_noise_A > 0.0):
        return choice(False, "the commissioning has not measured the saliency and the sensor noise its angle error "
                             "is predicted from")
    if not (rms <= TARGET_RMS_RAD and peak <= TARGET_PEAK_RAD):
        return choice(False, f"its predicted angle error {rms:.3f} rad RMS, {peak:.2f} rad peak misses ours' targets "
                             f"({TARGET_RMS_RAD:g}, {TARGET_PEAK_RAD:g} rad): it would refuse")
    return choice(True, f"tracking wants {wanted:.0f} Hz: the sine carrier allows {sine:.0f} Hz, the square wave "
                        f"{square:.0f} Hz at a predicted {rms:.3f} rad RMS")


class SquareWaveParams(NamedTuple):
    T_s_s: float
    half_period: int
    injection_amplitude_V: float
    R_s_ohm: float
    inverse_L_qh_per_H: float
    sigma_per_H: float
    delta_abs_per_H: float
    """The commissioned |Δ| at no load [1/H]."""
    saliency_retained: np.ndarray
    """The share of its no-load |Δ| the saliency keeps over shift_i_q_A (the commissioned |Δ|/Σ table over its
    no-load value, Σ taken as constant; 1 throughout where not measured)."""
    saliency_sign: float
    """+1 where the commissioned L_dh < L_qh, −1 where L_dh > L_qh, 0 without a commissioned saliency."""
    delay_periods: int
    kp: float
    ki: float
    ka: float
    observable_ratio: float
    smoothing: float
    current_smoothing: float
    shift_i_q_A: np.ndarray
    shift_rad: np.ndarray
    dead_time_voltage_V: float
    """Commissioned per-phase dead-time voltage taken off the applied voltage (0: not modelled)."""
    dead_time_smoothing_A: float
    startup: StartupParams


@njit(cache=True)
def square_wave_step(x, p, k, sample, out):
    """One sample (interface.py) → ``out``: θ̂_e, ω̂_e = the loop's integrator, the injection, ε [rad], signal
    |Δ̂| [1/H], the start-up's state. State x: SQUARE_WAVE; p: SquareWaveParams."""
    i_alpha, i_beta = clarke_contract(sample.i_a, sample.i_b, sample.i_c)
    depth = p.delay_periods + 2
    m = p.half_period
    axis_then = x.issued[(k - 1 - p.delay_periods) % depth]
    R_s = stator_resistance(p.R_s_ohm, sample.R_s_ohm)
    w_alpha, w_beta = net_of_dead_time(sample.u_applied_alpha - R_s * 0.5 * (i_alpha + x.prev_ia),
                                       sample.u_applied_beta - R_s * 0.5 * (i_beta + x.prev_ib),
                                       x.prev_ia, x.prev_ib, p.dead_time_voltage_V, p.dead_time_smoothing_A)
    y_d, y_q = rotate(i_alpha - x.prev_ia, i_beta - x.prev_ib, -axis_then)
    a, b = rotate(w_alpha, w_beta, -axis_then)
    x.prev_ia = i_alpha
    x.prev_ib = i_beta
    _, i_q = rotate(i_alpha, i_beta, -x.theta)
    x.i_q_smooth += p.current_smoothing * (i_q - x.i_q_smooth)

    eps = 0.0
    observable = 0.0
    step = x.steps[k % m]
    if k >= p.delay_periods + 2 + m:
        d_a = a - step[2]
        if abs(d_a) > p.injection_amplitude_V:
            z_q = ((y_q - step[1]) / p.T_s_s - (b - step[3]) * p.inverse_L_qh_per_H) / d_a
            z_d = (y_d - step[0]) / p.T_s_s / d_a - p.sigma_per_H
            # Smoothed in the θ̂ frame, turned as θ̂ turns, so that neither speed nor θ̂'s moves average it away.
            x.z_d_smooth, x.z_q_smooth = rotate(x.z_d_smooth, x.z_q_smooth, -2.0 * (x.theta - x.smoothed_at))
            x.smoothed_at = x.theta
            z_d_now, z_q_now = rotate(z_d, z_q, 2.0 * (axis_then - x.theta))
            x.z_d_smooth += p.smoothing * (z_d_now - x.z_d_smooth)
            x.z_q_smooth += p.smoothing * (z_q_now - x.z_q_smooth)
            x.delta_smooth = math.hypot(x.z_d_smooth, x.z_q_smooth)
            if x.delta_smooth > p.observable_ratio * p.sigma_per_H and p.saliency_sign != 0.0:
                observable = 1.0
                shift = table_value(x.i_q_smooth, p.shift_i_q_A, p.shift_rad)
                retained = table_value(x.i_q_smooth, p.shift_i_q_A, p.saliency_retained)
                gain = p.saliency_sign * 2.0 * p.delta_abs_per_H * retained
                eps = z_q / gain - shift
    step[0] = y_d
    step[1] = y_q
    step[2] = a
    step[3] = b

    tracking_loop(x, p.kp, p.ki, p.ka, p.T_s_s, eps)

    sign_now = 1.0 if (k // m) % 2 == 0 else -1.0
    axis_now = x.theta + x.omega * (p.delay_periods + 0.5) * p.T_s_s
    x.issued[k % depth] = axis_now
    u_alpha, u_beta = rotate(sign_now * p.injection_amplitude_V, 0.0, axis_now)
    u_alpha, u_beta, state = startup_step(x, p.startup, k, sample, (i_alpha, i_beta), (u_alpha, u_beta),
                                          eps, observable)
    if state != TRACKING:
        x.acceleration = 0.0
    write_injecting_estimate(out, x.theta, x.omega, (u_alpha, u_beta), eps, x.delta_smooth, state,
                             p.injection_amplitude_V)


def saliency_retained_table(commissioning):
    """The share of its no-load |Δ| the saliency keeps over commissioning.saliency_shift_i_q_A: the commissioned
    |Δ|/Σ table over its value at zero current (Σ taken as constant), 1 throughout where not measured."""
    currents = np.asarray(commissioning.saliency_shift_i_q_A, dtype=float)
    if commissioning.saliency_ratio is None:
        return np.ones(currents.shape)
    ratio = np.abs(np.asarray(commissioning.saliency_ratio, dtype=float))
    at_zero = float(np.interp(0.0, currents, ratio))
    return ratio / at_zero if at_zero > 0.0 else np.ones(currents.shape)


def _checked(settings, T_s):
    """The settings read through their keys, None kept for the two the rules set. A carrier given as
    ``frequency_Hz`` (a recording's, in replay) sets the half-period: m = round(f_s/(2·f_h)), at least 1."""
    rule_set = {name: settings.get(name) for name in ("amplitude_V", "pll_bandwidth_Hz")}
    given = {name: value for name, value in settings.items() if not (name in rule_set and value is None)}
    if "frequency_Hz" in given:
        if "samples_per_half_period" in given:
            raise ValueError("estimator 'square_wave': frequency_Hz and samples_per_half_period both set the carrier: "
                             "give one")
        f_h = given.pop("frequency_Hz")
        nyquist = 0.5 / T_s
        if isinstance(f_h, bool) or not isinstance(f_h, (int, float)) or not 0.0 < f_h <= nyquist * (1.0 + 1e-9):
            raise ValueError(f"estimator 'square_wave': frequency_Hz: must lie in (0, {nyquist:g}] (up to f_s/2, "
                             f"the square wave's own carrier), not {f_h!r} [Hz]")
        given["samples_per_half_period"] = max(1, int(round(nyquist / f_h)))
    s = check_settings("square_wave", given, {**DEFAULTS, "amplitude_V": 1.0, "pll_bandwidth_Hz": MIN_TRACKING_HZ},
                       T_s)
    for name, value in rule_set.items():
        if value is None:
            s[name] = None
    if s["samples_per_half_period"] > MAX_HALF_PERIOD_SAMPLES:
        raise ValueError(f"estimator 'square_wave': samples_per_half_period: {s['samples_per_half_period']} is more "
                         f"than {MAX_HALF_PERIOD_SAMPLES} (a carrier that low: use the sine carrier, injection_frame)")
    return s


@register("square_wave", "square-wave injection at up to f_s/2 on d̂, demodulated from successive current "
                         "steps and the applied voltage; ours' tracking loop, wider",
          "after Kim, Ha & Sul 2012 (PWM-frequency square-wave injection); docs/hf-demodulation.md §6",
          excitation="carrier", injection_kind="square")
def make_square_wave(nameplate, T_s, settings, commissioning, inverter):
    s = _checked(settings, T_s)
    m = int(s["samples_per_half_period"])
    delay_periods = int(inverter.delay_periods)
    ring_capacity(m, delay_periods)
    limit_Hz = square_wave_tracking_limit_Hz(T_s, delay_periods, m)
    bandwidth_Hz = s["pll_bandwidth_Hz"]
    acceleration_sets = False
    if bandwidth_Hz is None:
        wanted = rotor_tracking_wanted_Hz(nameplate)
        acceleration_sets = wanted > MIN_TRACKING_HZ
        bandwidth_Hz = min(max(wanted, MIN_TRACKING_HZ), limit_Hz)
    snr_min = float(s["saliency_snr_min"])
    snr_wanted = snr_min * math.sqrt(max(1.0, bandwidth_Hz / SNR_REFERENCE_HZ))
    amplitude_V, _, note = square_wave_amplitude(s["amplitude_V"], commissioning, nameplate, inverter, T_s,
                                                 snr_wanted, m)
    noise = commissioning.sensor_noise_A
    snr = (square_wave_saliency_current(amplitude_V, T_s, commissioning.delta) * math.sqrt(m) / noise
           if noise > 0.0 else 0.0)
    notes = [note] if note else []
    if commissioning.saliency_ratio is None and commissioning.salient():
        notes.append("the commissioning holds no |Δ|/Σ table: under load the error's gain falls with the saliency "
                     "the q axis keeps and the lock sits off by δ(1 − r)/r (`drive commission` measures the table)")
    loop_type = s["pll_type"]
    if loop_type == "auto":
        loop_type = 3 if acceleration_sets and snr >= snr_wanted * (1.0 - 1e-9) else 2
    notes.append(f"tracking {bandwidth_Hz:.0f} Hz (type {loop_type}; the square wave's delay allows "
                 f"{limit_Hz:.0f} Hz)")
    kp, ki, ka = unit_slope_gains(bandwidth_Hz, float(s["pll_damping"]), loop_type)
    shift_rad, loaded_note = loaded_correction(commissioning, 0.5 / (m * T_s), amplitude_V)
    if loaded_note:
        notes.append(loaded_note)
    salient = commissioning.salient()
    params = SquareWaveParams(
        T_s_s=T_s, half_period=m, injection_amplitude_V=amplitude_V, R_s_ohm=commissioning.R_s_ohm,
        inverse_L_qh_per_H=1.0 / commissioning.L_qh_H, sigma_per_H=commissioning.sigma,
        delta_abs_per_H=abs(commissioning.delta), saliency_retained=saliency_retained_table(commissioning),
        saliency_sign=math.copysign(1.0, commissioning.delta) if salient else 0.0, delay_periods=delay_periods,
        kp=kp, ki=ki, ka=ka,
        observable_ratio=float(s["observable_ratio"]),
        smoothing=1.0 - math.exp(-2.0 * math.pi * float(s["signal_smoothing_Hz"]) * T_s),
        current_smoothing=1.0 - math.exp(-1.0 / (2.0 * m)),
        shift_i_q_A=commissioning.saliency_shift_i_q_A, shift_rad=shift_rad,
        dead_time_voltage_V=commissioning.dead_time_voltage_V if s["dead_time_model"] in (True, "auto") else 0.0,
        dead_time_smoothing_A=SMOOTHING_PER_RATED_CURRENT * nameplate.rated_current_A,
        startup=make_startup(nameplate, commissioning, T_s, inverter, 1.0 if salient else 0.0, s))
    return Estimator("square_wave", square_wave_step, params, square_wave_state(), 0.5 / (m * T_s), bandwidth_Hz,
                     injection_amplitude_V=amplitude_V, injection_note="; ".join(notes),
                     tracking_loop=(kp, ki, ka, demodulation_delay_s(T_s, delay_periods, m)))
