"""The ``drive`` command line."""
import argparse
import dataclasses
import json
import sys
from pathlib import Path

from hf_estimator.registry import describe, estimator_names
from pmsm_plant.presets import PRESETS

from .scenario import ScenarioError, load_scenario, scenario_names


def _print_json(data):
    print(json.dumps(data, indent=2, ensure_ascii=False))


def cmd_run(args):
    from .runner import run_scenario, terminal_progress

    scenario = load_scenario(args.scenario, estimator_override=args.estimator)
    if args.duration is not None:
        if args.duration <= 0.0:
            raise ScenarioError(f"--duration: must be positive, not {args.duration}")
        scenario = dataclasses.replace(scenario, duration_s=args.duration)
    if args.record and Path(args.record).exists():
        raise ScenarioError(f"--record: {args.record} already exists; choose a new bag name")
    result = run_scenario(scenario, progress=terminal_progress(f"{scenario.name}/{scenario.estimator}"))
    extra = {}
    if args.record:
        from .bag import write_run_bag
        progress = terminal_progress(f"writing {args.record}")
        extra["bag"] = str(write_run_bag(result, args.record, progress=progress))
    return _report(result, args, extra)


def _report(result, args, extra=None):
    """Print a run's metrics (drive run and drive launch), write its plot unless --no-plot."""
    from .metrics import compute_metrics
    from .plots import plot_run

    scenario = result.scenario
    metrics = compute_metrics(result)
    metrics.update(extra or {})
    if not args.no_plot and result.log.shape[0]:
        out_dir = Path(args.out) if args.out else Path("runs") / scenario.name
        metrics["plots"] = [str(plot_run(result, out_dir))]
    if args.json:
        _print_json(metrics)
        return 0
    print(f"scenario {metrics['scenario']} ({metrics['motor']}), estimator {metrics['estimator']}, "
          f"{metrics['duration_s']:g} s, {metrics['samples']} samples in {metrics['wall_time_s']:.2f} s")
    for key, value in (extra or {}).items():
        if not isinstance(value, dict):
            print(f"  {key:36s} {value}")
    rows = [("angle error RMS (steady)", "angle_error_rms", "rad"),
            ("angle error bias (steady)", "angle_error_bias", "rad"),
            ("angle error peak (all after start)", "angle_error_peak", "rad"),
            ("angle error peak (transients)", "angle_error_peak_transient", "rad"),
            ("speed estimation error RMS", "speed_error_rms", "rad/s"),
            ("speed tracking error RMS", "speed_tracking_error_rms", "rad/s"),
            ("settling time (worst step)", "settling_time_s", "s"),
            ("observable fraction", "observable_fraction", ""),
            ("current limit", "current_limit_A", "A")]
    for label, key, unit in rows:
        value = metrics[key]
        text = "n/a" if value is None else f"{value:+.4f} {unit}"
        print(f"  {label:36s} {text}")
    for path in metrics.get("plots", []):
        print(f"  plot: {path}")
    return 0


def cmd_launch(args):
    from .graph import launch
    from .runner import terminal_progress

    if args.duration is not None and args.duration <= 0.0:
        raise ScenarioError(f"--duration: must be positive, not {args.duration}")
    scenario = load_scenario(args.scenario, estimator_override=args.estimator)
    result = launch(args.scenario, estimator=args.estimator, duration_s=args.duration,
                    processes=args.processes, executor=args.executor, namespace=args.namespace,
                    timeout_s=args.timeout, bag=args.record,
                    progress=terminal_progress(f"{scenario.name}/{scenario.estimator} over ROS"))
    faults = {name: d["message"] for name, d in (result.diagnostics or {}).items() if d["level"] > 0}
    extra = {"graph": f"{args.processes} processes, {args.executor} executor, namespace {args.namespace}",
             "real_time_factor": round(result.scenario.duration_s / result.wall_time_s, 4)
             if result.wall_time_s > 0 else None,
             "interrupted": result.interrupted, "node_faults": faults}
    if args.record:
        extra["bag"] = args.record
    _report(result, args, extra)
    return 130 if result.interrupted else 0


def cmd_scenarios(args):
    entries = []
    for name in scenario_names():
        s = load_scenario(name)
        entries.append({"name": name, "motor": s.motor, "estimator": s.estimator,
                        "duration_s": s.duration_s, "description": s.description})
    if args.json:
        _print_json(entries)
    else:
        for e in entries:
            print(f"{e['name']:18s} {e['motor']:12s} {e['estimator']:12s} {e['duration_s']:5g} s  "
                  f"{e['description']}")
    return 0


