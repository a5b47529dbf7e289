"""``drive bench replay``: estimators run on a recording's measured currents and applied voltages,
scored against its ground truth (docs/recordings.md).

Replay cannot steer the recorded voltage: each estimator meets the excitation the recording drive
applied. Whether that measures it depends on what it needs (hf_estimator EXCITATION_NEEDS): a
demodulating method needs its own carrier on its own estimated axis, which only the recording's own
estimator had (another one's q̂ current follows the recorded injection axis through the Σ term, so its
replay would measure the recording's estimator); ours fits the admittance to any known voltage, the Σ
term included; ``sensored`` needs the ground truth. Only applicable estimators are scored, and ``lost``
means a real loss of lock (|θ_e − θ̂_e| > π/2 from the first scored window on, with ground truth; else a
loss the estimator reported there). An estimator other than the recording's cannot run its own polarity
test on a recording: it takes the magnet's polarity as the recording drive resolved it once that drive
tracks (hf_estimator.startup item 5).
"""
import math
import time

import numpy as np

from drive_common.contract.estimator_records import ESTIMATE_FIELDS, estimates
from drive_common.contract.estimator_states import TRACKING
from drive_common.contract.log import COLUMN
from drive_common.contract.run_result import RunResult
from drive_common.motor.nameplate import InverterRating
from drive_common.motor.scaled_loops import scaled_loops
from drive_common.runtime.bound_kernels import bound
from drive_tools.runner.loop import replay_samples
from hf_estimator.build import SCALED_TRACKING, drive_estimator, scaled_tracking
from hf_estimator.interface import excitation_need, injects

from .excitation import MAX_CARRIER_PHASE_RAD, MIN_CARRIER_FRACTION, carrier_match
from .metrics import _mask, angle_error, angle_scores, reported_losses
from .recorded_inputs import replay_inputs
from .recording import held

TIMED_RUNS = 3
"""Each estimator replays the bag this many times from its fresh state; the fastest run is reported."""
LOCK_BAND_RAD = math.pi / 8
"""Time to lock: from the start until |angle error| stays within this band to the end. Every saliency
tracker's error signal goes as sin 2Δθ; within π/8 its slope is still ≥ 0.71 of the small-signal one."""
FAILURES = ("failed:", "too slow:", "answered NaN")
"""How a replay entry's reason begins where the estimator itself failed on the bag."""
PROBE_SAMPLES = 2000
"""Samples timed first: an estimator slower per sample than the recording's sampling period is not replayed
further (it could not run the drive it is measured for)."""
SCORED = ("angle_error_rms", "angle_error_bias", "angle_error_peak", "speed_error_rms")


def replayed_estimator(recording, name, forced=False, own_startup=True):
    """The estimator ``name`` built as the recording drive would have built it (its motor, sample period,
    delay, commissioning and injection); the recording's own estimator keeps its recorded settings (the
    drive's whole settings where its drive_config states them) and start-up (``own_startup`` false: it too
    takes the polarity from the recording), any other takes the polarity from the recording and, where the
    drive scales its loops to the motor (ours), those loops within the recording's carrier. ``forced``: built
    past the drive's refusal to run it on this motor (`drive run --force`)."""
    own = name == recording.estimator
    inverter = InverterRating(U_dc_V=recording.U_dc_V, delay_periods=recording.delay_periods)
    settings = dict(recording.estimator_settings) if own else {}
    if injects(name):
        if not (own and recording.settings_stated):
            settings = {**recording.injection, **settings}
        if not own and name in SCALED_TRACKING:
            loops = scaled_loops(recording.commissioning.refined(recording.nameplate), inverter, recording.T_s)
            settings.update(scaled_tracking(name, loops, recording.injection.get("frequency_Hz", math.inf)))
        if not (own and own_startup):
            settings["polarity_from_recording"] = True
        if forced:
            settings["run_refused"] = True
    return drive_estimator(name, recording.nameplate, recording.T_s, settings, recording.commissioning, inverter,
                           recording.controller_settings)


