"""``drive tune current|speed|pll``: controller gains from the motor's models, the PLL's with a closed-loop
check in the runner."""
import math
from pathlib import Path

from drive_common.motor.motor_file import load_motor
from drive_common.runtime.interrupt import Interrupted

from .options import COMMISSIONING_HELP, CommandLineError, exit_code, finite_float, print_report

PLL_ESTIMATORS = ("synchronous", "conventional", "improved")


def cmd_tune_current(args):
    from drive_tools.evaluation.tuning_report import current_tuning, current_tuning_lines
    from foc_controller.params import DEFAULTS

    plate = load_motor(args.motor, "--motor").nameplate
    omega_n = args.bandwidth or DEFAULTS["current_bandwidth_rad_s"]
    zeta = args.damping or DEFAULTS["current_damping"]
    try:
        report = current_tuning(args.motor, plate, omega_n, zeta, ("d", "q") if args.axis == "both" else (args.axis,))
    except ValueError as error:
        raise CommandLineError(f"--bandwidth: {error}") from None
    print_report(report, args, current_tuning_lines)
    return 0


def cmd_tune_speed(args):
    from drive_common.motor.scaled_loops import scaled_loops
    from drive_tools.evaluation.tuning_report import speed_tuning, speed_tuning_lines
    from foc_controller.params import DEFAULTS
    from hf_estimator.pll_model import margins

    motor = load_motor(args.motor, "--motor")
    plate = motor.nameplate
    if not math.isfinite(plate.J_kgm2):
        raise CommandLineError(f"--motor {args.motor}: nameplate.J_kgm2 unknown: no speed loop to tune "
                               f"(`drive commission --rotating` measures it)")
    requested = args.bandwidth or scaled_loops(plate, motor.inverter, 1e-4).speed_bandwidth_rad_s
    pll, source = args.pll_crossover, "--pll-crossover"
    if pll is None:
        from drive_tools.evaluation.pll_check import design_for_motor
        try:
            design = design_for_motor(args.motor, args.estimator, {}, commissioning=args.commissioning)
        except (KeyError, ValueError) as error:
            raise CommandLineError(f"--estimator {args.estimator}: {error.args[0]} (give --pll-crossover)") from None
        pll = margins(design.carrier, *design.current_gains).crossover_rad_s
        source = f"carrier model of `{args.estimator}` with its current gains"
    try:
        report = speed_tuning(args.motor, plate, requested, args.damping or DEFAULTS["speed_damping"], pll, source,
                              args.ratio)
    except ValueError as error:
        raise CommandLineError(f"--bandwidth: {error}") from None
    print_report(report, args, speed_tuning_lines)
    return 0


def _pll_settings(args):
    """The estimator settings the command line gives `drive tune pll` (T_f_s chosen for --crossover when
    --T-f auto)."""
    from drive_tools.evaluation.pll_check import largest_loop_filter_for_motor

    for flag, value in (("--crossover", args.crossover), ("--frequency", args.frequency),
                        ("--amplitude", args.amplitude), ("--u-star", args.u_star)):
        if value is not None and value <= 0.0:
            raise CommandLineError(f"{flag}: must be positive, not {value:g}")
    if not 0.0 < args.phase_margin < 90.0:
        raise CommandLineError(f"--phase-margin: between 0 and 90 degrees, not {args.phase_margin:g}")
    given = (("frequency_Hz", args.frequency), ("amplitude_V", args.amplitude), ("u_star", args.u_star),
             ("demodulation", args.demodulation))
    settings = {key: value for key, value in given if value is not None}
    if args.estimator != "synchronous" and (set(settings) - {"frequency_Hz", "amplitude_V"} or args.T_f):
        raise CommandLineError(f"--u-star, --T-f and --demodulation belong to `synchronous`, "
                               f"not `{args.estimator}`")
    if args.T_f == "auto":
        if args.crossover is None:
            raise CommandLineError("--T-f auto: give --crossover (the largest T_f is chosen for it)")
        try:
            settings["T_f_s"] = largest_loop_filter_for_motor(args.motor, settings, args.phase_margin,
                                                              args.crossover, args.model, args.commissioning)
        except ValueError as error:
            raise CommandLineError(f"--crossover: {error}") from None
    elif args.T_f is not None:
        try:
            settings["T_f_s"] = float(args.T_f)
        except ValueError:
            raise CommandLineError(f"--T-f: a time constant in seconds or 'auto', not {args.T_f!r}") from None
    return settings


