"""`drive tune pll --check`: the PLL of a pulsating-injection estimator, tuned from its models
(hf_estimator.pll_tuning), measured in closed loop in the one-process runner.

The check drives the shaft (imposed speed) through a stepped sine of the electrical angle,
θ = a·sin ω(t − t_i), one segment per frequency after a lead-in at standstill; each segment settles,
then θ and θ̂ are correlated with e^{−jωt} over whole periods. T(jω) = Θ̂/Θ is the closed loop from the
rotor angle to the estimate. By default the speed loop is set to 1 rad/s so that the cascade does not
close a second loop through the injection (docs/pll-tuning.md); the current loop runs as usual.
"""
import dataclasses
import math

import numpy as np

from drive_common.config.experiment import NON_IDEALITIES
from drive_common.config.scenario import parse_scenario
from drive_common.contract.log import COLUMN, LOG_COLUMNS
from drive_common.motor.commissioning import resolve_commissioning
from drive_common.motor.motor_file import load_motor
from drive_tools.runner.runner import build_drive
from hf_estimator.pll_model import margins
from hf_estimator.pll_tuning import largest_loop_filter, pll_design

IDEAL_PLANT_OFF = ("dead_time", "sensor_noise", "sensor_offset_gain", "adc")
"""What the ideal plant of the check leaves out (the models' assumptions); it keeps saturation (the
saliency of `wang_spmsm`) and the inverter's one-period delay."""


def motor_commissioning(motor, given=""):
    """The commissioning record the drive would load for a motor (a shipped name or a motor file;
    drive_common.motor.commissioning.resolve_commissioning: the file ``given``, 'nameplate', or the default file,
    else the nameplate)."""
    return resolve_commissioning(load_motor(motor, "--motor").nameplate, given, "--commissioning")


def design_for_motor(motor, estimator_name, settings, T_s=1e-4, commissioning=""):
    """hf_estimator.pll_tuning.pll_design for a motor (a shipped name or a motor file): its nameplate,
    inverter, and its commissioning record (``motor_commissioning``); the design names the motor as given."""
    m = load_motor(motor, "--motor")
    design = pll_design(m.nameplate, motor_commissioning(m, commissioning), m.inverter, estimator_name, settings, T_s)
    return dataclasses.replace(design, motor=str(motor))


def largest_loop_filter_for_motor(motor, settings, phase_margin_deg, crossover_rad_s, model="carrier",
                                  commissioning=""):
    """hf_estimator.pll_tuning.largest_loop_filter for a motor (as ``design_for_motor``)."""
    m = load_motor(motor, "--motor")
    return largest_loop_filter(m.nameplate, motor_commissioning(m, commissioning), m.inverter, settings,
                               phase_margin_deg, crossover_rad_s, model)


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
    return parse_scenario(data, f"pll_check_{motor}", "PLL closed-loop check")


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
    scenario = dataclasses.replace(scenario, mode="imposed_speed", duration_s=k * T_s, initial_omega_m_rad_s=0.0)
    drive = build_drive(scenario)
    n_p = drive.controller.n_p
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