def cmd_estimators(args):
    entries = [{"name": n, "description": describe(n)} for n in estimator_names()]
    if args.json:
        _print_json(entries)
    else:
        for e in entries:
            print(f"{e['name']:14s} {e['description']}")
    return 0


def cmd_presets(args):
    entries = [{"name": p.name, "source": p.source, "assumptions": list(p.assumptions),
                "machine": p.machine._asdict(), "nameplate": p.nameplate._asdict(),
                "mechanics": p.mechanics._asdict(), "inverter": p.inverter._asdict(),
                "sensor": p.sensor._asdict()} for p in PRESETS.values()]
    if args.json:
        _print_json(entries)
    else:
        for e in entries:
            print(f"{e['name']}: {e['source']}")
            for a in e["assumptions"]:
                print(f"  - {a}")
    return 0


def cmd_echo(args):
    from .graph import echo
    for flag, value in (("--count", args.count), ("--every", args.every)):
        if value is not None and value < 1:
            raise ScenarioError(f"{flag}: must be at least 1, not {value}")
    return echo(args.topic, args.namespace, args.count, args.every, args.json, args.timeout)


def cmd_bag_info(args):
    from .bag import bag_info
    info = bag_info(args.bag)
    if args.json:
        _print_json(info)
        return 0
    print(f"bag {info['bag']}: storage {info['storage']}, compression {info['compression']}")
    for f in info["files"]:
        print(f"  file {f['path']} ({f['bytes']:,} bytes)")
    print(f"  duration {info['duration_s']:.6f} s (start {info['start_s']:.6f} s, "
          f"end {info['end_s']:.6f} s), {info['messages']:,} messages")
    width = max((len(t["topic"]) for t in info["topics"]), default=0)
    for t in info["topics"]:
        qos = t["offered_qos"][0] if t["offered_qos"] else {}
        qos_text = "/".join(str(qos.get(key, "?")).lower() for key in ("reliability", "durability", "depth"))
        print(f"  {t['topic']:{width}s}  {t['type']:38s} {t['count']:8d}  {t['serialization']}  {qos_text}")
    return 0


def cmd_bag_reindex(args):
    from .bag import reindex
    info = reindex(args.bag, force=args.force)
    if args.json:
        _print_json(info)
    else:
        print(f"{info['bag']}: rebuilt, {info['messages']:,} messages over {info['duration_s']:.6f} s")
    return 0


COMPARED_METRICS = (("angle error RMS (steady)", "angle_error_rms", "rad"),
                    ("angle error bias (steady)", "angle_error_bias", "rad"),
                    ("angle error peak", "angle_error_peak", "rad"),
                    ("speed estimation error RMS", "speed_error_rms", "rad/s"),
                    ("observable fraction", "observable_fraction", ""))


def cmd_bench_compare(args):
    from .bag import bag_result, has_ground_truth
    from .metrics import compute_metrics
    from .plots import plot_angle_errors

    results, entries = [], []
    for bag in (args.bag_a, args.bag_b):
        result = bag_result(bag)
        entry = {"bag": bag, "scenario": result.scenario.name, "estimator": result.estimator,
                 "samples": int(result.log.shape[0]), "ground_truth": has_ground_truth(result.log)}
        metrics = compute_metrics(result)
        entry.update({key: metrics[key] if entry["ground_truth"] or key == "observable_fraction" else None
                      for _, key, _ in COMPARED_METRICS})
        results.append(result)
        entries.append(entry)
    names = [Path(bag).name for bag in (args.bag_a, args.bag_b)]
    report = {"benchmark": "compare", "runs": entries}
    if not args.no_plot:
        out = Path(args.out) if args.out else Path("runs") / "compare"
        report["plot"] = str(plot_angle_errors(results, names, out / f"{names[0]}_vs_{names[1]}.png"))
    if args.json:
        _print_json(report)
        return 0
    print(f"  {'':30s} {names[0]:>24s} {names[1]:>24s}")
    for label, key, unit in (("scenario", "scenario", ""), ("estimator", "estimator", ""),
                             ("samples", "samples", "")) + COMPARED_METRICS:
        cells = [e[key] for e in entries]
        text = ["n/a" if v is None else f"{v:+.4f} {unit}" if isinstance(v, float) else str(v)
                for v in cells]
        print(f"  {label:30s} {text[0]:>24s} {text[1]:>24s}")
    for entry in entries:
        if not entry["ground_truth"]:
            print(f"  {entry['bag']}: no ground truth (rotor_state); only consistency is scored")
    if "plot" in report:
        print(f"  plot: {report['plot']}")
    return 0


