"""``drive bench compare`` and ``drive bench replay``: recorded runs scored side by side, and estimators
replayed on a recording's currents or on a corpus of recordings."""
import sys
from pathlib import Path

from drive_common.contract.strict_json import dumps

from .options import (
    CommandLineError,
    estimator_list,
    print_report,
    recording_options,
    windows_arg,
)


def _recording(bag, args):
    """A bag read for scoring with the command line's --motor, --sample-period, --commissioning, --windows."""
    from drive_tools.evaluation.recording import read_recording
    return read_recording(bag, motor=args.motor, sample_period_s=args.sample_period,
                          commissioning=args.commissioning, windows=windows_arg(args.windows), namespace=args.namespace)


def _bags(pattern):
    """(the bags named by a bag path, a directory of bags or a glob, whether they are a corpus);
    CommandLineError when none."""
    import glob
    path = Path(pattern)
    if path.is_dir() and not (path / "metadata.yaml").exists() and not any(path.glob("*.mcap")):
        bags = [str(p.parent) for p in sorted(path.rglob("metadata.yaml"))]
        if not bags:
            raise CommandLineError(f"bag: {pattern}: a directory without a bag (metadata.yaml) in it")
        return bags, True
    if any(c in pattern for c in "*?["):
        bags = sorted(glob.glob(pattern))
        if not bags:
            raise CommandLineError(f"bag: {pattern}: no bag matches")
        return bags, True
    return [pattern], False


