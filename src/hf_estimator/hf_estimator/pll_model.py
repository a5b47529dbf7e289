"""PLL loop models for tuning the tracking PI of the pulsating-injection estimators.

Szabó & Veszprémi §2.4 (faithful): the loop of Fig. 4, angle error → G_1 = 1 (Eq. 23, sin α cos α ≈ α)
→ process G_p(s) (Eq. 34-37, the q̂ HF current's response when the d- and q-direction R-L circuits are hit
by a sine step, Eq. 24-33) → gain K (Eq. 38) → loop filter 1/(sT_f + 1) → PI A_p(1 + 1/(sT_i)) (Eq. 22)
→ integrator 1/s → θ̂. Eq. (39) writes G_o = −K·A_p(…)·G_p/(sT_f+1)/s. K is negative here
(sin(φ_d + φ*) ≈ sin(−π/2) for inductive circuits), so −K = |K| and ``szabo_loop`` gives
L(s) = |K|·A_p(1 + 1/(sT_i))·G_p(s)/(s(sT_f + 1)), read with the usual negative feedback.

Carrier model (ours, ``carrier_loop``): the same loop as the sampled drive runs it. A slow angle
perturbation at ω modulates the carrier; a linear element G then acts at ω_h ± ω, and demodulation
brings ¼u*[e^{jΔφ}G(ω + ω_h) + e^{−jΔφ}G(ω − ω_h)] back to ω (Δφ: injection minus demodulation carrier
phase). With G the sampled motor admittance (one-period command delay, zero-order hold), the estimator's
digital band-pass and low-pass, its discrete PI and integrator, this is the estimator's small-signal
loop. It has no R/L poles: those belong to the step's baseband transient, which the band-pass and the
demodulation keep out of the envelope; what it has instead is the carrier's phase error ω_h·1.5·T_s.
"""
import cmath
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PllProcess:
    """G_p(s) = (p1 s² + p2 s + p3)/((s − λ_d)(s − λ_q)) and K of Eq. (34)-(38)."""

    p1: float
    p2: float
    p3: float
    lambda_d: float
    lambda_q: float
    K: float
    c_S: float
    """c of Eq. (30): |1/z_d − 1/z_q| at ω_h, the DC gain of G_p [S]."""
    phi_star_rad: float

    def G_p(self, s):
        return (self.p1 * s * s + self.p2 * s + self.p3) / ((s - self.lambda_d) * (s - self.lambda_q))


def pll_process(R_s_ohm, L_dh_H, L_qh_H, injection_frequency_Hz, injection_amplitude_V, u_star):
    """G_p and K from the motor's R, its incremental L_dh, L_qh (docs/glossary.md; Szabó writes L_d, L_q) and
    the injection (Szabó Eq. 24-38). ValueError without HF saliency (L_dh = L_qh): the q̂ current then carries
    no angle information (§2.3, case 2)."""
    if L_dh_H == L_qh_H:
        raise ValueError(f"L_dh = L_qh = {L_dh_H:g} H: no saliency, so the PLL has no angle signal to track")
    omega_h = 2.0 * math.pi * injection_frequency_Hz
    y_d, y_q = 1.0 / complex(R_s_ohm, omega_h * L_dh_H), 1.0 / complex(R_s_ohm, omega_h * L_qh_H)
    i_d, phi_d = abs(y_d), cmath.phase(y_d)
    i_q, phi_q = abs(y_q), cmath.phase(y_q)
    c = math.sqrt(i_d ** 2 + i_q ** 2 - 2.0 * i_d * i_q * math.cos(phi_q - phi_d))  # Eq. (30)
    phi_star = math.atan(-i_q * math.sin(phi_q - phi_d) / (i_d + i_q * math.cos(phi_q - phi_d)))  # Eq. (31)
    lambda_d, lambda_q = -R_s_ohm / L_dh_H, -R_s_ohm / L_qh_H  # Eq. (25)
    S = math.sin(phi_d + phi_star)
    a, b = i_d * math.sin(phi_d) / S, i_q * math.sin(phi_q) / S  # Eq. (33)
    p1 = -a + b + c  # Eq. (35)
    p2 = a * lambda_q - b * lambda_d - c * lambda_d - c * lambda_q  # Eq. (36)
    p3 = c * lambda_d * lambda_q  # Eq. (37)
    K = 0.5 * injection_amplitude_V * u_star * S  # Eq. (38)
    return PllProcess(p1, p2, p3, lambda_d, lambda_q, K, c, phi_star)