def cmd_bench_replay(args):
    from .plots import plot_angle_errors
    from .replay import replay

    names = args.estimators.split(",") if args.estimators else estimator_names()
    for name in names:
        if name not in estimator_names():
            raise ScenarioError(f"--estimators: unknown estimator '{name}' "
                                f"(known: {', '.join(estimator_names())})")
    recorded, entries, results = replay(args.bag, names)
    truth = "rotor_state" if "angle_error_rms" in entries[0] else None
    out = Path(args.out) if args.out else Path("runs") / "replay" / Path(args.bag).name
    report = {"benchmark": "replay", "bag": args.bag, "scenario": recorded.scenario.name,
              "recorded_estimator": recorded.estimator, "samples": int(recorded.log.shape[0]),
              "ground_truth": truth is not None, "results": entries}
    if not args.no_plot and truth:
        report["plot"] = str(plot_angle_errors(results, names, out / "angle_error.png"))
    out.mkdir(parents=True, exist_ok=True)
    (out / "replay.json").write_text(json.dumps(report, indent=2))
    report["json"] = str(out / "replay.json")
    if args.json:
        _print_json(report)
        return 0
    print(f"replay of {args.bag}: {report['samples']} samples of {report['scenario']}, recorded with "
          f"{recorded.estimator}")
    if not truth:
        print("  no ground truth (rotor_state) in this bag: scored for consistency only")
    columns = [("samples/s", "samples_per_second", "{:,.0f}"),
               ("exc. mismatch", "excitation_mismatch", "{:.3f}"),
               ("observable", "observable_fraction", "{:.3f}")]
    if truth:
        columns += [("RMS [rad]", "angle_error_rms", "{:.4f}"), ("bias [rad]", "angle_error_bias", "{:+.4f}"),
                    ("peak [rad]", "angle_error_peak", "{:.4f}"), ("speed RMS", "speed_error_rms", "{:.3f}"),
                    ("lock [s]", "time_to_lock_s", "{:.4f}")]
    print(f"  {'estimator':16s}" + "".join(f"{label:>14s}" for label, _, _ in columns))
    for e in entries:
        cells = ["n/a" if e.get(key) is None else fmt.format(e[key]) for _, key, fmt in columns]
        print(f"  {e['estimator']:16s}" + "".join(f"{c:>14s}" for c in cells))
    for key in ("plot", "json"):
        if key in report:
            print(f"  {key}: {report[key]}")
    return 0


