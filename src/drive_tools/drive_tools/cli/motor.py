"""``drive presets``, ``drive motor template|show`` and ``drive commission``: the motors the drive knows and
what it measures of one."""
import sys
from pathlib import Path

from drive_common.config.scenario import load_scenario
from drive_common.contract.graph import DEFAULT_NAMESPACE
from drive_common.motor.motor_file import load_motor

from .options import (
    MOTOR_HELP,
    CommandLineError,
    finite_float,
    motor_reference,
    print_report,
    sample_period_arg,
)


def cmd_commission(args):
    from drive_common.motor.commissioning import default_commissioning_file, save_commissioning
    from drive_tools.evaluation.motor_report import CommissioningWritten, commissioning_lines, commissioning_report
    from drive_tools.runner.commissioning_run import CommissioningRun
    from drive_tools.runner.runner import terminal_progress
    from hf_estimator.commissioning.procedure import METHOD

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
    rated = scenario.motor.nameplate.rated_current_A
    truth, true_currents = None, None
    if args.graph:
        from drive_tools.launch.commissioning_graph import commission_over_ros
        from pmsm_plant.build import plant_for_scenario
        from pmsm_plant.commissioning import commissioning_truth
        procedure, wall = commission_over_ros(args.scenario, args.namespace, args.link, progress=progress,
                                              motor=args.motor and motor_reference(args.motor))
        host = "ROS graph: " + (f"virtual inverter over {args.link} + drive_bridge node" if args.link
                                else "pmsm_plant node") + " + drive_commissioning node"
        truth = commissioning_truth(plant_for_scenario(scenario), rated)
    else:
        from drive_tools.runner.commissioning_run import commission_in_process, commission_through_bridge
        run = (commission_through_bridge(scenario, args.link, progress=progress) if args.link
               else commission_in_process(scenario, progress=progress))
        procedure, wall, host, truth, true_currents = run.procedure, run.wall_time_s, run.host, run.truth, \
            run.true_currents
    record = procedure.result()
    conditions = {"scenario": scenario.name, "host": host, **procedure.conditions(), "tests_completed": ["standstill"]}
    work = out.with_name(f".{out.name}.partial")  # what the later tests read; out: only once all are done
    try:
        save_commissioning(work, record, scenario.motor.name, METHOD, conditions)
        rotating = None
        if args.rotating:
            from drive_tools.runner.commissioning_run import rotating_test_in_process
            estimates, rotating_truth, _ = rotating_test_in_process(scenario, work, progress=progress)
            record = record._replace(psi_f_Wb=estimates["psi_f_Wb"], J_kgm2=estimates["J_kgm2"])
            rotating = {key: estimates[key] for key in ("B_Nms", "friction_Nm", "speeds_rad_s")}
            conditions["rotating_test"] = {"speeds_rad_s": estimates["speeds_rad_s"], "load": "none, shaft free"}
            conditions["tests_completed"].append("rotating")
            save_commissioning(work, record, scenario.motor.name, METHOD, conditions)
            truth = {**(truth or {}), **{key: rotating_truth[key] for key in ("psi_f_Wb", "J_kgm2")}}
        loaded = None
        if args.loaded:
            from drive_tools.runner.commissioning_run import loaded_test_in_process, with_loaded_test
            loaded, _ = loaded_test_in_process(scenario, work, progress=progress)
            record = with_loaded_test(record, loaded)
            conditions["loaded_test"] = {"shaft": "held (brake)", "top_current_A": loaded["top_current_A"],
                                         "injection_frequency_Hz": loaded["injection_frequency_Hz"],
                                         "injection_amplitude_V": loaded["injection_amplitude_V"]}
            conditions["tests_completed"].append("loaded")
        save_commissioning(out, record, scenario.motor.name, METHOD, conditions)
    finally:
        work.unlink(missing_ok=True)
    written = CommissioningWritten(out, scenario.motor.name, METHOD, conditions)
    run = CommissioningRun(procedure, truth, true_currents, wall, host)
    report = commissioning_report(written, run, record, rated, rotating, loaded)
    print_report(report, args, commissioning_lines)
    return 0


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

    print_report(motor_report(load_motor(args.motor, "motor"), sample_period_arg(args.sample_period)), args,
                 motor_lines)
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
    show = motor_sub.add_parser("show", help="a motor's nameplate, inverter and the loops scaled to it")
    show.add_argument("motor", metavar="NAME|FILE")
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