@dataclass(frozen=True)
class TrackingLoop:
    """A PLL's open loop L(jω) = A_p·pi(ω, T_i)·rest(ω), and its closed loop from the rotor angle."""

    label: str
    rest: Callable
    """ω [rad/s] → the loop without A_p·PI (complex)."""
    pi: Callable
    """(ω, T_i) → the PI's shape 1 + 1/(sT_i), or its discrete form."""
    input_path: Callable = None
    """ω → the input path over the loop path (θ → θ̂ over −(θ̂ → θ̂)); None: 1 (unity feedback)."""
    omega_max_rad_s: float = 1e6
    """Where the model holds, and the search for the highest crossover stops."""
    search_max_rad_s: float = 1e6
    """Where the search for crossovers stops: below Nyquist for a sampled loop (periodic beyond)."""

    def open_loop(self, A_p, T_i_s, omega):
        w = np.asarray(omega, dtype=float)
        return A_p * self.pi(w, T_i_s) * self.rest(w)

    def closed_loop(self, A_p, T_i_s, omega):
        """θ̂/θ at ω."""
        L = self.open_loop(A_p, T_i_s, omega)
        ratio = 1.0 if self.input_path is None else self.input_path(np.asarray(omega, dtype=float))
        return ratio * L / (1.0 + L)

    def phase(self, A_p, T_i_s, omega):
        """Phase of L(jω), continuous from low frequency (where the two integrators give −180°)."""
        w = np.atleast_1d(np.asarray(omega, dtype=float))
        grid = np.logspace(-2, math.log10(max(w.max(), 1.0) * 1.01), 40000)
        wrapped = np.angle(self.open_loop(A_p, T_i_s, grid))
        unwrapped = np.unwrap(wrapped)
        unwrapped += 2.0 * math.pi * round((-math.pi - unwrapped[0]) / (2.0 * math.pi))
        result = np.interp(w, grid, unwrapped)
        return result if np.ndim(omega) else float(result[0])


def continuous_pi(omega, T_i_s):
    """1 + 1/(sT_i) (Szabó Eq. 22); 1 for T_i = ∞ (a P controller)."""
    return 1.0 if math.isinf(T_i_s) else 1.0 + 1.0 / (1j * omega * T_i_s)


def szabo_loop(process, filter_response, omega_max_rad_s=1e6):
    """Szabó Eq. (39) with the loop filter ``filter_response(ω)`` (1/(jωT_f + 1) in the paper; a digital
    filter's response is periodic, so searches then stop at ``omega_max_rad_s``, its Nyquist)."""
    def rest(omega):
        s = 1j * omega
        return abs(process.K) * process.G_p(s) * filter_response(omega) / s
    return TrackingLoop("Szabó §2.4 model", rest, continuous_pi, omega_max_rad_s=omega_max_rad_s,
                        search_max_rad_s=omega_max_rad_s)


def sos_response(sos, omega, T_s):
    """Frequency response of digital second-order sections at ω [rad/s] (negative ω allowed)."""
    zi = np.exp(-1j * np.asarray(omega, dtype=float) * T_s)
    h = np.ones_like(zi)
    for b0, b1, b2, _, a1, a2 in sos:
        h = h * (b0 + b1 * zi + b2 * zi * zi) / (1.0 + a1 * zi + a2 * zi * zi)
    return h


@dataclass(frozen=True)
class CarrierPath:
    """What the carrier model needs of a drive and a pulsating-injection estimator."""

    R_s_ohm: float
    L_d_H: float
    L_q_H: float
    T_s_s: float
    delay_periods: int
    omega_h_rad_s: float
    injection_amplitude_V: float
    u_star: float
    """Demodulation carrier amplitude (Szabó u*, Wang's 2)."""
    carrier_phase_difference_rad: float
    """Injection carrier phase minus demodulation carrier phase (sin vs cos: −π/2; cos vs sin: +π/2)."""
    error_sign: float
    """The error the PI receives is error_sign × the demodulated q̂ (or β-rotated) current."""
    bandpass: np.ndarray
    """Band-pass before demodulation (SOS rows; none: empty)."""
    lowpass: np.ndarray
    """Low-pass after demodulation (SOS rows)."""
    alphabeta: bool
    """Wang's improved structure: demodulate α and β, low-pass, then rotate by θ̂ (Eq. 22)."""


def sampled_admittance(R_s_ohm, L_H, T_s_s, delay_periods, omega):
    """Sampled current per voltage command of one R-L axis at ω [rad/s]: the command delay, the
    zero-order hold and 1/(R + sL) (exact for the average-value inverter)."""
    a = math.exp(-R_s_ohm * T_s_s / L_H)
    zi = np.exp(-1j * np.asarray(omega, dtype=float) * T_s_s)
    return zi ** delay_periods * (1.0 - a) / R_s_ohm * zi / (1.0 - a * zi)