def cmd_tune_pll(args):
    import math

    import numpy as np
    from hf_estimator.pll_model import highest_crossover, loop_phase, margins, open_loop, pll_process, tune_pi
    from hf_estimator.szabo import DEFAULTS

    from .plots import plot_bode

    preset = PRESETS.get(args.motor)
    if preset is None:
        raise ScenarioError(f"--motor: unknown preset '{args.motor}' (known: {', '.join(sorted(PRESETS))})")
    m = preset.nameplate
    f_h = args.frequency or DEFAULTS["frequency_Hz"]
    u_h = args.amplitude or DEFAULTS["amplitude_V"]
    T_f = DEFAULTS["T_f_s"] if args.T_f is None else args.T_f
    process = pll_process(m.R_s_ohm, m.L_d_H, m.L_q_H, f_h, u_h, args.u_star)
    table2 = margins(process, DEFAULTS["A_p"], DEFAULTS["T_i_s"], DEFAULTS["T_f_s"])
    try:
        crossover = args.crossover or highest_crossover(process, T_f, args.phase_margin)
        A_p, T_i = tune_pi(process, T_f, args.phase_margin, crossover)
    except ValueError as error:
        raise ScenarioError(str(error)) from None
    tuned = margins(process, A_p, T_i, T_f)
    report = {"motor": args.motor, "estimator": "synchronous",
              "model": "Szabó & Veszprémi Eq. (22)-(39): G_o = |K|·A_p(1 + 1/(sT_i))·G_p(s)/(s(sT_f + 1))",
              "injection": {"frequency_Hz": f_h, "amplitude_V": u_h, "u_star": args.u_star},
              "process": {"p1": process.p1, "p2": process.p2, "p3": process.p3, "lambda_d": process.lambda_d,
                          "lambda_q": process.lambda_q, "K": process.K, "c_S": process.c_S},
              "requested": {"phase_margin_deg": args.phase_margin, "crossover_rad_s": crossover},
              "tuned": {"A_p": A_p, "T_i_s": T_i, "T_f_s": T_f, **tuned.__dict__},
              "table2_gains": {"A_p": DEFAULTS["A_p"], "T_i_s": DEFAULTS["T_i_s"], "T_f_s": DEFAULTS["T_f_s"],
                               **table2.__dict__}}
    if not args.no_plot:
        out = Path(args.out) if args.out else Path("runs") / "tune"
        omega = np.logspace(0, 5, 2000)
        s = 1j * omega
        process_phase = np.degrees(loop_phase(process, 1.0, math.inf, 0.0, omega) + math.pi / 2.0)
        report["plots"] = [
            str(plot_bode([("G_p(s)", omega, process.G_p(s), process_phase)],
                          out / f"{args.motor}_pll_process.png",
                          f"{args.motor}: PLL process G_p (Szabó Fig. 8)")),
            str(plot_bode([(f"tuned A_p {A_p:.0f}, T_i {1e3 * T_i:.1f} ms", omega,
                            open_loop(process, A_p, T_i, T_f, omega),
                            np.degrees(loop_phase(process, A_p, T_i, T_f, omega))),
                           ("Table 2 A_p 4853, T_i 136 ms", omega,
                            open_loop(process, DEFAULTS["A_p"], DEFAULTS["T_i_s"], DEFAULTS["T_f_s"], omega),
                            np.degrees(loop_phase(process, DEFAULTS["A_p"], DEFAULTS["T_i_s"],
                                                        DEFAULTS["T_f_s"], omega)))],
                          out / f"{args.motor}_pll_open_loop.png",
                          f"{args.motor}: PLL open loop (Szabó Fig. 9)"))]
    if args.json:
        _print_json(report)
        return 0
    print(f"PLL of `synchronous` on {args.motor}: {f_h:g} Hz, {u_h:g} V, u* {args.u_star:g}; "
          f"K {process.K:.3f}, G_p(0) {process.c_S:.6f} S, poles {process.lambda_d:.1f}, "
          f"{process.lambda_q:.1f} rad/s")
    print(f"  tuned:    A_p {A_p:10.1f}  T_i {1e3 * T_i:7.2f} ms  T_f {1e3 * T_f:.3f} ms  crossover "
          f"{tuned.crossover_rad_s:7.1f} rad/s  phase margin {tuned.phase_margin_deg:5.1f}°  "
          f"gain margin {tuned.gain_margin_dB:5.1f} dB")
    print(f"  Table 2:  A_p {DEFAULTS['A_p']:10.1f}  T_i {1e3 * DEFAULTS['T_i_s']:7.2f} ms  T_f "
          f"{1e3 * DEFAULTS['T_f_s']:.3f} ms  crossover {table2.crossover_rad_s:7.1f} rad/s  phase margin "
          f"{table2.phase_margin_deg:5.1f}°  gain margin {table2.gain_margin_dB:5.1f} dB "
          f"(paper: 175 rad/s, 60°)")
    for path in report.get("plots", []):
        print(f"  plot: {path}")
    return 0


def cmd_bench_graph(args):
    from .bench import graph_throughput
    if args.duration <= 0.0:
        raise ScenarioError(f"--duration: must be positive, not {args.duration}")
    if args.repeats < 1:
        raise ScenarioError(f"--repeats: must be at least 1, not {args.repeats}")
    report = graph_throughput(args.scenario, args.duration, record=args.record, repeats=args.repeats,
                              progress=None if args.json else print)
    if args.json:
        _print_json(report)
    return 0


