"""``drive presets``, ``drive motor template|show`` and ``drive commission``: the motors the drive knows and
what it measures of one."""
import dataclasses
import sys
from pathlib import Path

from drive_common.config.scenario import load_scenario
from drive_common.contract.exit_codes import EXIT_REFUSED
from drive_common.contract.graph import DEFAULT_NAMESPACE
from drive_common.motor.motor_file import load_motor

from .options import (
    COMMISSIONING_HELP,
    MOTOR_HELP,
    CommandLineError,
    finite_float,
    motor_reference,
    print_report,
    sample_period_arg,
)
from .outcome import say_reason


def cmd_commission(args):
    from drive_common.motor.commissioning import default_commissioning_file, save_commissioning
    from drive_tools.evaluation.motor_report import (
        CommissioningWritten,
        commissioning_report,
        refused_report,
        stated_torque_report,
    )
    from drive_tools.runner.runner import terminal_progress
    from hf_estimator.commissioning.loaded import LoadedTestError
    from hf_estimator.commissioning.procedure import METHOD, CommissioningError
    from hf_estimator.commissioning.rotating import RotatingTestError

    scenario = load_scenario(args.scenario, motor_override=args.motor, motor_source="--motor")
    for option, asked in (("--rotating", args.rotating), ("--loaded", args.loaded)):
        if asked and (args.graph or args.link):
            raise CommandLineError(f"{option}: the {option[2:]} test runs in one process only (not yet over --graph "
                                   f"or --link)")
    out = Path(args.out) if args.out else default_commissioning_file(scenario.motor.name)
    if out.exists() and not args.force:
        raise CommandLineError(f"--out: {out} already exists (--force replaces it)")
    if not args.out:
        out.parent.mkdir(exist_ok=True)
    elif not out.parent.is_dir():
        raise CommandLineError(f"--out: the directory {out.parent} does not exist")
    progress = terminal_progress(f"commissioning {scenario.motor.name}")
    try:
        run = _standstill(args, scenario, progress)
    except CommissioningError as error:
        return _refused(args, refused_report(scenario.motor.name, "standstill", str(error)))
    record, conditions = run.procedure.result(), {"scenario": scenario.name, "host": run.host,
                                                  **run.procedure.conditions(), "tests_completed": ["standstill"]}
    rotating = loaded = refused = None
    work = out.with_name(f".{out.name}.partial")  # what the later tests read; out: once they are done or refused
    try:
        save_commissioning(work, record, scenario.motor.name, METHOD, conditions)
        if args.rotating:
            try:
                record, rotating, truth = _rotating(scenario, work, record, conditions, run.truth, progress)
                run.truth = truth
            except RotatingTestError as error:
                refused = {"test": "rotating", "reason": str(error)}
        if args.loaded and refused is None:
            try:
                record, loaded = _loaded(scenario, work, record, conditions, progress)
            except LoadedTestError as error:
                refused = {"test": "loaded", "reason": str(error)}
        save_commissioning(out, record, scenario.motor.name, METHOD, conditions)
    finally:
        work.unlink(missing_ok=True)
    written = CommissioningWritten(out, scenario.motor.name, METHOD, conditions)
    report = commissioning_report(written, run, record, scenario.motor.nameplate.rated_current_A, rotating, loaded)
    report["refused"] = refused
    report["sensorless_torque"] = stated_torque_report(dataclasses.replace(scenario, commissioning=str(out)))
    return _refused(args, report) if refused else _done(args, report)


def _standstill(args, scenario, progress):
    """The standstill procedure over the graph, through the bridge or in one process: a CommissioningRun."""
    from drive_tools.runner.commissioning_run import CommissioningRun, commission_in_process, commission_through_bridge
    if not args.graph:
        return (commission_through_bridge(scenario, args.link, progress=progress) if args.link
                else commission_in_process(scenario, progress=progress))
    from drive_tools.launch.commissioning_graph import commission_over_ros
    from pmsm_plant.build import plant_for_scenario
    from pmsm_plant.commissioning import commissioning_truth
    procedure, wall = commission_over_ros(args.scenario, args.namespace, args.link, progress=progress,
                                          motor=args.motor and motor_reference(args.motor))
    host = "ROS graph: " + (f"virtual inverter over {args.link} + drive_bridge node" if args.link
                            else "pmsm_plant node") + " + drive_commissioning node"
    truth = commissioning_truth(plant_for_scenario(scenario), scenario.motor.nameplate.rated_current_A)
    return CommissioningRun(procedure, truth, None, wall, host)


def _rotating(scenario, work, record, conditions, truth, progress):
    """The rotating test on the standstill file ``work``: (record, its B and friction, the truth with ψ_f and J)."""
    from drive_common.motor.commissioning import save_commissioning
    from drive_tools.runner.commissioning_run import rotating_test_in_process
    from hf_estimator.commissioning.procedure import METHOD
    estimates, rotating_truth, _ = rotating_test_in_process(scenario, work, progress=progress)
    record = record._replace(psi_f_Wb=estimates["psi_f_Wb"], J_kgm2=estimates["J_kgm2"])
    conditions["rotating_test"] = {"speeds_rad_s": estimates["speeds_rad_s"], "load": "none, shaft free"}
    conditions["tests_completed"].append("rotating")
    save_commissioning(work, record, scenario.motor.name, METHOD, conditions)
    truth = {**(truth or {}), **{key: rotating_truth[key] for key in ("psi_f_Wb", "J_kgm2")}}
    return record, {key: estimates[key] for key in ("B_Nms", "friction_Nm", "speeds_rad_s")}, truth


