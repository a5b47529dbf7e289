"""Commissioning through the ROS graph: the plant node with its shaft held (or, with a link, the virtual
inverter behind the drive_bridge node) and the drive_commissioning node in the controller's place,
composed in this process. The procedure is the same core the one-process host runs."""
import tempfile
import time

from drive_common.config.parameters import all_parameters, scenario_from_parameters
from drive_common.contract.graph import DEFAULT_NAMESPACE
from drive_common.runtime.interrupt import Interrupted, polled, requested
from drive_tools.doubles.virtual_inverter import InverterOptions
from hf_estimator.commissioning.procedure import procedure_for_scenario

from .launcher import (
    DriveSpec,
    GraphError,
    NamespaceLock,
    _virtual_inverter,
    make_node,
    node_parameters,
    refuse_occupied,
    tear_down,
)


def commission_over_ros(scenario_ref, namespace=DEFAULT_NAMESPACE, link=None, timeout_s=1.0,
                        startup_timeout_s=60.0, progress=None, motor=None):
    """Run the commissioning procedure over topics; returns (the finished procedure, wall time [s]).
    GraphError when the graph does not finish; Interrupted on SIGINT/SIGTERM (the plant is left at zero
    volts). ``motor``: a shipped motor or motor file in place of the scenario's."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from drive_common.ros.node import make_executor

    motor_file = {"motor_file": motor} if motor else {}
    base = scenario_from_parameters(all_parameters(node_parameters(scenario_ref, extra=motor_file)))
    seconds = procedure_for_scenario(base).total_samples * base.T_s
    parameters = node_parameters(scenario_ref, duration_s=seconds, timeout_s=timeout_s,
                                 extra={"shaft_held": True, **motor_file})
    scenario = scenario_from_parameters(all_parameters(parameters))
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    lock = None
    nodes, inverter, ex = [], None, None
    workdir = tempfile.TemporaryDirectory(prefix="drive_commission_")
    polling = polled()
    polling.__enter__()
    try:
        lock = NamespaceLock(namespace)
        refuse_occupied(context, [namespace])
        ex = make_executor("events", context)
        if link:
            apart = DriveSpec(scenario_ref, namespace, link=link, inverter_apart=True)
            inverter, host_link = _virtual_inverter(scenario, parameters, apart, (workdir.name, 0),
                                                    InverterOptions(command_wait_s=timeout_s))
            nodes.append(make_node("drive_bridge", context, namespace, {"link_timeout_s": timeout_s,
                                                                        "command_timeout_s": timeout_s},
                                   link=host_link))
        else:
            nodes.append(make_node("pmsm_plant", context, namespace, parameters))
        commissioning = make_node("drive_commissioning", context, namespace, parameters)
        nodes.append(commissioning)
        if commissioning.health.latched:
            raise GraphError(f"{namespace}: {commissioning.health.latched}")
        for node in nodes:
            ex.add_node(node)
        start = time.monotonic()
        started = inverter is None
        while not commissioning.procedure.done:
            if not started and commissioning.voltage_pub and commissioning.voltage_pub.get_subscription_count():
                inverter.start()
                started = True
            if requested():
                raise Interrupted(requested())
            if commissioning.aborted:
                raise GraphError(f"{namespace}: {commissioning.aborted}")
            ex.spin_once(timeout_sec=0.05)
            waited = time.monotonic() - start
            if commissioning.k == 0 and waited > startup_timeout_s:
                raise GraphError(f"{namespace}: the plant did not start within {startup_timeout_s:g} s")
            if progress and commissioning.k % 1000 == 0:
                progress(commissioning.k / scenario.n_samples)
        if progress:
            progress(1.0)
        return commissioning.procedure, time.monotonic() - start
    finally:
        polling.__exit__(None, None, None)
        tear_down(ex, nodes, context, [inverter] if inverter else [], workdir)
        if lock:
            lock.release()