def cmd_bench(args):
    from .bench import motulator_python, motulator_throughput, throughput

    for flag, value in (("--samples", args.samples), ("--repeats", args.repeats)):
        if value < 1:
            raise ScenarioError(f"{flag}: must be at least 1, not {value}")
    names = args.estimators.split(",") if args.estimators else estimator_names()
    for name in names:
        if name not in estimator_names():
            raise ScenarioError(f"--estimators: unknown estimator '{name}' "
                                f"(known: {', '.join(estimator_names())})")
    results = []
    for name in names:
        if not args.json:
            print(f"  {name:14s} ...", end="", flush=True)
        r = throughput(name, samples=args.samples, repeats=args.repeats)
        results.append(r)
        if not args.json:
            print(f"\r  {name:14s} {r['samples_per_second']:12,.0f} samples/s "
                  f"(best of {r['repeats']} × {r['samples']} samples; median "
                  f"{r['samples_per_second_median']:,.0f})")
    report = {"benchmark": "throughput", "results": results,
              "samples_per_second": {r["estimator"]: r["samples_per_second"] for r in results}}
    python = None if args.no_motulator else motulator_python()
    if python:
        if not args.json:
            print("  motulator 2.2-kW PMSM signal-injection example ...", end="", flush=True)
        reference = motulator_throughput(python)
        report["motulator"] = reference
        if "error" not in reference:
            report["ratio_to_motulator"] = {r["estimator"]: r["samples_per_second"]
                                            / reference["samples_per_second"] for r in results}
        if not args.json:
            if "error" in reference:
                print(f"\r  motulator: not timed ({reference['error']})")
            else:
                print(f"\r  motulator      {reference['samples_per_second']:12,.0f} samples/s "
                      f"({reference['samples']} samples in {reference['wall_time_s']:.2f} s, {python})")
                for name, ratio in report["ratio_to_motulator"].items():
                    print(f"  {name:14s} {ratio:12,.0f} × motulator")
    elif not args.json:
        print("  motulator: not installed (./setup.sh --with-motulator, or DRIVE_MOTULATOR_PYTHON)")
    if args.json:
        _print_json(report)
    return 0