def _save_report(report, path):
    """Write a report as JSON to ``path`` (its directory made) and name the file in it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(dumps(report, indent=2))
    report["json"] = str(path)


def cmd_bench_compare(args):
    from drive_tools.evaluation.plots import plot_angle_errors
    from drive_tools.evaluation.replay_report import compare_lines, compared_run

    entries, results = zip(*(compared_run(_recording(bag, args)) for bag in (args.bag_a, args.bag_b)))
    names = [Path(bag).name for bag in (args.bag_a, args.bag_b)]
    report = {"benchmark": "compare", "runs": list(entries)}
    if not args.no_plot:
        out = Path(args.out) if args.out else Path("runs") / "compare"
        report["plot"] = str(plot_angle_errors(list(results), names, out / f"{names[0]}_vs_{names[1]}.png"))
    print_report(report, args, lambda r: compare_lines(r, names))
    return 0


def cmd_bench_replay(args):
    from drive_tools.evaluation.plots import plot_angle_errors
    from drive_tools.evaluation.replay import replay
    from drive_tools.evaluation.replay_report import replay_lines

    names = estimator_list(args.estimators)
    bags, corpus = _bags(args.bag)
    if args.workers is not None and args.cluster:
        raise CommandLineError("--workers and --cluster: give one (local processes, or a cluster's scheduler)")
    if not corpus:
        for flag, given in (("--workers", args.workers is not None), ("--cluster", args.cluster),
                            ("--report", args.report)):
            if given:
                raise CommandLineError(f"{flag}: a corpus's option (a directory or glob of bags); {args.bag} is "
                                       f"one bag")
    if corpus:
        return _replay_corpus(bags, names, args)
    recording = _recording(args.bag, args)
    entries, results = replay(recording, names)
    out = Path(args.out) if args.out else Path("runs") / "replay" / Path(args.bag).name
    report = {"benchmark": "replay", **recording.report(), "results": entries}
    drawn = [(result, entry["estimator"]) for result, entry in zip(results, entries) if entry["applicable"]]
    if not args.no_plot and recording.ground_truth:
        skipped = [f"{e['estimator']}: not applicable" for e in entries if not e["applicable"]]
        report["plot"] = str(plot_angle_errors([r for r, _ in drawn], [n for _, n in drawn],
                                               out / "angle_error.png", not_drawn=skipped,
                                               title=f"replay of {Path(args.bag).name} (recorded with "
                                                     f"{recording.estimator or 'an unnamed estimator'}): "
                                                     f"θ_e − θ̂_e per estimator"))
    _save_report(report, out / "replay.json")
    print_report(report, args, lambda r: replay_lines(r, recording))
    return 0


def _replay_corpus(bags, names, args):
    """Every bag of a corpus replayed (here, in --workers local processes or on the --cluster); one summary
    row per estimator. A path that is not a bag, or a bag that cannot be replayed, is skipped with one line
    on stderr (and listed under ``skipped``)."""
    from drive_tools.evaluation.corpus_replay import Engine, ReplayOptions, replay_corpus
    from drive_tools.evaluation.replay import summarise
    from drive_tools.evaluation.replay_report import corpus_lines

    if args.workers is not None and args.workers < 1:
        raise CommandLineError(f"--workers: must be at least 1, not {args.workers}")
    options = ReplayOptions(tuple(names), args.motor, args.sample_period, args.commissioning,
                            windows_arg(args.windows))
    engine = Engine(args.workers or 0, args.cluster or "")
    say = (lambda line: print(line, file=sys.stderr, flush=True)) if sys.stderr.isatty() else None
    outcomes, engine_facts = replay_corpus(bags, options, engine, say)
    per_bag = [o["report"] for o in outcomes if "report" in o]
    skipped = [{"path": o["path"], "reason": o["skipped"]} for o in outcomes if "skipped" in o]
    for entry in skipped:
        print(f"drive: skipped {entry['path']}: {entry['reason']}", file=sys.stderr)
    if not per_bag:
        raise CommandLineError(f"bag: {args.bag}: none of its {len(bags)} paths could be replayed")
    report = {"benchmark": "replay corpus", "pattern": args.bag, "bags": len(per_bag), "engine": engine_facts,
              "summary": summarise(per_bag, names), "skipped": skipped, "per_bag": per_bag}
    if args.out:
        _save_report(report, Path(args.out) / "replay_corpus.json")
    if args.report:
        from drive_tools.evaluation.corpus_report import write_report
        report["report"] = write_report(report, args.report)
    print_report(report, args, corpus_lines)
    return 0


def add_bench_commands(bench_sub):
    """bench compare, bench replay."""
    compare = bench_sub.add_parser("compare", help="two recorded runs side by side: metrics and angle error")
    compare.add_argument("bag_a")
    compare.add_argument("bag_b")
    recording_options(compare)
    compare.add_argument("--out", help="plot directory (default runs/compare)")
    compare.add_argument("--no-plot", action="store_true")
    compare.add_argument("--json", action="store_true")
    compare.set_defaults(func=cmd_bench_compare)

    rp = bench_sub.add_parser("replay",
                              help="estimators on a recording's currents, scored against its ground truth")
    rp.add_argument("bag", help="a bag, a directory of bags or a glob (a corpus: one summary per estimator)")
    rp.add_argument("--estimators", help="comma-separated (default: all)")
    recording_options(rp)
    rp.add_argument("--out", help="directory for angle_error.png and replay.json (default runs/replay/BAG; a "
                                  "corpus writes replay_corpus.json only with --out)")
    rp.add_argument("--no-plot", action="store_true")
    rp.add_argument("--workers", type=int, metavar="N",
                    help="a corpus: replay its bags in N local worker processes (Dask distributed; default: "
                         "this process)")
    rp.add_argument("--cluster", metavar="ADDRESS",
                    help="a corpus: replay its bags on the Dask scheduler at ADDRESS (tcp://HOST:PORT), whose "
                         "workers have this package installed (docs/recordings.md)")
    rp.add_argument("--report", metavar="DIR",
                    help="a corpus: write report.html (self-contained), report.json and bags.csv there: intervals "
                         "over bags, a ranking with significance, per motor class and speed band "
                         "(docs/recordings.md)")
    rp.add_argument("--json", action="store_true")
    rp.set_defaults(func=cmd_bench_replay)
