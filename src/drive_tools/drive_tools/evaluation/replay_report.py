"""Reports of recordings scored (drive bench compare, replay): two recorded runs side by side, estimators
replayed on one recording or on a corpus; each as text lines."""
import math

from .metrics import angle_scores
from .report_text import formatted

COMPARED_METRICS = (("angle error RMS (steady)", "angle_error_rms", "rad"),
                    ("angle error bias (steady)", "angle_error_bias", "rad"),
                    ("angle error peak", "angle_error_peak", "rad"),
                    ("speed estimation error RMS", "speed_error_rms", "rad/s"),
                    ("observable fraction", "observable_fraction", ""))
REPLAY_COLUMNS = (
    ("samples/s", "replay speed, best of the timed runs"),
    ("observable", "fraction of samples after the scoring start the estimator reports tracking"),
    ("RMS [rad]", "electrical angle error θ_e − θ̂_e against the recorded rotor_state, scored windows"),
    ("bias [rad]", "its mean, scored windows"), ("peak [rad]", "its largest magnitude from the first window on"),
    ("speed RMS", "speed estimation error [rad/s], scored windows"),
    ("lock [s]", "time until |θ_e − θ̂_e| stays within π/8 to the end"),
    ("lost", "a real loss of lock: |θ_e − θ̂_e| > π/2 from the first window on (without ground truth: a loss "
             "the estimator reported)"))
"""The replay table's columns and what each means (printed under the table)."""


def compared_run(recording):
    """(a recorded run's entry for ``drive bench compare``: its recording report and COMPARED_METRICS, the
    run as drive_common.contract.run_result.RunResult for the plot)."""
    from drive_common.contract.run_result import RunResult

    entry = {**recording.report(), "estimator": recording.estimator or None}
    scores = angle_scores(recording.log, recording.n_p, recording.windows, recording.start_s)
    entry.update({key: scores[key] if entry["ground_truth"] or key == "observable_fraction" else None
                  for _, key, _ in COMPARED_METRICS})
    return entry, RunResult(recording.scenario, recording.estimator, recording.log, 0.0, math.nan,
                            recording_n_p=recording.n_p)


def compare_lines(report, names):
    entries = report["runs"]
    lines = [f"  {'':30s} {names[0]:>24s} {names[1]:>24s}"]
    for label, key, unit in (("scenario", "scenario", ""), ("estimator", "estimator", ""),
                             ("samples", "samples", "")) + COMPARED_METRICS:
        text = ["n/a" if v is None else f"{v:+.4f} {unit}" if isinstance(v, float) else str(v)
                for v in (e[key] for e in entries)]
        lines.append(f"  {label:30s} {text[0]:>24s} {text[1]:>24s}")
    for entry in entries:
        lines.append(f"  {entry['bag']}: windows {entry['windows']['source']}")
        if not entry["ground_truth"]:
            lines.append(f"  {entry['bag']}: no ground truth (rotor_state); only consistency is scored")
    if "plot" in report:
        lines.append(f"  plot: {report['plot']}")
    return lines


