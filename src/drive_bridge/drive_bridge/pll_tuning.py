"""`drive tune pll`: the PLL of a pulsating-injection estimator, modelled (Szabó §2.4 and our carrier
model, ``hf_estimator.pll_model``), tuned, and checked in closed loop in the one-process runner.

The check drives the shaft (imposed speed) through a stepped sine of the electrical angle,
θ = a·sin ω(t − t_i), one segment per frequency after a lead-in at standstill; each segment settles,
then θ and θ̂ are correlated with e^{−jωt} over whole periods. T(jω) = Θ̂/Θ is the closed loop from the
rotor angle to the estimate. By default the speed loop is set to 1 rad/s so that the cascade does not
close a second loop through the injection (see README); the current loop runs as usual.
"""
import dataclasses
import math

import numpy as np

from hf_estimator.common import commission
from hf_estimator.interface import make_estimator
from hf_estimator.pll_model import (carrier_loop, carrier_path, fastest_pi, highest_crossover, margins,
                                    pll_process,
                                    sos_response, szabo_loop, tune_pi)
from pmsm_plant.presets import get_preset, plant_parameters

from .loop import COLUMN, LOG_COLUMNS
from .runner import build_drive
from .scenario import NON_IDEALITIES, parse_scenario

IDEAL_PLANT_OFF = ("dead_time", "sensor_noise", "sensor_offset_gain", "adc")
"""What the ideal plant of the check leaves out (the models' assumptions); it keeps saturation (the
saliency of `wang_spmsm`) and the inverter's one-period delay."""

MAPPINGS = {
    "synchronous": "Szabó's own loop (Fig. 4): u_h sin ω_h t on d̂, î_q̂ band-pass, × u* cos ω_h t, "
                   "1/(sT_f + 1), PI A_p(1 + 1/(sT_i)), integrator",
    "conventional": "Szabó's loop with Wang's parts: U_h cos ω_h t on d̂, î_q̂ band-pass, × 2 sin ω_h t "
                    "(u* = 2), Butterworth low-pass in place of 1/(sT_f + 1), PI k_p = A_p, k_i = A_p/T_i",
    "improved": "not of Szabó's form: α and β are demodulated and low-passed before the rotation by θ̂ "
                "(Eq. 22), so the loop also sees the d admittance through 1 − F (a high-pass Szabó's model "
                "lacks); only the carrier model covers it",
}


@dataclasses.dataclass(frozen=True)
class PllDesign:
    motor: str
    estimator: object
    """The built estimator (its params hold the current gains k_p, k_i)."""
    path: object
    """Its ``CarrierPath``: what the models read of the drive and the estimator."""
    carrier: object
    szabo: object
    """Szabó's model of the loop (None for `improved`)."""

    @property
    def current_gains(self):
        """(A_p, T_i) the estimator runs with now."""
        p = self.estimator.params
        return p.kp, (p.kp / p.ki if p.ki > 0.0 else math.inf)


def pll_design(motor, estimator_name, settings, T_s=1e-4):
    """Both models of ``estimator_name``'s loop on ``motor`` with estimator ``settings``; the HF
    inductances are what commissioning measures on the motor, R is the nameplate's."""
    preset = get_preset(motor)
    machine, inverter, _ = plant_parameters(preset, {key: True for key in NON_IDEALITIES})
    commissioning = commission(machine, preset.current_limit_A)
    estimator = make_estimator(estimator_name, preset, T_s, settings, 0.0, 0.0, commissioning,
                               inverter.delay_periods)
    R = preset.nameplate.R_s_ohm
    path = carrier_path(estimator, R, commissioning.L_dh_H, commissioning.L_qh_H, inverter.delay_periods)
    szabo = None
    if not path.alphabeta:
        process = pll_process(R, commissioning.L_dh_H, commissioning.L_qh_H,
                              path.omega_h_rad_s / (2.0 * math.pi), path.u_h_V, path.u_star)
        szabo = szabo_loop(process, lambda omega: sos_response(path.lowpass, omega, T_s),
                           0.999 * math.pi / T_s)
    return PllDesign(motor, estimator, path, carrier_loop(path), szabo)