def aligned_demodulation_phase(R_s_ohm, L_dh_H, L_qh_H, T_s_s, delay_periods, omega_h, bandpass):
    """Phase φ [rad] added to a pulsating-injection estimator's demodulation carrier (Szabó: cos(ω_h t + φ)
    against u_h sin ω_h t; Wang: sin(ω_h t + φ) against U_h cos ω_h t) that puts it in phase with the
    sampled q̂ current an angle error produces: φ = −π/2 + arg((Y_q − Y_d)·B) at ω_h, B the band-pass
    sections before demodulation (none: empty); 0 for the papers' continuous loops of lossless
    inductances."""
    y = (sampled_admittance(R_s_ohm, L_qh_H, T_s_s, delay_periods, omega_h)
         - sampled_admittance(R_s_ohm, L_dh_H, T_s_s, delay_periods, omega_h))
    return -math.pi / 2.0 + float(np.angle(y * sos_response(bandpass, omega_h, T_s_s)))


def carrier_loop(path):
    """The sampled estimator loop of ``path`` (module docstring), PI discrete as in pi_tracking_loop.
    A baseband model: it holds for ω well below ω_h, so searches stop at ω_h/10."""
    T_s, w_h = path.T_s_s, path.omega_h_rad_s
    rot = cmath.exp(1j * path.carrier_phase_difference_rad)

    def admittance(L, nu):
        return sampled_admittance(path.R_s_ohm, L, T_s, path.delay_periods, nu)

    def band(nu):
        return sos_response(path.bandpass, nu, T_s) if len(path.bandpass) else np.ones_like(nu, dtype=complex)

    def paths(omega):
        """Demodulated error per unit θ̂ (loop path) and per unit θ (input path). M: the q̂ voltage
        modulated before the q admittance; N: the d current turned after it; S: the speed voltage
        −ω_r·ψ_d of the turning rotor on the q axis, ψ_d the HF d flux over the period."""
        z = np.exp(1j * omega * T_s)
        y_d = admittance(path.L_d_H, w_h)
        M = 0.25 * path.u_star * (rot * admittance(path.L_q_H, omega + w_h) * band(omega + w_h)
                                  + np.conj(rot) * admittance(path.L_q_H, omega - w_h) * band(omega - w_h))
        N = 0.25 * path.u_star * (rot * y_d * band(omega + w_h) + np.conj(rot * y_d) * band(omega - w_h))
        psi_d = path.L_d_H * y_d * (cmath.exp(1j * w_h * T_s) + cmath.exp(2j * w_h * T_s)) / 2.0
        S = 0.25 * path.u_star * (
            rot * psi_d * admittance(path.L_q_H, omega + w_h) * band(omega + w_h)
            + np.conj(rot * psi_d) * admittance(path.L_q_H, omega - w_h) * band(omega - w_h))
        F = sos_response(path.lowpass, omega, T_s)
        gain = path.error_sign * path.injection_amplitude_V
        rotor = gain * F * (N - (M + 1j * omega * S) * z ** 1.5)
        if path.alphabeta:
            return gain * (F * M * z - N), rotor
        return gain * F * (M * z - N), rotor

    def integrator(omega):
        zi = np.exp(-1j * omega * T_s)
        return T_s * zi / (1.0 - zi)

    def rest(omega):
        return -integrator(omega) * paths(omega)[0]

    def discrete_pi(omega, T_i_s):
        if math.isinf(T_i_s):
            return 1.0
        return 1.0 + (T_s / T_i_s) / (1.0 - np.exp(-1j * omega * T_s))

    def input_path(omega):
        """Including the estimator's own update at the sample (θ̂ as it outputs it)."""
        loop, rotor = paths(omega)
        return -np.exp(1j * omega * T_s) * rotor / loop

    nyquist = 0.999 * math.pi / T_s
    return TrackingLoop("carrier model", rest, discrete_pi, input_path, min(0.1 * w_h, nyquist), nyquist)


@dataclass(frozen=True)
class Margins:
    crossover_rad_s: float
    phase_margin_deg: float
    gain_margin_dB: float
    """∞ when the phase never reaches −180° above the crossover."""