def applicability(recording, name, frequency, requested, scored):
    """(applicable, reason) of replaying the estimator ``name`` (its carrier ``frequency`` [Hz]) on the
    recording; ``requested``: the injection it asked for in the replay (n × 2), ``scored``: the scored
    samples."""
    need = excitation_need(name)
    excitation = recording.excitation
    if need == "encoder":
        if recording.ground_truth:
            return True, "reads the recorded ground truth as its encoder"
        return False, "needs the ground truth (rotor_state) as its encoder; the bag has none"
    if need == "backemf":
        return True, "needs no injection: a back-EMF model of the applied voltage and the currents (at speed only)"
    if excitation["kind"] == "none":
        return False, "the recording holds no injection, and this estimator needs one"
    described = f"{excitation['kind']} injection at {excitation['frequency_Hz']:.0f} Hz"
    if need == "any":
        return True, f"fits any injection whose voltage is known; the recording's: {described}"
    if name == recording.estimator:
        if not recording.estimator_settings and recording.scenario is None:
            return True, ("the recording's own estimator on its own excitation (with its default settings: the "
                          "bag states none)")
        return True, "the recording's own estimator on its own excitation (a faithful replay)"
    share, phase = carrier_match(recording.carrier, requested, frequency, recording.T_s, scored)
    if share >= MIN_CARRIER_FRACTION and phase is not None and phase <= MAX_CARRIER_PHASE_RAD:
        return False, (f"its carrier is in the recording ({share:.0%} of the recorded carrier at {frequency:.0f} Hz, "
                       f"{math.degrees(phase):.0f}° from its carrier phase), but on the recording estimator's "
                       f"axis: its demodulated q̂ current follows that axis (the Σ·sin(θ̂_rec − θ̂) term), so "
                       f"replay would measure the recording's estimator, not it")
    found = f"{share:.0%} at {frequency:.0f} Hz" + (f", {math.degrees(phase):.0f}° from its carrier phase"
                                                     if phase is not None else "")
    return False, (f"demodulates its own carrier on its own axis; the recording holds a {described} ({found})")


def replay(recording, estimators):
    """Replay each estimator on a Recording (drive_tools.evaluation.recording) → ([entry dict], [RunResult, or
    None for an estimator that failed]). An estimator that raises, answers NaN or steps slower than the
    recording's sampling period is reported so in its entry (applicable False, the reason), never aborting the
    others (a plugin, docs/estimator-plugins.md)."""
    inputs = replay_inputs(recording)
    log0 = recording.log
    n_p = recording.n_p
    encoder = (held(n_p * log0[:, COLUMN["theta_m"]]), held(n_p * log0[:, COLUMN["omega_m"]]))
    unresolved = log0[:, COLUMN["state"]] != TRACKING
    unresolved &= np.isfinite(log0[:, COLUMN["state"]])
    estimate = (held(np.where(unresolved, np.nan, log0[:, COLUMN["theta_e_hat"]]), np.isnan(log0[:, COLUMN["state"]])),
                held(log0[:, COLUMN["omega_e_hat"]]))
    entries, results = [], []
    for name in estimators:
        reference = np.column_stack(encoder if excitation_need(name) == "encoder" else estimate)
        try:
            entry, result = _replay_one(recording, name, inputs, reference)
        except NotBuilt as refusal:
            entry, result = failed_entry(name, str(refusal), 0, None), None
        except Exception as error:  # an estimator's own failure (a plugin's, whatever it raises) is its entry's
            entry = failed_entry(name, f"failed: {type(error).__name__}: "
                                       f"{str(error).splitlines()[0] if str(error) else ''}", 0, None)
            result = None
        entries.append(entry)
        results.append(result)
    return entries, results


def failed_entry(name, reason, samples, samples_per_second):
    """The replay entry of an estimator that failed on a bag (FAILURES: ``reason``), not applicable there."""
    return {"estimator": name, "applicable": False, "reason": reason, "samples": samples,
            "samples_per_second": samples_per_second, "observable_fraction": None}


