"""The whole speed range scored (docs/full-speed.md): ``drive bench full-speed`` runs a scenario with the
blended estimator, injection only and the back-EMF observer only, and scores the angle error and the HF
current per speed band; ``drive bench injection-cost`` measures what each estimator's injection costs at
low speed (HF current RMS, the copper loss it causes) and the least amplitude at which ours keeps its
targets."""
import dataclasses
import math

import numpy as np

from drive_common.contract.estimator_records import ESTIMATE_FIELDS, estimates
from drive_common.contract.estimator_states import LEADER_BACKEMF
from drive_common.contract.log import COLUMN
from drive_common.runtime.bound_kernels import bound
from drive_tools.runner.loop import replay_samples
from drive_tools.runner.runner import run_scenario, scenario_commissioning
from hf_estimator.registry import make_estimator

from .metrics import _mask, angle_error, compute_metrics, windows
from .recorded_inputs import logged_inputs

SPEED_BANDS = ((0.0, 0.02), (0.02, 0.1), (0.1, 0.3), (0.3, 1.1))
"""|ω_m| per rated speed: standstill and through zero; low; the handover region; high speed."""
TARGETS = {"angle_error_rms": 0.02, "angle_error_peak": 0.15}
"""Issue 20's targets [rad el.]: steady RMS, peak over the run after its start; and no lock loss."""
COMPARED = ("full_speed", "injection_frame", "flux_observer")
AMPLITUDES_V = (10.0, 7.0, 5.0, 4.0, 3.0, 2.5, 2.0, 1.5, 1.0, 0.7, 0.5)
"""Ours' amplitude sweep for the least one that keeps the targets, largest first."""


def carrier_samples(scenario):
    """Samples per period of the scenario's injection carrier."""
    return int(round(1.0 / (scenario.injection["frequency_Hz"] * scenario.T_s)))


def hf_current(log, n_p, samples_per_period):
    """|i_hf| per sample [A]: the true currents in the true rotor frame less their moving average over
    one carrier period (which removes a carrier whole and keeps the fundamental)."""
    i_alpha = log[:, COLUMN["i_a"]]
    i_beta = (log[:, COLUMN["i_b"]] - log[:, COLUMN["i_c"]]) / math.sqrt(3.0)
    dq = (i_alpha + 1j * i_beta) * np.exp(-1j * n_p * log[:, COLUMN["theta_m"]])
    n = max(1, int(samples_per_period))
    kernel = np.ones(n) / n
    average = np.convolve(dq.real, kernel, "same") + 1j * np.convolve(dq.imag, kernel, "same")
    return np.abs(dq - average)


def band_scores(log, scenario, n_p, hf):
    """Per SPEED_BANDS band over the samples after the scenario's start: share of the run, angle error
    RMS and peak [rad el.], HF current RMS [A] (``hf``: the run's hf_current), the copper loss it causes
    [W] (1.5 R_s |i_hf|², the nameplate's R_s) and the share of samples the back-EMF observer led."""
    plate = scenario.motor.nameplate
    t = log[:, COLUMN["t"]]
    after = t >= scenario.metrics_start_s
    speed = np.abs(log[:, COLUMN["omega_m"]]) / (plate.rated_speed_rpm * math.pi / 30.0)
    error = angle_error(log, n_p)
    rows = []
    for low, high in SPEED_BANDS:
        m = after & (speed >= low) & (speed < high)
        if not m.any():
            rows.append({"band": [low, high], "fraction": 0.0})
            continue
        rows.append({"band": [low, high], "fraction": float(m.sum() / after.sum()),
                     "angle_error_rms": float(np.sqrt(np.mean(error[m] ** 2))),
                     "angle_error_peak": float(np.max(np.abs(error[m]))),
                     "hf_current_rms_A": float(np.sqrt(np.mean(hf[m] ** 2))),
                     "hf_copper_loss_W": float(1.5 * plate.R_s_ohm * np.mean(hf[m] ** 2)),
                     "observer_led_fraction": float(np.mean(log[m, COLUMN["leader"]] == LEADER_BACKEMF))})
    return rows


def observer_led(log, hf):
    """HF current RMS [A] (``hf``: the run's hf_current) where the observer leads with the injection faded
    out, where it leads with the injection on (the overlap: rising until the back-EMF stands clear, falling
    before ours must lead), and how long the overlap lasted [s] (None where there is none)."""
    leads = log[:, COLUMN["leader"]] == LEADER_BACKEMF
    quiet = leads & (log[:, COLUMN["injection_amplitude"]] == 0.0)
    injecting = leads & ~quiet

    def rms(mask):
        return float(np.sqrt(np.mean(hf[mask] ** 2))) if mask.any() else None
    return {"hf_current_rms_observer_quiet_A": rms(quiet), "hf_current_rms_observer_injecting_A": rms(injecting),
            "observer_led_injecting_s": float(injecting.sum() * (log[1, 0] - log[0, 0]))}


def _whole_run(result):
    m = compute_metrics(result)
    return {key: m[key] for key in ("angle_error_rms", "angle_error_bias", "angle_error_peak", "lock_lost_s",
                                    "lock_lost", "speed_error_rms", "observable_fraction")}