def margins(loop, A_p, T_i_s):
    """Gain crossover, phase margin and gain margin of ``loop`` with the PI (A_p, T_i)."""
    def magnitude_minus_one(w):
        return abs(loop.open_loop(A_p, T_i_s, w)) - 1.0

    from scipy.optimize import brentq
    crossover = brentq(magnitude_minus_one, 1e-2, loop.search_max_rad_s)
    phase_margin = 180.0 + math.degrees(loop.phase(A_p, T_i_s, crossover))
    grid = np.logspace(math.log10(crossover), math.log10(loop.search_max_rad_s), 20000)
    below = np.nonzero(loop.phase(A_p, T_i_s, grid) <= -math.pi)[0]
    if below.size == 0:
        return Margins(crossover, phase_margin, math.inf)
    gain_margin = -20.0 * math.log10(abs(loop.open_loop(A_p, T_i_s, grid[below[0]])))
    return Margins(crossover, phase_margin, gain_margin)


def tune_pi(loop, phase_margin_deg, crossover_rad_s):
    """A_p and T_i putting the crossover at ``crossover_rad_s`` with ``phase_margin_deg``: the PI's
    phase lag makes up the margin, its gain the magnitude. ValueError when the loop without PI already
    has less margin than asked (a PI only takes phase away)."""
    w = crossover_rad_s
    rest = loop.phase(1.0, math.inf, w)
    lag = -math.pi + math.radians(phase_margin_deg) - rest
    if lag >= 0.0:
        available = 180.0 + math.degrees(rest)
        raise ValueError(f"a phase margin of {phase_margin_deg:g}° at {w:g} rad/s is not reachable with a PI; "
                         f"the loop without it has {available:.1f}°")
    most = float(np.angle(loop.pi(w, 1e-12)))
    if lag <= most:
        raise ValueError(f"a phase margin of {phase_margin_deg:g}° at {w:g} rad/s would need a PI lag of "
                         f"{-math.degrees(lag):.1f}°, more than a PI gives ({-math.degrees(most):.1f}°): "
                         f"any PI leaves more margin there")
    from scipy.optimize import brentq
    T_i = brentq(lambda T: np.angle(loop.pi(w, T)) - lag, 1e-12, 1e9)
    A_p = 1.0 / abs(loop.open_loop(1.0, T_i, w))
    return A_p, T_i


def highest_crossover(loop, phase_margin_deg, pi_zero_ratio=10.0):
    """The highest crossover where ``phase_margin_deg`` holds with the PI zero ``pi_zero_ratio`` below it
    (a PI lag of atan(1/ratio))."""
    lag = math.atan(1.0 / pi_zero_ratio)
    grid = np.logspace(0, math.log10(loop.omega_max_rad_s), 4000)
    excess = 180.0 + np.degrees(loop.phase(1.0, math.inf, grid) - lag) - phase_margin_deg
    if excess[0] <= 0.0:
        raise ValueError(f"a phase margin of {phase_margin_deg:g}° is not reachable at any crossover")
    last = np.nonzero(excess > 0.0)[0][-1]
    if last == len(grid) - 1:
        return grid[-1]
    return float(np.interp(0.0, [excess[last + 1], excess[last]], [grid[last + 1], grid[last]]))


CARRIERS = {
    "synchronous": (-math.pi / 2.0, -1.0, False),
    "conventional": (math.pi / 2.0, 1.0, False),
    "improved": (math.pi / 2.0, 1.0, True),
}
"""How each pulsating-injection estimator maps onto the carrier model: (injection minus demodulation
carrier phase, error sign, αβ structure). Szabó injects u_h sin ω_h t and demodulates with u* cos ω_h t,
the PI gets 0 − î_qhf; Wang injects U_h cos ω_h t and demodulates with 2 sin ω_h t."""


def carrier_path(estimator, R_s_ohm, L_dh_H, L_qh_H, delay_periods):
    """The CarrierPath of a built estimator (``interface.Estimator``) on a motor with HF inductances
    L_dh, L_qh; KeyError for an estimator this model does not cover."""
    base = estimator.name.removesuffix("_aligned")
    if base not in CARRIERS:
        raise KeyError(f"estimator '{estimator.name}' has no PLL of this form "
                       f"(covered: {', '.join(CARRIERS)} and their _aligned variants)")
    phase, sign, alphabeta = CARRIERS[base]
    p = estimator.params
    u_star = getattr(p, "u_star", None) or p.demodulation_amplitude
    phase -= getattr(p, "demodulation_phase_rad", 0.0)
    return CarrierPath(R_s_ohm, L_dh_H, L_qh_H, p.T_s_s, delay_periods, p.omega_h_rad_s, p.injection_amplitude_V,
                       u_star, phase, sign, np.zeros((0, 6)) if alphabeta else p.bandpass, p.lowpass, alphabeta)


