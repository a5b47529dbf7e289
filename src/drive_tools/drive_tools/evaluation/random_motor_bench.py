"""``drive bench motors --random N --seed S``: N motors drawn from the fixed distribution of
drive_tools.evaluation.random_motors, written as motor files, each tried as a robot builder would
(drive_tools.evaluation.motor_bench.motor_trial) in a pool of processes; one row per motor and the counts
per verdict, per class and per reason (docs/random-motors.md)."""
import concurrent.futures
import multiprocessing
import signal
import time
from collections import Counter
from typing import NamedTuple

from drive_common.runtime.interrupt import Interrupted

from .motor_bench import INJECTIONS, VERDICTS, TrialOptions, crashed_row, motor_trial, reason_kind
from .random_motors import draw_motors, write_motor_files

SALIENT_RATIO = 1.3
"""Issue 51: every motor with L_q/L_d ≥ 1.3 (its HF saliency L_qh/L_dh, or its inverse, at least this) is
not refused."""
SALIENCY_BANDS = ((1.1, "< 1.1"), (SALIENT_RATIO, "1.1-1.3"), (float("inf"), "≥ 1.3"))
POLE_PAIR_BANDS = ((5, "1-5"), (15, "6-15"), (30, "16-30"))
PREDICTION_FACTOR = (0.5, 2.0)
"""The factor within which the measured angle error RMS (the motor's low-speed case, no load) is set against the
predicted one (docs/random-motors.md)."""
PREDICTION_CASE = "low_speed"


class RandomBenchOptions(NamedTuple):
    """A random bench: how many motors of which seed, written where, tried how (motor_bench.TrialOptions'
    sampling period and starts) by how many processes."""

    count: int
    seed: int
    folder: object
    """pathlib.Path of the motor files."""
    T_s: float = 1e-4
    starts: int = 8
    workers: int = 2