def _loaded(scenario, work, record, conditions, progress):
    """The loaded test on the file ``work``: (record with ours' correction, the test's result)."""
    from drive_tools.runner.commissioning_run import loaded_test_in_process, with_loaded_test
    loaded, _ = loaded_test_in_process(scenario, work, progress=progress)
    conditions["loaded_test"] = {"shaft": "held (brake)", "top_current_A": loaded["top_current_A"],
                                 "injection_frequency_Hz": loaded["injection_frequency_Hz"],
                                 "injection_amplitude_V": loaded["injection_amplitude_V"]}
    conditions["tests_completed"].append("loaded")
    return with_loaded_test(record, loaded), loaded


def _done(args, report):
    from drive_tools.evaluation.motor_report import commissioning_lines
    print_report(report, args, commissioning_lines)
    return 0


def _refused(args, report):
    """Print what was written and what was refused (text or --json), the refusal's reason on stderr: exit 2."""
    from drive_tools.evaluation.motor_report import commissioning_lines
    print_report(report, args, commissioning_lines)
    say_reason(report["refused"]["reason"])
    return EXIT_REFUSED


def cmd_presets(args):
    from drive_tools.evaluation.motor_report import presets_lines, presets_report

    print_report(presets_report(), args, presets_lines)
    return 0


def cmd_motor_template(args):
    from drive_common.motor.motor_file import TEMPLATE
    sys.stdout.write(TEMPLATE)
    return 0


def cmd_motor_show(args):
    from drive_tools.evaluation.motor_report import motor_lines, motor_report

    motor = load_motor(args.motor, "motor show")
    if motor.plant:
        from pmsm_plant.presets import plant_truth
        plant_truth(motor, "motor show")
    scenario = None
    if args.scenario:
        scenario = load_scenario(args.scenario, motor_override=args.motor, motor_source="motor show")
        if args.commissioning:
            scenario = dataclasses.replace(scenario, commissioning=args.commissioning)
    elif args.commissioning:
        raise CommandLineError("--commissioning: needs --scenario (the run it is used in)")
    print_report(motor_report(motor, sample_period_arg(args.sample_period), scenario), args, motor_lines)
    return 0


def add_commands(sub):
    """presets, motor template|show, commission."""
    p = sub.add_parser("presets", help="motor presets: the nameplate the drive is told beside the simulated plant's "
                                       "truth, and the assumptions")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_presets)

    motor = sub.add_parser("motor", help="motor files: a commented template; what the drive makes of a motor")
    motor_sub = motor.add_subparsers(dest="motor_command", required=True)
    template = motor_sub.add_parser("template", help="print a commented motor file (drive motor template > m.yaml)")
    template.set_defaults(func=cmd_motor_template)
    show = motor_sub.add_parser("show", help="a motor's nameplate, inverter and the loops scaled to it, or with "
                                             "--scenario the loops `drive run SCENARIO --motor` uses")
    show.add_argument("motor", metavar="NAME|FILE")
    show.add_argument("--scenario", help="print what `drive run SCENARIO --motor NAME|FILE` uses (built as the run "
                                         "builds it)")
    show.add_argument("--commissioning", metavar="FILE", help=COMMISSIONING_HELP)
    show.add_argument("--sample-period", type=finite_float, default=1e-4, metavar="S", help="sampling period [s]")
    show.add_argument("--json", action="store_true")
    show.set_defaults(func=cmd_motor_show)

    commission = sub.add_parser("commission", help="measure the scenario's motor at standstill, shaft held "
                                                   "(R_s, dead time, current sensors, L_dh, L_qh, saliency shift) "
                                                   "and write its commissioning file")
    commission.add_argument("scenario", help="shipped scenario name or YAML path (its motor and plant)")
    commission.add_argument("--motor", metavar="NAME|FILE", help=MOTOR_HELP)
    commission.add_argument("--out", help="file to write (default commissioning/MOTOR.yaml)")
    commission.add_argument("--force", action="store_true", help="replace an existing file")
    commission.add_argument("--loaded", action="store_true",
                            help="then the loaded test (shaft still held): ours runs as the scenario configures it, "
                                 "under loads of both signs, and measures its own angle error under load")
    commission.add_argument("--link", choices=("pty", "can"),
                            help="through the bridge: the virtual inverter behind this link")
    commission.add_argument("--graph", action="store_true",
                            help="through the ROS graph (plant node, or with --link the drive_bridge node, and "
                                 "the drive_commissioning node)")
    commission.add_argument("--namespace", default=DEFAULT_NAMESPACE, help="the graph's namespace (--graph)")
    commission.add_argument("--rotating", action="store_true",
                            help="then the rotating test (shaft free, unloaded): the drive spins it and measures "
                                 "ψ_f and J (docs/commissioning.md)")
    commission.add_argument("--json", action="store_true")
    commission.set_defaults(func=cmd_commission)