def _replay_one(recording, name, inputs, reference):
    """(entry, RunResult) of estimator ``name`` replayed on ``recording``'s ``inputs`` (replay_inputs) with the
    ``reference`` angle and speed its polarity may take (n × 2)."""
    currents, u_applied, whole = inputs
    log0, truth, n_p = recording.log, recording.ground_truth, recording.n_p
    t = log0[:, COLUMN["t"]]
    scored = _mask(t, recording.windows)
    calibration = recording.commissioning.calibration()
    e, refused = _built(recording, name)
    out = estimates(len(currents))
    bound(replay_samples, e.step)(e.core(e.state.copy()), currents[:2], u_applied[:2], reference[:2], whole[:2],
                                  calibration, out[:2])
    probe = min(len(currents), PROBE_SAMPLES)
    start = time.perf_counter()
    bound(replay_samples, e.step)(e.core(e.state.copy()), currents[:probe], u_applied[:probe], reference[:probe],
                                  whole[:probe], calibration, out[:probe])
    per_sample_s = (time.perf_counter() - start) / probe
    T_s = recording.T_s
    if per_sample_s > T_s:
        return failed_entry(name, f"too slow: {1e6 * per_sample_s:.0f} µs per sample, more than the recording's "
                                  f"sampling period of {1e6 * T_s:.0f} µs", 0, 1.0 / per_sample_s), None
    wall = _timed_replay(e, inputs, reference, calibration, out)
    departed = startup_departure(log0[:, COLUMN["state"]], out["state"]) if name == recording.estimator else None
    if departed is not None and injects(name):
        e, refused = _built(recording, name, own_startup=False)
        wall = _timed_replay(e, inputs, reference, calibration, out)
        lost = int((~np.isfinite(log0[:departed + 1][:, [COLUMN["i_a_meas"], COLUMN["u_alpha"]]]).all(axis=1)).sum())
        refused += (f"; its replayed start-up left the recorded one at sample {departed} ({lost} of the samples "
                    f"before it lost in the recording): replayed with the polarity taken from the recording, as "
                    f"another estimator is")
    injection = np.column_stack((out["u_inj_alpha"], out["u_inj_beta"]))
    applicable, reason = applicability(recording, name, e.injection_frequency_Hz, injection, scored)
    answered = np.column_stack([out[field] for field in ("theta_e_hat", "omega_e_hat", "u_inj_alpha",
                                                         "u_inj_beta")])
    broken = whole & ~np.isfinite(answered).all(axis=1)
    if applicable and broken.any():
        return failed_entry(name, f"answered NaN or ∞ from sample {int(np.argmax(broken))} on", int(whole.sum()),
                            len(currents) / wall), None
    log = log0.copy()
    for field in ESTIMATE_FIELDS:
        log[:, COLUMN[field]] = out[field]
    scores = angle_scores(log, n_p, recording.windows, recording.start_s)
    entry = {"estimator": name, "applicable": applicable, "reason": reason + refused, "samples": int(whole.sum()),
             "samples_per_second": len(currents) / wall,
             "observable_fraction": scores["observable_fraction"] if applicable else None}
    if applicable:
        if truth:
            entry.update({key: scores[key] for key in SCORED})
            entry["time_to_lock_s"] = time_to_lock(log, n_p)
            entry["lost"] = bool(scores["lock_lost_s"])
        else:
            entry["lost"] = bool(reported_losses(log[t >= recording.start_s, COLUMN["state"]]))
    return entry, RunResult(recording.scenario, name, log, wall, math.nan, recording_n_p=n_p)


class NotBuilt(Exception):
    """An estimator that cannot be built for a recording (its motor, sample period or recorded injection is
    outside what the estimator takes): not applicable there, not a failure of the estimator."""