def build_parser():
    parser = argparse.ArgumentParser(prog="drive", description="Sensorless PMSM drive stack.")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run a scenario in one process, print metrics, write plots")
    run.add_argument("scenario", help="shipped scenario name (see 'drive scenarios') or YAML path")
    run.add_argument("--estimator", help="override the scenario's estimator")
    run.add_argument("--duration", type=float, help="override the duration [s]")
    run.add_argument("--out", help="plot directory (default runs/SCENARIO)")
    run.add_argument("--no-plot", action="store_true", help="skip the PNG plot")
    run.add_argument("--record", metavar="BAG",
                     help="write the run as a rosbag2/MCAP bag into this new directory")
    run.add_argument("--json", action="store_true", help="print the metrics as JSON")
    run.set_defaults(func=cmd_run)

    for name, func, text in (("scenarios", cmd_scenarios, "list shipped scenarios"),
                             ("estimators", cmd_estimators, "list estimators"),
                             ("presets", cmd_presets, "list motor presets and their assumptions")):
        p = sub.add_parser(name, help=text)
        p.add_argument("--json", action="store_true")
        p.set_defaults(func=func)

    bench = sub.add_parser("bench", help="benchmarks")
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    tp = bench_sub.add_parser("throughput", help="closed-loop samples/s in one process, per estimator")
    tp.add_argument("--estimators", help="comma-separated (default: all)")
    tp.add_argument("--samples", type=int, default=1_000_000)
    tp.add_argument("--repeats", type=int, default=3, help="timed runs per estimator (best reported)")
    tp.add_argument("--no-motulator", action="store_true",
                    help="skip timing motulator's signal-injection example")
    tp.add_argument("--json", action="store_true")
    tp.set_defaults(func=cmd_bench)
    graph = bench_sub.add_parser("graph", help="real-time factor of the lock-step ROS graph at the "
                                               "scenario's sampling rate, composed and separate")
    graph.add_argument("--scenario", default="wang_100rpm")
    graph.add_argument("--duration", type=float, default=0.5, help="simulated seconds per run")
    graph.add_argument("--record", action="store_true", help="also record every per-sample topic")
    graph.add_argument("--repeats", type=int, default=2, help="timed runs per configuration (best kept)")
    graph.add_argument("--json", action="store_true")
    graph.set_defaults(func=cmd_bench_graph)

    compare = bench_sub.add_parser("compare", help="two recorded runs side by side: metrics and angle error")
    compare.add_argument("bag_a")
    compare.add_argument("bag_b")
    compare.add_argument("--out", help="plot directory (default runs/compare)")
    compare.add_argument("--no-plot", action="store_true")
    compare.add_argument("--json", action="store_true")
    compare.set_defaults(func=cmd_bench_compare)

    rp = bench_sub.add_parser("replay",
                              help="estimators on a recording's currents, scored against its ground truth")
    rp.add_argument("bag")
    rp.add_argument("--estimators", help="comma-separated (default: all)")
    rp.add_argument("--out", help="directory for angle_error.png and replay.json (default runs/replay/BAG)")
    rp.add_argument("--no-plot", action="store_true")
    rp.add_argument("--json", action="store_true")
    rp.set_defaults(func=cmd_bench_replay)

    tune = sub.add_parser("tune", help="controller tuning from models")
    tune_sub = tune.add_subparsers(dest="tune", required=True)
    pll = tune_sub.add_parser("pll", help="PI of the synchronous-injection PLL from Szabó's model (§2.4)")
    pll.add_argument("--motor", default="szabo_ipmsm", help="motor preset (nameplate R, L_d, L_q)")
    pll.add_argument("--phase-margin", type=float, default=60.0, help="[deg]")
    pll.add_argument("--crossover", type=float, help="[rad/s] (default: the highest reaching the margin "
                                                     "with the PI zero a decade below)")
    pll.add_argument("--frequency", type=float, help="injection frequency [Hz] (default 1500)")
    pll.add_argument("--amplitude", type=float, help="injection amplitude u_h [V] (default 40)")
    pll.add_argument("--u-star", type=float, default=1.0, help="demodulation amplitude u*")
    pll.add_argument("--T-f", type=float, help="loop filter time constant [s] (default 0.53 ms)")
    pll.add_argument("--out", help="plot directory (default runs/tune)")
    pll.add_argument("--no-plot", action="store_true")
    pll.add_argument("--json", action="store_true")
    pll.set_defaults(func=cmd_tune_pll)

    from .graph import DEFAULT_NAMESPACE, EXECUTORS
    launch = sub.add_parser("launch", help="run a scenario through the ROS 2 graph (nodes over topics)")
    launch.add_argument("scenario", help="shipped scenario name or YAML path")
    launch.add_argument("--estimator", help="override the scenario's estimator")
    launch.add_argument("--duration", type=float, help="override the duration [s]")
    launch.add_argument("--processes", choices=("composed", "separate"), default="composed",
                        help="nodes in this process (default) or one process per node")
    launch.add_argument("--executor", choices=EXECUTORS, default="events",
                        help="events (rclpy.experimental.EventsExecutor, default) or single (fallback)")
    launch.add_argument("--namespace", default=DEFAULT_NAMESPACE)
    launch.add_argument("--timeout", type=float, default=1.0, help="lock-step answer timeout [s]")
    launch.add_argument("--out", help="plot directory (default runs/SCENARIO)")
    launch.add_argument("--no-plot", action="store_true")
    launch.add_argument("--record", metavar="BAG",
                        help="record every drive topic into this new rosbag2 directory")
    launch.add_argument("--json", action="store_true")
    launch.set_defaults(func=cmd_launch)

    echo = sub.add_parser("echo", help="print a drive topic (like ros2 topic echo)")
    echo.add_argument("topic", help="contract topic, e.g. angle_error, joint_states, /diagnostics")
    echo.add_argument("--namespace", default=DEFAULT_NAMESPACE)
    echo.add_argument("--count", type=int, help="stop after this many printed messages")
    echo.add_argument("--every", type=int, default=1, help="print every N-th message")
    echo.add_argument("--timeout", type=float, help="stop after this many seconds")
    echo.add_argument("--json", action="store_true", help="one JSON object per line")
    echo.set_defaults(func=cmd_echo)

    bag = sub.add_parser("bag", help="recordings (rosbag2 directories with MCAP storage)")
    bag_sub = bag.add_subparsers(dest="bag_command", required=True)
    info = bag_sub.add_parser("info", help="topics, types, counts, duration (like ros2 bag info)")
    info.add_argument("bag")
    info.add_argument("--json", action="store_true")
    info.set_defaults(func=cmd_bag_info)
    reindex = bag_sub.add_parser("reindex", help="make a cut recording (killed recorder) a complete bag")
    reindex.add_argument("bag")
    reindex.add_argument("--force", action="store_true", help="also when metadata.yaml exists (a cut .mcap)")
    reindex.add_argument("--json", action="store_true")
    reindex.set_defaults(func=cmd_bag_reindex)
    return parser


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except ScenarioError as error:
        print(f"drive: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