def fastest_pi(loop, phase_margin_deg, pi_zero_ratio=10.0):
    """(crossover, A_p, T_i): the highest crossover where the margin holds with the PI zero
    ``pi_zero_ratio`` below it, T_i = ratio/crossover. The margin is the one asked for, or more where
    the model's range of validity ends first."""
    crossover = highest_crossover(loop, phase_margin_deg, pi_zero_ratio)
    T_i = pi_zero_ratio / crossover
    return crossover, 1.0 / abs(loop.open_loop(1.0, T_i, crossover)), T_i


NOISE_GAIN_SETTLE_PERIODS = 40.0
"""Ours' noise gain sums the impulse response over this many periods of the loop's natural frequency."""
UNSETTLED_SHARE = 1e-3
"""A loop whose impulse response keeps this share of its energy in its last tenth does not settle."""
CLARKE_NOISE_SHARE = 5.0 / 6.0
"""The variance of one αβ current component per phase-current noise variance, averaged over α (= a, 1) and
β ((b − c)/√3, 2/3): the contract's Clarke on measured currents."""
TARGET_RMS_RAD = 0.02
TARGET_PEAK_RAD = 0.15
"""Ours' targets: what the predicted angle error must meet for the drive to run (docs/hf-demodulation.md §5)."""
PEAK_PER_RMS = 4.0
"""The peak of a run's noise-driven angle error per its RMS (a Gaussian's largest of ~10³ loop correlation
times: √(2 ln 10³) ≈ 3.7)."""


def injection_frame_noise_gain(gains, window_samples, delay_periods, T_s):
    """Σ h_k² of ours' loop (injection_frame item 6): the response h of θ̂ [rad] to one sample's contribution
    c (unit) to the fit's error, the fit averaging the last ``window_samples`` samples of c − θ̂ (θ̂ as issued
    ``delay_periods`` + 1 samples before), the loop's ``gains`` (k_p, k_i, k_a) [1/s, 1/s², 1/s³] updating as
    the estimator does (type 3 where k_a ≠ 0). Dimensionless: σ_θ² = var(c)·Σh²; ∞ where the loop does not
    settle (its last tenth still holds UNSETTLED_SHARE of the sum)."""
    kp, ki, ka = gains
    omega_n = math.sqrt(ki)
    steps = window_samples + delay_periods + int(NOISE_GAIN_SETTLE_PERIODS * 2.0 * math.pi / (omega_n * T_s))
    lag = delay_periods + 1
    theta = np.zeros(steps + 1)
    error_sum, omega, acceleration, total = 0.0, 0.0, 0.0, 0.0
    for k in range(steps):
        error_sum += (1.0 if k == 0 else 0.0) - theta[max(k - lag, 0)] * (k >= lag)
        if k >= window_samples:
            error_sum -= (1.0 if k == window_samples else 0.0) - theta[k - window_samples - lag] * (
                k - window_samples >= lag)
        eps = error_sum / window_samples
        acceleration += T_s * ka * eps
        omega += T_s * acceleration + T_s * ki * eps
        theta[k + 1] = theta[k] + T_s * (kp * eps + omega)
        total += theta[k + 1] ** 2
    tail = float(np.sum(theta[-(steps // 10):] ** 2))
    return total if math.isfinite(total) and tail <= UNSETTLED_SHARE * total else math.inf


def predicted_angle_error_rad(saliency_current_A, sensor_noise_A, noise_gain, carrier_samples):
    """Ours' noise-driven angle error RMS [rad] (docs/hf-demodulation.md §5): the fit's Δi holds the sensor
    noise differenced (variance 4σ²sin²(π/N) at the carrier, σ² = CLARKE_NOISE_SHARE × the phase noise²),
    the cross admittance g_dq = 2|Δ|·e from unit regressors over the window; each sample adds var(c) =
    σ²·2 sin²(π/N)/(T_s²U_h²Δ²) = σ²/(2 I_Δ²)·(sin(π/N)/(π/N))², I_Δ = U_h|Δ|/ω_h the saliency current [A];
    the loop passes var(c)·Σh² (injection_frame_noise_gain)."""
    if saliency_current_A <= 0.0 or not math.isfinite(noise_gain):
        return math.inf
    sigma = math.sqrt(CLARKE_NOISE_SHARE) * sensor_noise_A
    shape = math.sin(math.pi / carrier_samples) / (math.pi / carrier_samples)
    return sigma / saliency_current_A * shape * math.sqrt(0.5 * noise_gain)