def cmd_tune_pll(args):
    from drive_tools.evaluation.pll_check import check_tuning, design_for_motor
    from drive_tools.evaluation.plots import plot_pll
    from drive_tools.evaluation.tuning_report import pll_tuning, pll_tuning_lines
    from hf_estimator.pll_tuning import MAPPINGS
    from hf_estimator.synchronous import DEFAULTS as SYNCHRONOUS_DEFAULTS

    settings = _pll_settings(args)
    try:
        design = design_for_motor(args.motor, args.estimator, settings, commissioning=args.commissioning)
    except KeyError as error:
        raise CommandLineError(f"--motor/--estimator: {error.args[0]}") from None
    except ValueError as error:
        raise CommandLineError(f"--estimator {args.estimator}: {error}") from None
    if args.model == "szabo" and design.szabo is None:
        raise CommandLineError(f"--model szabo: {MAPPINGS[args.estimator]}")
    T_f = settings.get("T_f_s", SYNCHRONOUS_DEFAULTS["T_f_s"]) if args.estimator == "synchronous" else None
    report = pll_tuning(design, args.estimator, args.motor, args.phase_margin, args.crossover, args.model, T_f)
    if "error" in report["tuned"][args.model]:
        raise CommandLineError(f"--phase-margin/--crossover: {report['tuned'][args.model]['error']}")
    choice = report["tuned"][args.model]
    interrupted = 0
    if args.check:
        from drive_tools.runner.runner import terminal_progress
        report["check"] = []
        A_now, T_now = design.current_gains
        try:
            for label, A, T in (("current gains", A_now, T_now), ("tuned gains", choice["A_p"], choice["T_i_s"])):
                for ideal, plant in ((True, "ideal"), (False, "full")):
                    report["check"].append(check_tuning(design, A, T, settings, ideal, args.check_speed_loop,
                                                        terminal_progress(f"closed-loop check, {label}, "
                                                                          f"{plant} plant")))
        except Interrupted as stop:
            interrupted = report["interrupted"] = stop.signum
    if not args.no_plot:
        out = Path(args.out) if args.out else Path("runs") / "tune"
        report["plots"] = plot_pll(design, choice["A_p"], choice["T_i_s"], report.get("check"),
                                   out / f"{load_motor(args.motor, '--motor').name}_{args.estimator}")
    print_report(report, args, pll_tuning_lines)
    return exit_code(interrupted)


def add_commands(sub):
    """tune pll|current|speed."""
    tune = sub.add_parser("tune", help="controller tuning from models")
    tune_sub = tune.add_subparsers(dest="tune", required=True)
    pll = tune_sub.add_parser("pll", help="PI of a pulsating-injection estimator's PLL from Szabó's model "
                                          "(§2.4) and our carrier model, with a closed-loop check")
    pll.add_argument("--motor", default="szabo_ipmsm", metavar="NAME|FILE",
                     help="motor preset (its commissioned R_s, L_dh, L_qh)")
    pll.add_argument("--commissioning", metavar="FILE", help=COMMISSIONING_HELP)
    pll.add_argument("--estimator", default="synchronous", choices=PLL_ESTIMATORS)
    pll.add_argument("--model", default="carrier", choices=("carrier", "szabo"),
                     help="model the tuned gains come from (both are reported)")
    pll.add_argument("--phase-margin", type=finite_float, default=60.0, help="[deg]")
    pll.add_argument("--crossover", type=finite_float, help="[rad/s] (default: the highest reaching the margin "
                                                     "with the PI zero a decade below)")
    pll.add_argument("--frequency", type=finite_float, help="injection frequency [Hz] (default: the estimator's)")
    pll.add_argument("--amplitude", type=finite_float, help="injection amplitude [V] (default: the estimator's)")
    pll.add_argument("--u-star", type=finite_float, help="synchronous: demodulation amplitude u* (default 1)")
    pll.add_argument("--T-f", help="synchronous: loop filter time constant [s] (default 0.53 ms), or 'auto': "
                                   "the largest reaching --crossover at --phase-margin")
    pll.add_argument("--demodulation", choices=("paper", "aligned"),
                     help="synchronous: demodulation carrier as the paper, or turned by the sampled "
                          "current's phase lag (ours)")
    pll.add_argument("--check", action="store_true",
                     help="measure the closed loop in the runner with the current and the tuned gains, on "
                          "the ideal plant (no dead time or sensor errors: the models' assumptions) and the "
                          "full one")
    pll.add_argument("--check-speed-loop", choices=("off", "rule", "table2"), default="off",
                     help="speed loop during the check: 1 rad/s (the PLL alone), the controller's rule, or "
                          "Szabó's Table 2 cascade")
    pll.add_argument("--out", help="plot directory (default runs/tune)")
    pll.add_argument("--no-plot", action="store_true")
    pll.add_argument("--json", action="store_true")
    pll.set_defaults(func=cmd_tune_pll)
    current = tune_sub.add_parser("current", help="d/q current PI gains from a bandwidth and damping")
    current.add_argument("--motor", default="szabo_ipmsm", metavar="NAME|FILE",
                         help="a shipped motor or a motor file (nameplate R, L_d, L_q)")
    current.add_argument("--bandwidth", type=finite_float, help="closed-loop ω_n [rad/s] (default 2π·250)")
    current.add_argument("--damping", type=finite_float, help="ζ (default 0.8)")
    current.add_argument("--axis", choices=("d", "q", "both"), default="both")
    current.add_argument("--json", action="store_true")
    current.set_defaults(func=cmd_tune_current)
    speed = tune_sub.add_parser("speed",
                                help="speed PI gains from a bandwidth and damping, kept below the PLL")
    speed.add_argument("--motor", default="szabo_ipmsm", metavar="NAME|FILE",
                       help="a shipped motor or a motor file (J, B, k_t)")
    speed.add_argument("--bandwidth", type=finite_float, help="closed-loop ω_n [rad/s] (default: scaled to the motor, "
                                                       "40 for the shipped ones)")
    speed.add_argument("--damping", type=finite_float, help="ζ (default 1)")
    speed.add_argument("--estimator", default="synchronous", choices=PLL_ESTIMATORS,
                       help="whose PLL crossover (carrier model, current gains) bounds the speed loop")
    speed.add_argument("--commissioning", metavar="FILE", help=COMMISSIONING_HELP)
    speed.add_argument("--pll-crossover", type=finite_float, help="[rad/s] instead of the estimator's model")
    speed.add_argument("--ratio", type=finite_float, default=0.25, help="speed bandwidth ≤ ratio × PLL crossover")
    speed.add_argument("--json", action="store_true")
    speed.set_defaults(func=cmd_tune_speed)