def meets_targets(scores):
    """True when a run's whole-run scores keep TARGETS and the lock."""
    return scores["angle_error_rms"] is not None and not scores["lock_lost_s"] and not scores["lock_lost"] and all(
        scores[key] is not None and scores[key] <= limit for key, limit in TARGETS.items())


def observer_on_run(result, scenario):
    """The back-EMF observer alone on a closed-loop run's measured currents and applied voltages, open loop
    (as replay): its log (LOG_COLUMNS), scored against the run's ground truth."""
    commissioning = result.commissioning
    inverter = scenario.motor.inverter._replace(delay_periods=scenario.drive_delay_periods())
    e = make_estimator("flux_observer", scenario.motor.nameplate, scenario.T_s, {}, commissioning, inverter)
    currents, u_applied, whole = logged_inputs(result.log, scenario.drive_delay_periods())
    out = estimates(len(currents))
    bound(replay_samples, e.step)(e.core(e.state.copy()), currents, u_applied, np.zeros((len(currents), 2)), whole,
                                  commissioning.calibration(), out)
    log = result.log.copy()
    for field in ESTIMATE_FIELDS:
        log[:, COLUMN[field]] = out[field]
    return log


def full_speed_comparison(scenario, progress=None):
    """The scenario run closed loop with each of COMPARED, and the observer alone on the blended run's
    samples: whole-run scores, whether they keep TARGETS, and per-band scores."""
    carrier = carrier_samples(scenario)
    runs = []
    blended = None
    for i, name in enumerate(COMPARED):
        result = run_scenario(dataclasses.replace(scenario, estimator=name, estimator_settings={}))
        scores = _whole_run(result)
        started = bool(np.any(result.log[:, COLUMN["state"]] == 3.0))
        hf = hf_current(result.log, result.n_p, carrier)
        runs.append({"estimator": name, "loop": "closed", "started": started, **scores,
                     "meets_targets": started and meets_targets(scores),
                     "bands": band_scores(result.log, scenario, result.n_p, hf), **observer_led(result.log, hf)})
        if name == "full_speed":
            blended = result
        if progress:
            progress((i + 1) / (len(COMPARED) + 1))
    log = observer_on_run(blended, scenario)
    errors = angle_error(log, blended.n_p)[log[:, 0] >= scenario.metrics_start_s]
    runs.append({"estimator": "flux_observer", "loop": "open, on the full_speed run's samples",
                 "angle_error_rms": float(np.sqrt(np.mean(errors ** 2))),
                 "angle_error_peak": float(np.max(np.abs(errors))),
                 "bands": band_scores(log, scenario, blended.n_p, hf_current(log, blended.n_p, carrier))})
    if progress:
        progress(1.0)
    return {"scenario": scenario.name, "motor": scenario.motor.name, "duration_s": scenario.duration_s,
            "commissioning": scenario_commissioning(scenario).source, "runs": runs}


def injection_cost(scenario, estimators, progress=None):
    """At the scenario's speed (``wang_100rpm``: 100 rpm): per estimator its injection amplitude, HF
    current RMS [A] and copper loss [W] over the steady windows, its scores and whether they keep TARGETS;
    then ours (saliency_snr_min 0: the amplitude as asked) over AMPLITUDES_V, and the least that keeps them."""
    carrier = carrier_samples(scenario)
    steady, _ = windows(scenario)
    plate = scenario.motor.nameplate

    def measure(s, label):
        result = run_scenario(s)
        mask = _mask(result.log[:, 0], steady)
        hf = hf_current(result.log, result.n_p, carrier)[mask]
        scores = _whole_run(result)
        amplitude = result.log[mask, COLUMN["injection_amplitude"]]
        return {"estimator": label, "amplitude_V": float(np.median(amplitude)) if amplitude.size else None,
                "hf_current_rms_A": float(np.sqrt(np.mean(hf ** 2))),
                "hf_copper_loss_W": float(1.5 * plate.R_s_ohm * np.mean(hf ** 2)), **scores,
                "meets_targets": meets_targets(scores)}
    steps = len(estimators) + len(AMPLITUDES_V)
    rows, sweep = [], []
    for name in estimators:
        rows.append(measure(dataclasses.replace(scenario, estimator=name, estimator_settings={}), name))
        if progress:
            progress(len(rows) / steps)
    for amplitude in AMPLITUDES_V:
        s = dataclasses.replace(scenario, estimator="injection_frame", estimator_settings={"saliency_snr_min": 0.0},
                                injection={**scenario.injection, "amplitude_V": amplitude})
        sweep.append(measure(s, f"injection_frame at {amplitude:g} V"))
        if progress:
            progress((len(rows) + len(sweep)) / steps)
    kept = [r for r in sweep if r["meets_targets"]]
    least = min(kept, key=lambda r: r["amplitude_V"]) if kept else None
    return {"scenario": scenario.name, "motor": scenario.motor.name, "estimators": rows, "sweep": sweep,
            "least_amplitude_V": least["amplitude_V"] if least else None,
            "least": least}