def _worker_ignores_signals():
    """A pool process leaves SIGINT and SIGTERM to the bench's own process, which stops the pool."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


def _trial(job):
    """motor_trial of one job; a trial that raised is a failure row naming the exception (never a lost row)."""
    path, trial = job
    try:
        return motor_trial(path, trial)
    except Interrupted:
        raise
    except Exception as error:  # noqa: BLE001 - any crash is the motor's failure row, shown in the table
        return crashed_row(path, trial, error)


def each_in_processes(function, jobs, workers, finished):
    """``finished(i, function(jobs[i]))`` for every job, in this process (``workers`` ≤ 1) or in a pool of
    ``workers`` spawned processes that leave SIGINT and SIGTERM to this one, in the order they end. → 0, or the
    signal that stopped it (the pool's queued jobs cancelled; the jobs finished before it handed over)."""
    try:
        if workers <= 1:
            for i, job in enumerate(jobs):
                finished(i, function(job))
        else:
            context = multiprocessing.get_context("spawn")
            with concurrent.futures.ProcessPoolExecutor(workers, mp_context=context,
                                                        initializer=_worker_ignores_signals) as pool:
                futures = {pool.submit(function, job): i for i, job in enumerate(jobs)}
                try:
                    for future in concurrent.futures.as_completed(futures):
                        finished(futures[future], future.result())
                except Interrupted:
                    pool.shutdown(wait=False, cancel_futures=True)
                    raise
    except Interrupted as stop:
        return stop.signum
    return 0


def random_motor_bench(options, progress=None):
    """Draw, write and try ``options.count`` motors (RandomBenchOptions); ``progress(line)`` hears of each
    motor done. The report: the draw's facts, one compact row per motor, the counts (summary) and
    ``interrupted`` (the signal that stopped it, 0: none)."""
    motors = draw_motors(options.count, options.seed)
    paths = write_motor_files(motors, options.folder)
    jobs = [(str(path), TrialOptions(options.T_s, options.starts, (options.seed, i))) for i, path in enumerate(paths)]
    rows, start = [None] * len(jobs), time.perf_counter()

    def finished(index, row):
        rows[index] = compact_row(row, motors[index].figures)
        if progress:
            done = sum(r is not None for r in rows)
            elapsed = time.perf_counter() - start
            progress(f"[{done}/{len(rows)}] {row['motor']}: {row['verdict']} ({elapsed:.0f} s, "
                     f"{elapsed / done:.1f} s per motor, about {elapsed / done * (len(rows) - done):.0f} s left)")
    interrupted = each_in_processes(_trial, jobs, options.workers, finished)
    done = [r for r in rows if r is not None]
    wall = time.perf_counter() - start
    return {"benchmark": "motors", "random": options.count, "seed": options.seed, "folder": str(options.folder),
            "sample_period_s": options.T_s, "starts": options.starts, "workers": options.workers,
            "wall_time_s": wall, "seconds_per_motor": wall / len(done) if done else None,
            "interrupted": interrupted, "summary": summary(done), "rows": done}


def compact_row(row, figures):
    """The bench's row of one motor (issue 51's --json): its file, class figures, verdict, exit codes, the
    reason, identification errors, ours' RMS and peak per case and the polarity's success."""
    return {"motor": row["motor"], "file": row["file"], "figures": figures, "verdict": row["verdict"],
            "reason": row["reason"], "refused_at": row["refused_at"], "problems": row["problems"],
            "exit_codes": row["exit_codes"], "tests": row["tests"],
            "identification_error": row["identification_error"], "current_limit_A": row["current_limit_A"],
            "derated": row.get("derated", False), "sensorless_torque": row.get("sensorless_torque"),
            "warnings": row["warnings"], "polarity_correct": row["polarity_correct"],
            "injection": row.get("injection"), "predicted": row.get("predicted"), "forced": row.get("forced"),
            "rated_load_by_injection": row.get("rated_load_by_injection", {}),
            "cases": {c["case"]: {"exit_code": c["exit_code"], "angle_error_rms": c["angle_error_rms"],
                                  "angle_error_peak": c["angle_error_peak"], "load_per_rated": c["load_per_rated"],
                                  "verdict": c["verdict"]} for c in row["cases"]}}


def saliency_band(figures):
    """The band of the plant's HF saliency (L_qh/L_dh or its inverse, whichever exceeds 1)."""
    ratio = figures["L_qh_per_L_dh"]
    ratio = max(ratio, 1.0 / ratio)
    return next(label for top, label in SALIENCY_BANDS if ratio < top)


def pole_pair_band(figures):
    return next(label for top, label in POLE_PAIR_BANDS if figures["n_p"] <= top)


CLASSES = (("power", lambda f: f["power_class"]), ("rotor", lambda f: f["rotor"]),
           ("HF saliency L_qh/L_dh", saliency_band), ("pole pairs", pole_pair_band),
           ("saturation", lambda f: "on" if f["saturation"] else "off"),
           ("cross-saturation", lambda f: "on" if f["cross_saturation"] else "off"),
           ("J on the nameplate", lambda f: "yes" if f["J_on_nameplate"] else "no (rotating test)"))


def prediction_rows(rows):
    """Every motor with a predicted angle error and a measured low-speed case (the forced ones' measured as run
    anyway): {motor, refused, predicted and measured RMS and peak [rad], their ratio}."""
    out = []
    for row in rows:
        predicted, forced = row.get("predicted"), row.get("forced")
        case = (forced or row.get("cases") or {}).get(PREDICTION_CASE) or {}
        if not predicted or (case.get("angle_error_rms") is None and not forced):
            continue
        measured = case.get("angle_error_rms")
        out.append({"motor": row["motor"], "refused": bool(forced), "estimator": predicted["estimator"],
                    "predicted_rms": predicted["rms"], "predicted_peak": predicted["peak"],
                    "measured_rms": measured, "measured_peak": case.get("angle_error_peak"),
                    "lost": (forced or {}).get("commissioning", ""),
                    "ratio_rms": measured / predicted["rms"] if measured is not None and predicted["rms"] > 0.0
                    else None})
    return out


def prediction_summary(rows):
    """How many of the predictions hold within PREDICTION_FACTOR, of the refused motors run anyway and of all (a
    refused motor whose commissioning failed when run anyway has no measured error: counted, not within)."""
    predictions = prediction_rows(rows)
    low, high = PREDICTION_FACTOR

    def within(group):
        ratios = [p["ratio_rms"] for p in group if p["ratio_rms"] is not None]
        return {"motors": len(group), "measured": len(ratios), "within_factor": sum(low <= r <= high for r in ratios),
                "ratio_median": float(sorted(ratios)[len(ratios) // 2]) if ratios else None}
    return {"factor": list(PREDICTION_FACTOR), "refused": within([p for p in predictions if p["refused"]]),
            "all": within(predictions), "rows": predictions}


def injection_summary(rows):
    """Which injection the loops' rule chose (motors that ran), and the rated-load case on each injection: how many
    motors ran it and how many within targets at exit 0 (issue 52 item 4)."""
    chosen = Counter(row["injection"] for row in rows if row.get("injection"))
    rated = {}
    for name in INJECTIONS:
        cases = [row["rated_load_by_injection"][name] for row in rows if name in row.get("rated_load_by_injection", {})]
        rated[name] = {"motors": len(cases), "works": sum(c["exit_code"] == 0 and c["verdict"] == "within targets"
                                                          for c in cases)}
    return {"chosen": dict(chosen), "rated_load": rated}


def summary(rows):
    """Counts per verdict, per class and verdict, refusals' and failures' reasons (numbers taken out:
    reason_kind; a failure by its first problem), and the refused motors issue 51 says must not be."""
    by_class = {}
    for title, label in CLASSES:
        table = {}
        for row in rows:
            table.setdefault(label(row["figures"]), Counter())[row["verdict"]] += 1
        by_class[title] = {key: {v: counts[v] for v in VERDICTS} for key, counts in sorted(table.items())}
    verdicts = Counter(row["verdict"] for row in rows)
    refused = [row for row in rows if row["verdict"] == "refused up front"]
    return {"motors": len(rows), "verdicts": {v: verdicts[v] for v in VERDICTS}, "by_class": by_class,
            "refusal_reasons": dict(Counter(reason_kind(r["reason"]) for r in refused).most_common()),
            "failure_kinds": dict(Counter(reason_kind(r["problems"][0]) for r in rows
                                          if r["verdict"] == "failure").most_common()),
            "refused_at": dict(Counter(r["refused_at"] for r in refused)),
            "refused_salient": [r["motor"] for r in refused if saliency_band(r["figures"]) == "≥ 1.3"],
            "injection": injection_summary(rows), "prediction": prediction_summary(rows)}


def random_bench_lines(report):
    """The random bench as text: one line per motor, then the counts as Markdown tables."""
    lines = [f"{'motor':16s} {'class':11s} {'n_p':>3s} {'P [W]':>7s} {'U_dc':>6s} {'Lqh/Ldh':>7s} {'rotor':8s} "
             f"verdict: reason"]
    for r in report["rows"]:
        f = r["figures"]
        lines.append(f"{r['motor']:16s} {f['power_class']:11s} {f['n_p']:3d} {f['rated_power_W']:7.4g} "
                     f"{f['U_dc_V']:6.4g} {f['L_qh_per_L_dh']:7.3f} {f['rotor']:8s} {r['verdict']}"
                     + (f": {r['reason']}" if r["reason"] else ""))
    s = report["summary"]
    total = max(1, s["motors"])
    lines += ["", f"{s['motors']} motors, seed {report['seed']}, {report['wall_time_s']:.0f} s"
                  + (" (interrupted)" if report["interrupted"] else ""), "",
              "| verdict | motors | share |", "|---|---|---|"]
    lines += [f"| {v} | {n} | {100.0 * n / total:.1f} % |" for v, n in s["verdicts"].items()]
    for title, table in s["by_class"].items():
        lines += ["", f"| {title} | " + " | ".join(VERDICTS) + " |", "|---" * (len(VERDICTS) + 1) + "|"]
        lines += [f"| {key} | " + " | ".join(str(counts[v]) for v in VERDICTS) + " |" for key, counts in table.items()]
    for title, key in (("refusal reason", "refusal_reasons"), ("failure (first problem)", "failure_kinds")):
        lines += ["", f"| {title} | motors |", "|---|---|"]
        lines += [f"| {reason} | {n} |" for reason, n in s[key].items()]
    lines += ["", f"refused although L_qh/L_dh ≥ {SALIENT_RATIO} (issue 51 says they must not be): "
                  f"{len(s['refused_salient'])} ({', '.join(s['refused_salient']) or 'none'})"]
    injection = s["injection"]
    lines += ["", "injection the loops' rule chose: " + (", ".join(f"{k} {n}" for k, n in injection["chosen"].items())
                                                        or "none ran"),
              "rated load within targets, each injection on the same motors: "
              + ", ".join(f"{k} {v['works']} of {v['motors']}" for k, v in injection["rated_load"].items())]
    prediction = s["prediction"]
    low, high = prediction["factor"]
    lines += ["", f"predicted against measured angle error RMS ({PREDICTION_CASE}), within {low:g}-{high:g}×: refused "
                  f"motors run anyway {prediction['refused']['within_factor']} of {prediction['refused']['motors']}, "
                  f"all {prediction['all']['within_factor']} of {prediction['all']['motors']}"]
    lines += [f"  {p['motor']}{' (refused)' if p['refused'] else ''} {p['estimator']}: predicted "
              f"{p['predicted_rms']:.4f} / {p['predicted_peak']:.3f}, measured "
              + (f"{p['measured_rms']:.4f} / {p['measured_peak']:.3f} rad" if p["measured_rms"] is not None
                 else f"none: run anyway, {p['lost']}") for p in prediction["rows"]]
    return lines