def largest_loop_filter(motor, settings, phase_margin_deg, crossover_rad_s, model="carrier"):
    """`synchronous`'s largest T_f [s] (most ripple filtering) with which ``model``'s loop still reaches
    ``phase_margin_deg`` at ``crossover_rad_s`` (PI zero a decade below); ValueError if none does."""
    def reaches(T_f):
        design = pll_design(motor, "synchronous", {**settings, "T_f_s": T_f})
        try:
            return highest_crossover(getattr(design, model), phase_margin_deg) >= crossover_rad_s
        except ValueError:
            return False

    low, high = 1e-6, 1e-2
    if not reaches(low):
        raise ValueError(f"--crossover: {crossover_rad_s:g} rad/s at {phase_margin_deg:g}° is out of reach "
                         f"even with T_f = {low:g} s")
    for _ in range(40):
        middle = math.sqrt(low * high)
        low, high = (middle, high) if reaches(middle) else (low, middle)
    return low


def tuned(loop, phase_margin_deg, crossover_rad_s=None):
    """{A_p, T_i_s, margins} for the request; crossover None: the highest reaching the margin."""
    if crossover_rad_s is None:
        _, A_p, T_i = fastest_pi(loop, phase_margin_deg)
    else:
        A_p, T_i = tune_pi(loop, phase_margin_deg, crossover_rad_s)
    return {"A_p": float(A_p), "T_i_s": float(T_i), **dataclasses.asdict(margins(loop, A_p, T_i))}


SPEED_LOOPS = {"off": {"gains": "rule", "speed_bandwidth_rad_s": 1.0}, "rule": {"gains": "rule"},
               "table2": {"gains": "szabo_table2"}}
"""The controller during the check: the speed loop at 1 rad/s (the estimator loop alone), the
controller's default rule, or Szabó's Table 2 cascade (speed loop fed the PLL's speed)."""


def check_scenario(motor, estimator_name, settings, T_s=1e-4, ideal_plant=False, speed_loop="off"):
    """The scenario of the closed-loop check (durations are set by the measurement)."""
    data = {"motor": motor, "estimator": {"type": estimator_name, "settings": settings},
            "duration_s": 1.0, "sampling_period_s": T_s, "mode": "imposed_speed",
            "speed": {"unit": "rad_s", "points": [[0.0, 0.0]]},
            "controller": SPEED_LOOPS[speed_loop],
            "non_idealities": {key: not (ideal_plant and key in IDEAL_PLANT_OFF) for key in NON_IDEALITIES}}
    return parse_scenario(data, f"pll_check_{motor}", "drive tune pll --check")


@dataclasses.dataclass(frozen=True)
class MeasuredResponse:
    omega_rad_s: np.ndarray
    T: np.ndarray
    """θ̂/θ at each ω (complex)."""
    samples: int


def check_frequencies(T_s):
    """24 frequencies, log-spaced from 10 rad/s to 3000 rad/s (or 0.1·Nyquist)."""
    return np.logspace(1.0, math.log10(min(3000.0, 0.1 * math.pi / T_s)), 24)


def measure_tracking_response(scenario, omegas_rad_s, amplitude_e_rad=0.05, lead_in_s=0.3,
                              settle_periods=2.0, measure_periods=3.0, min_measure_s=0.05, progress=None):
    """Stepped-sine measurement of θ̂/θ on ``scenario``'s drive (its speed and load tables are replaced)."""
    T_s = scenario.T_s
    segments, k = [], int(round(lead_in_s / T_s))
    for w in omegas_rad_s:
        period = 2.0 * math.pi / w
        settle = int(math.ceil(settle_periods * period / T_s))
        measure = int(round(max(measure_periods, math.ceil(min_measure_s / period)) * period / T_s))
        segments.append((w, k, k + settle, k + settle + measure))
        k += settle + measure
    scenario = dataclasses.replace(scenario, mode="imposed_speed", duration_s=k * T_s,
                                   initial_angle_error_e_rad=0.0, initial_omega_m_rad_s=0.0)
    drive = build_drive(scenario)
    n_p = drive.machine.n_p
    drive.speed_ref[:] = 0.0
    drive.tau_load[:] = 0.0
    for w, start, _, end in segments:
        tau = (np.arange(start, end) - start) * T_s
        drive.speed_ref[start:end] = amplitude_e_rad / n_p * w * np.cos(w * tau)
    log = np.zeros((k, len(LOG_COLUMNS)))
    done = 0
    for _, _, _, end in segments:
        drive.run(done, end, log[done:end])
        done = end
        if progress:
            progress(end / k)
    theta = n_p * log[:, COLUMN["theta_m"]]
    theta_hat = log[:, COLUMN["theta_e_hat"]]
    T = []
    for w, _, begin, end in segments:
        carrier = np.exp(-1j * w * np.arange(begin, end) * T_s)
        rotor = np.sum((theta[begin:end] - theta[begin:end].mean()) * carrier)
        estimate = np.sum((theta_hat[begin:end] - theta_hat[begin:end].mean()) * carrier)
        T.append(estimate / rotor)
    return MeasuredResponse(np.asarray(omegas_rad_s, dtype=float), np.asarray(T), k)