def replay_lines(report, recording):
    """One recording's replay (drive_tools.evaluation.replay.replay's entries under ``results``) as text lines."""
    e, entries, truth = recording.excitation, report["results"], recording.ground_truth
    lines = [f"replay of {recording.path}: {report['samples']} samples at {recording.T_s:g} s, motor "
             f"{recording.nameplate.name}, recorded with "
             f"{recording.estimator or 'an estimator the bag does not name'}",
             f"  recorded excitation (measured): {e['kind']}"
             + (f", {e['frequency_Hz']:.0f} Hz, {e['amplitude_V']:.3g} V" if e["kind"] != "none" else ""),
             "  from: " + "; ".join(f"{key} {value}" for key, value in recording.sources.items())]
    timing, lost = recording.timing, {k: v for k, v in recording.gaps["missing_samples"].items() if v}
    cut = recording.gaps["cut_samples"]
    lines.append(f"  stamps from {timing['epoch_s']:.6f} s, jitter {timing['jitter_rms_s'] * 1e6:.2g} µs RMS "
                 f"({timing['jitter_max_s'] * 1e6:.2g} max), {timing['off_grid_messages']} off the grid; missing "
                 f"samples: " + (", ".join(f"{k} {v}" for k, v in lost.items()) or "none")
                 + (f"; cut: the last {cut} samples incomplete, left off" if cut else ""))
    if not truth:
        lines.append("  no ground truth (rotor_state) in this bag: scored for consistency only")
    columns = [("samples/s", "samples_per_second", "{:,.0f}"), ("observable", "observable_fraction", "{:.3f}")]
    if truth:
        columns += [("RMS [rad]", "angle_error_rms", "{:.4f}"), ("bias [rad]", "angle_error_bias", "{:+.4f}"),
                    ("peak [rad]", "angle_error_peak", "{:.4f}"), ("speed RMS", "speed_error_rms", "{:.3f}"),
                    ("lock [s]", "time_to_lock_s", "{:.4f}")]
    columns.append(("lost", "lost", "{}"))
    lines.append(f"  {'estimator':22s}" + "".join(f"{label:>12s}" for label, _, _ in columns))
    for entry in entries:
        cells = [formatted(entry.get(key), fmt) for _, key, fmt in columns]
        lines.append(f"  {entry['estimator']:22s}" + "".join(f"{c:>12s}" for c in cells)
                     + ("" if entry["applicable"] else "   not applicable"))
    lines += [f"  {entry['estimator']}: {'' if entry['applicable'] else 'NOT APPLICABLE: '}{entry['reason']}"
              for entry in entries]
    shown = {label for label, _, _ in columns}
    lines += [f"  {label:>12s}: {explanation}" for label, explanation in REPLAY_COLUMNS if label in shown]
    lines += [f"  {key}: {report[key]}" for key in ("plot", "json") if key in report]
    return lines


def corpus_lines(report):
    """A corpus's replay (its ``summary`` per estimator) as text lines."""
    skipped = report["skipped"]
    lines = [f"replay of {report['bags']} bags ({report['pattern']})"
             + (f", {len(skipped)} paths skipped (not a bag, or not replayable: one line each above)"
                if skipped else ""),
             f"  {'estimator':22s}{'scored':>8s}{'n/a':>5s}{'failed':>7s}{'lost':>6s}{'RMS med':>10s}{'RMS worst':>11s}"
             f"{'bias med':>10s}{'bias worst':>11s}{'peak med':>10s}{'peak worst':>11s}{'samples/s':>12s}"]
    for row in report["summary"]:
        lines.append(f"  {row['estimator']:22s}{row['scored']:8d}{row['not_applicable']:5d}{row['failed']:7d}"
                     f"{row['lost']:6d}"
                     f"{formatted(row['rms_median'], '{:.4f}'):>10s}{formatted(row['rms_worst'], '{:.4f}'):>11s}"
                     f"{formatted(row['bias_median'], '{:+.4f}'):>10s}"
                     f"{formatted(row['bias_worst'], '{:+.4f}'):>11s}"
                     f"{formatted(row['peak_median'], '{:.4f}'):>10s}{formatted(row['peak_worst'], '{:.4f}'):>11s}"
                     f"{formatted(row['samples_per_second_min'], '{:,.0f}'):>12s}")
    lines.append("  scored: bags where it is applicable and the bag has ground truth; n/a: bags where it is not "
                 "applicable; failed: bags where the estimator raised, answered NaN or was slower than the bag's "
                 "sampling; lost: real losses of lock; worst bias: the largest magnitude; samples/s: the slowest "
                 "bag")
    if "json" in report:
        lines.append(f"  json: {report['json']}")
    if "report" in report:
        lines.append(f"  report: {report['report']['html']} (and report.json, bags.csv beside it)")
    return lines
