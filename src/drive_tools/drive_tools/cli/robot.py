"""``drive up ROBOT.yaml``: a robot's axes in one process, commanded as ROS robots are (docs/robot.md); ``drive axis
NAME TRANSITION``: the supervisor's side, one lifecycle transition of a running axis."""
import sys

from drive_common.contract.errors import DriveError
from drive_common.contract.exit_codes import EXIT_OK, EXIT_RECORDING_FAILED
from drive_common.contract.graph import EXECUTORS

from .options import finite_float, print_json, record_arg
from .outcome import say_reason

AXIS_TRANSITIONS = ("configure", "activate", "deactivate", "cleanup", "shutdown", "state")


def cmd_up(args):
    from drive_tools.launch.robot import bring_up
    from drive_tools.launch.robot_file import load_robot

    robot = load_robot(args.robot)

    def started(axes):
        states = ", ".join(f"{a.spec.joint} ({a.spec.namespace}/drive_axis) {a._state_machine.current_state[1]}"
                           for a in axes)
        print(f"drive up: {len(axes)} axes: {states}; joint commands on {robot.command_topic}, states on "
              f"{robot.joint_states_topic}; Ctrl-C stops every axis", file=sys.stderr, flush=True)
    record_arg(args.record)
    result = bring_up(robot, args.executor, started=started, record=args.record)
    for line in result.scheduling["applied"] if result.scheduling else ():
        print(f"drive: {line}", file=sys.stderr)
    for line in result.scheduling["refused"] if result.scheduling else ():
        print(f"drive: warning: {line}", file=sys.stderr)
    exit_code, reason = result.exit_code, result.reason
    recording = result.recording
    if recording and recording["error"] and exit_code == EXIT_OK:
        exit_code, reason = EXIT_RECORDING_FAILED, recording["error"]
    report = {"robot": robot.source, "exit_code": exit_code, "reason": reason, "axes": result.axes,
              "faults": result.faults, "scheduling": result.scheduling, "recording": recording,
              "running": result.running}
    if args.json:
        print_json(report)
    else:
        for axis in result.axes:
            print(f"{axis['joint']}: {axis['state']}, link {axis.get('link', 'closed')}, inverter told to switch off "
                  f"{axis.get('safe_state_sent', 0)} time(s)")
        if recording:
            unheard = recording["not_heard_from_the_start"]
            print(f"recording: {recording['path']}, {recording['messages']} messages"
                  + (f" ({recording['error']})" if recording["error"] else "")
                  + (f"; not heard from their start (the machine was slow): {', '.join(unheard)}" if unheard else "")
                  + ("" if recording["drained"] else "; still receiving when it closed (its last messages may be "
                     "missing)"))
    if reason:
        say_reason(reason)
    return exit_code


def cmd_axis(args):
    """One lifecycle transition of a running axis (``NAMESPACE/drive_axis``), or its state; exit 0 when done, 2 (a
    DriveError) when refused or not there."""
    import rclpy
    from lifecycle_msgs.srv import ChangeState, GetState
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    namespace = args.name if args.name.startswith("/") else f"/{args.name}"
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = Node("drive_axis_supervisor", context=context)
    try:
        state_client = node.create_client(GetState, f"{namespace}/drive_axis/get_state")
        if not state_client.wait_for_service(timeout_sec=args.timeout):
            raise DriveError(f"axis {namespace}: no {namespace}/drive_axis/get_state within {args.timeout:g} s "
                             f"(is `drive up` running it, in this ROS_DOMAIN_ID?)")
        if args.transition != "state":
            change = node.create_client(ChangeState, f"{namespace}/drive_axis/change_state")
            change.wait_for_service(timeout_sec=args.timeout)
            request = ChangeState.Request()
            request.transition.id = _transition_id(args.transition, _call(context, node, state_client,
                                                                          GetState.Request(), args.timeout))
            done = _call(context, node, change, request, args.timeout)
            if not done.success:
                state = _call(context, node, state_client, GetState.Request(), args.timeout).current_state.label
                raise DriveError(f"axis {namespace}: {args.transition} refused (the axis is {state}; its log and "
                                 f"/diagnostics say why)")
        state = _call(context, node, state_client, GetState.Request(), args.timeout).current_state.label
    finally:
        node.destroy_node()
        context.try_shutdown()
    if args.json:
        print_json({"axis": namespace, "state": state})
    else:
        print(f"{namespace}: {state}")
    return EXIT_OK


def _transition_id(transition, state_response):
    """The lifecycle_msgs/Transition id of ``transition`` from the axis's current state (shutdown has one per
    state)."""
    from drive_tools.launch.robot import TRANSITION_IDS
    if transition != "shutdown":
        return TRANSITION_IDS[transition]
    return {"unconfigured": 5, "inactive": 6, "active": 7}.get(state_response.current_state.label, 5)


def _call(context, node, client, request, timeout_s):
    from rclpy.executors import SingleThreadedExecutor
    future = client.call_async(request)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    executor.spin_until_future_complete(future, timeout_sec=timeout_s)
    executor.remove_node(node)
    if not future.done():
        raise DriveError(f"{client.srv_name}: no answer within {timeout_s:g} s")
    return future.result()


def add_commands(sub):
    up = sub.add_parser("up", help="run a robot's axes (a robot file) until stopped, commanded over ROS")
    up.add_argument("robot", help="the robot file (docs/robot.md)")
    up.add_argument("--executor", choices=EXECUTORS, default="events")
    up.add_argument("--record", metavar="BAG", help="record every axis's topics, /joint_states, the joint commands "
                    "and /diagnostics into this new bag directory while the robot runs (closed when it stops)")
    up.add_argument("--json", action="store_true")
    up.set_defaults(func=cmd_up)
    axis = sub.add_parser("axis", help="a lifecycle transition of a running axis (drive up), or its state")
    axis.add_argument("name", help="the axis's namespace (its joint's name by default)")
    axis.add_argument("transition", choices=AXIS_TRANSITIONS)
    axis.add_argument("--timeout", type=finite_float, default=10.0, help="seconds to wait for the axis [s]")
    axis.add_argument("--json", action="store_true")
    axis.set_defaults(func=cmd_axis)