def _timed_replay(e, inputs, reference, calibration, out):
    """Seconds of the fastest of TIMED_RUNS replays of the built estimator ``e`` into ``out``."""
    currents, u_applied, whole = inputs
    wall = math.inf
    for _ in range(TIMED_RUNS):
        core = e.core(e.state.copy())
        start = time.perf_counter()
        bound(replay_samples, e.step)(core, currents, u_applied, reference, whole, calibration, out)
        wall = min(wall, time.perf_counter() - start)
    return wall


def startup_departure(recorded, replayed):
    """The first sample up to the recording's first in tracking where the replayed start-up state code differs
    from the ``recorded`` one (both known), or None: a start-up's decisions (when to pulse, which pole) act on
    the voltage it applies, so a replay whose start-up departs from the recorded one meets pulses it did not
    time."""
    tracking = np.flatnonzero(recorded == TRACKING)
    end = tracking[0] + 1 if len(tracking) else len(recorded)
    differs = np.isfinite(recorded[:end]) & np.isfinite(replayed[:end]) & (recorded[:end] != replayed[:end])
    return int(np.argmax(differs)) if differs.any() else None


def _built(recording, name, own_startup=True):
    """(replayed_estimator of ``name``, "" or the note that the drive refuses it on this motor and it is
    replayed as `drive run --force` runs it): replay measures an estimator, it does not drive the motor.
    NotBuilt where the estimator refuses the recording's motor, sample period or injection (a ValueError or
    KeyError naming its setting, even forced)."""
    try:
        return replayed_estimator(recording, name, own_startup=own_startup), ""
    except (ValueError, KeyError) as error:
        first = str(error).strip("'\"").splitlines()[0]
        if injects(name):
            try:
                forced = replayed_estimator(recording, name, forced=True, own_startup=own_startup)
            except (ValueError, KeyError):
                pass
            else:
                return forced, f"; the drive refuses it on this motor ({first}): replayed as `drive run --force` " \
                               f"runs it"
        raise NotBuilt(f"cannot be built for this recording: {first}") from None


def time_to_lock(log, n_p):
    """Seconds until |θ_e − θ̂_e| stays within LOCK_BAND_RAD to the end; None if it never does."""
    outside = np.abs(angle_error(log, n_p)) > LOCK_BAND_RAD
    if outside[-1]:
        return None
    t = log[:, COLUMN["t"]]
    return float(t[np.nonzero(outside)[0][-1] + 1]) if outside.any() else 0.0


def summarise(per_bag, estimators):
    """One row per estimator over a corpus (``per_bag``: [{..., "results": replay entries}]): bags scored
    (applicable, with ground truth), not applicable (``failed`` among them: the estimator raised, answered NaN
    or was too slow), real lock losses, median and worst RMS, bias (worst:
    the largest magnitude) and peak, and the slowest replay speed."""
    rows = []
    for name in estimators:
        entries = [e for bag in per_bag for e in bag["results"] if e["estimator"] == name]
        scored = [e for e in entries if e["applicable"] and e.get("angle_error_rms") is not None]
        found = {key: [e[key] for e in scored if e.get(key) is not None]
                 for key in ("angle_error_rms", "angle_error_bias", "angle_error_peak")}
        median = {key: float(np.median(v)) if v else None for key, v in found.items()}
        worst = {key: float(max(v, key=abs)) if v else None for key, v in found.items()}
        speeds = [e["samples_per_second"] for e in entries if e["samples_per_second"] is not None]
        rows.append({"estimator": name, "bags": len(entries), "scored": len(scored),
                     "not_applicable": sum(not e["applicable"] for e in entries),
                     "lost": sum(bool(e.get("lost")) for e in entries),
                     "failed": sum(e["reason"].startswith(FAILURES) for e in entries if not e["applicable"]),
                     "rms_median": median["angle_error_rms"], "rms_worst": worst["angle_error_rms"],
                     "bias_median": median["angle_error_bias"], "bias_worst": worst["angle_error_bias"],
                     "peak_median": median["angle_error_peak"], "peak_worst": worst["angle_error_peak"],
                     "samples_per_second_min": min(speeds) if speeds else None})
    return rows