def closed_loop_figures(omega, T, input_ratio=None):
    """Bandwidth (|T| first below −3 dB) and resonance peak of θ̂/θ from its values at ascending ω,
    interpolated in log ω. With ``input_ratio`` (the input path over the loop path, from a model) also
    the crossover and phase margin of L = T/(ratio − T). NaN where the frequencies do not reach."""
    omega = np.asarray(omega, dtype=float)
    log_w = np.log(omega)
    dB = 20.0 * np.log10(np.abs(T))
    peak = int(np.argmax(dB))
    figures = {"bandwidth_rad_s": math.nan, "peak_dB": float(dB[peak]), "peak_rad_s": float(omega[peak]),
               "crossover_rad_s": math.nan, "phase_margin_deg": math.nan}
    below = np.nonzero(dB < -3.0103)[0]
    if below.size and below[0] > 0:
        i = below[0]
        figures["bandwidth_rad_s"] = math.exp(np.interp(-3.0103, [dB[i], dB[i - 1]],
                                                        [log_w[i], log_w[i - 1]]))
    if input_ratio is not None:
        L = T / (input_ratio - T)
        mag = np.log(np.abs(L))
        below = np.nonzero(mag < 0.0)[0]
        if below.size and below[0] > 0:
            i = below[0]
            x = np.interp(0.0, [mag[i], mag[i - 1]], [log_w[i], log_w[i - 1]])
            phase = np.interp(x, [log_w[i - 1], log_w[i]], np.unwrap([np.angle(L[i - 1]), np.angle(L[i])]))
            figures["crossover_rad_s"] = math.exp(x)
            figures["phase_margin_deg"] = (180.0 + math.degrees(phase)) % 360.0
    return figures


def model_figures(loop, A_p, T_i_s, omega_max):
    """closed_loop_figures of a model's T on a dense grid, with its exact crossover and margin."""
    grid = np.logspace(0.0, math.log10(omega_max), 3000)
    figures = closed_loop_figures(grid, loop.closed_loop(A_p, T_i_s, grid))
    m = margins(loop, A_p, T_i_s)
    figures.update(crossover_rad_s=m.crossover_rad_s, phase_margin_deg=m.phase_margin_deg)
    return figures


def check_tuning(design, A_p, T_i_s, settings, ideal_plant=False, speed_loop="off", progress=None):
    """Measured closed-loop figures of the estimator run with (A_p, T_i) against both models'."""
    name = design.estimator.name
    params = design.estimator.params
    scenario = check_scenario(design.motor, name, {**settings, "A_p": A_p, "T_i_s": T_i_s},
                              params.T_s_s, ideal_plant, speed_loop)
    omega = check_frequencies(params.T_s_s)
    measured = measure_tracking_response(scenario, omega, progress=progress)
    result = {"A_p": A_p, "T_i_s": T_i_s, "plant": "ideal" if ideal_plant else "full",
              "speed_loop": speed_loop,
              "samples": measured.samples,
              "measured": closed_loop_figures(omega, measured.T, design.carrier.input_path(omega)),
              "carrier_model": model_figures(design.carrier, A_p, T_i_s, omega[-1])}
    if design.szabo is not None:
        result["szabo_model"] = model_figures(design.szabo, A_p, T_i_s, omega[-1])
    result["response"] = {"omega_rad_s": omega.tolist(), "T_re": measured.T.real.tolist(),
                          "T_im": measured.T.imag.tolist()}
    return result
