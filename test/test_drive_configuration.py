"""The drive apart from the experiment: a drive configuration file (DRIVE_KEYS) that a scenario names with
``drive:`` and the drive's nodes read with no scenario at all, as on a robot."""
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from drive_common.config.drive_config import DRIVE_KEYS, DriveConfig
from drive_common.config.experiment import Experiment
from drive_common.config.parameters import all_parameters, scenario_from_parameters
from drive_common.config.scenario import Scenario, ScenarioError, load_drive_configuration, load_scenario
from drive_common.contract.estimator_states import TRACKING
from drive_common.contract.log import COLUMN
from drive_tools.runner.runner import run_scenario

COMMISSIONING = str(Path(__file__).resolve().parent.parent / "commissioning" / "wang_spmsm.yaml")
DRIVE = f"""\
format_version: 1
description: the Wang drive, as a robot runs it
motor: wang_spmsm
estimator: injection_frame
commissioning: {COMMISSIONING}
injection: {{frequency_Hz: 900.0, amplitude_V: 5.0}}
sampling_period_s: 1.0e-4
"""
EXPERIMENT = """\
description: a start from 1.3 rad and a ramp to 60 rpm, run by the drive in drive.yaml
drive: drive.yaml
duration_s: {duration_s}
initial: {{theta_m_rad: 1.3}}
speed: {{unit: rpm, interpolation: linear, points: [[0.0, 0.0], [0.04, 60.0]]}}
load: {{unit: rated, points: [[0.0, 0.0], [0.03, 0.5]]}}
"""


def files(tmp_path, duration_s=0.06):
    (tmp_path / "drive.yaml").write_text(DRIVE)
    path = tmp_path / "experiment.yaml"
    path.write_text(EXPERIMENT.format(duration_s=duration_s))
    return tmp_path / "drive.yaml", path


def test_a_scenario_naming_a_drive_file_is_the_scenario_with_the_drive_inline(tmp_path):
    """Same samples, to the bit, as the scenario written in one file."""
    drive, experiment = files(tmp_path)
    inline = tmp_path / "inline.yaml"
    inline.write_text(EXPERIMENT.format(duration_s=0.06).replace("drive: drive.yaml\n", DRIVE.split("\n", 2)[2]))
    a, b = load_scenario(str(experiment)), load_scenario(str(inline))
    assert a.drive_file == str(drive.resolve()) and b.drive_file == ""
    assert (a.motor.nameplate, a.motor.inverter, a.motor.plant) == (b.motor.nameplate, b.motor.inverter, b.motor.plant)
    assert dataclasses.replace(a, drive_file="", from_drive_file=(), name="inline", source=b.source,
                               estimator_source=b.estimator_source, motor=b.motor) == b
    np.testing.assert_array_equal(run_scenario(a).log, run_scenario(b).log)


def test_a_drive_configuration_alone_is_open_ended(tmp_path):
    """A DriveConfig with no experiment (no duration: it runs until stopped; no tables); its commissioning
    file its own."""
    drive, _ = files(tmp_path)
    d = load_drive_configuration(str(drive), "parameter drive_configuration")
    assert type(d) is DriveConfig and not isinstance(d, Experiment)
    assert d.open_ended and d.n_samples == sys.maxsize and d.drive_file == str(drive)
    assert (d.commissioning, d.T_s, d.drive_delay_periods()) == (COMMISSIONING, 1e-4, 1)


@pytest.mark.parametrize("text, key", [
    (DRIVE + "speed: {unit: rpm, points: [[0.0, 10.0]]}\n", "speed"),
    (DRIVE + "seed: 3\n", "seed"),
    (DRIVE.replace("motor: wang_spmsm\n", ""), "motor"),
])
def test_a_drive_configuration_holds_the_drive_only(tmp_path, text, key):
    """An experiment key in it, or a drive key missing: one line naming where it was given, the file and
    the key."""
    path = tmp_path / "drive.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as raised:
        load_drive_configuration(str(path), "parameter drive_configuration")
    message = str(raised.value)
    assert message.startswith("parameter drive_configuration: ") and str(path) in message and f": {key}:" in message


def test_a_drive_key_given_in_both_files_is_refused(tmp_path):
    _, experiment = files(tmp_path)
    experiment.write_text(experiment.read_text() + "estimator: sensored\n")
    with pytest.raises(ScenarioError, match=r"experiment.yaml: estimator: given here and in the drive configuration"):
        load_scenario(str(experiment))


def test_the_nodes_take_the_drive_alone_or_with_an_experiment(tmp_path):
    """Parameters with ``drive_configuration`` and no scenario: an open-ended drive (the estimator's and
    a controller's that takes `speed_command`); with the experiment (the plant, a scheduled controller):
    the scenario's tables run by that drive; overrides apply either way."""
    drive, experiment = files(tmp_path)
    alone = scenario_from_parameters(all_parameters({"scenario": "", "drive_configuration": str(drive),
                                                     "estimator": "sensored"}), experiment=False)
    assert type(alone) is DriveConfig and alone.open_ended and alone.estimator == "sensored"
    assert alone.motor.name == "wang_spmsm" and alone.commissioning == COMMISSIONING
    both = scenario_from_parameters(all_parameters({"scenario": str(experiment), "drive_configuration": str(drive)}))
    assert isinstance(both, Scenario) and not both.open_ended and both.n_samples == 600
    assert both.estimator == "injection_frame" and both.drive == dataclasses.replace(
        load_drive_configuration(str(drive)), name="experiment", source=str(experiment),
        description=both.description, from_drive_file=DRIVE_KEYS)
    assert both.experiment == load_scenario(str(experiment)).experiment


def test_the_drive_nodes_run_with_no_scenario(tmp_path):
    """The estimator and the controller started with a drive configuration alone (scenario:=''), the
    speed from `speed_command` as a robot sends it; the simulated plant runs its experiment. The drive
    starts from the unknown angle, tracks, and follows the plant to its last sample."""
    pytest.importorskip("rclpy")
    import rclpy
    import rclpy.node
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import Float64

    from drive_common.ros.node import parameter_overrides, topic_qos
    from foc_controller.node import ControllerNode
    from hf_estimator.node import EstimatorNode
    from pmsm_plant.node import PlantNode

    drive, experiment = files(tmp_path, duration_s=0.3)
    context = rclpy.Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    namespace = "/robot_joint"
    alone = {"scenario": "", "drive_configuration": str(drive)}
    nodes = [PlantNode(context=context, namespace=namespace,
                       parameter_overrides=parameter_overrides({"scenario": str(experiment)})),
             EstimatorNode(context=context, namespace=namespace, parameter_overrides=parameter_overrides(alone)),
             ControllerNode(context=context, namespace=namespace, parameter_overrides=parameter_overrides(alone))]
    tester = rclpy.node.Node("tester", context=context, namespace=namespace)
    states, errors = [], []
    tester.create_subscription(Vector3Stamped, "estimator_state", lambda m: states.append(m.vector.z),
                               topic_qos("estimator_state"))
    tester.create_subscription(Vector3Stamped, "angle_error", lambda m: errors.append(m.vector.x),
                               topic_qos("angle_error"))
    speed = tester.create_publisher(Float64, "speed_command", topic_qos("speed_command"))
    executor = EventsExecutor(context=context)
    try:
        assert all(n.configured for n in nodes) and nodes[1].scenario is None and nodes[1].config.open_ended
        for node in nodes + [tester]:
            executor.add_node(node)
        end, spins = time.monotonic() + 120.0, 0
        while len(states) < 3000:
            assert time.monotonic() < end, f"{len(states)} samples in 120 s"
            if spins % 2000 == 0:
                speed.publish(Float64(data=2.0))
            spins += 1
            executor.spin_once(timeout_sec=0.02)
        assert states.count(TRACKING) > 2500
        assert np.sqrt(np.mean(np.square(errors[-1000:]))) < 0.03
        assert not nodes[1].health.counters and not nodes[2].health.counters
    finally:
        executor.shutdown()
        for node in nodes + [tester]:
            node.destroy_node()
        context.try_shutdown()


def test_the_launcher_gives_the_estimator_the_drive_configuration_alone(tmp_path):
    """A scenario naming its drive file over the graph: the estimator runs from the drive configuration
    with no scenario, and the samples are the runner's, to 1e-9."""
    pytest.importorskip("rclpy")
    from drive_tools.launch.launcher import DriveSpec, launch
    _, experiment = files(tmp_path)
    result = launch(DriveSpec(str(experiment), "/drive_file"))
    assert not result.interrupted and not result.node_faults
    reference = run_scenario(load_scenario(str(experiment))).log
    for name in ("theta_m", "i_a_meas", "theta_e_hat", "u_alpha", "state"):
        np.testing.assert_allclose(result.log[:, COLUMN[name]], reference[:, COLUMN[name]], rtol=0.0, atol=1e-9,
                                   err_msg=name)


def test_a_scenario_is_its_drive_and_its_experiment():
    """A Scenario splits into the DriveConfig a robot's drive reads and the Experiment a simulation adds,
    and is made of them again unchanged; no field belongs to both."""
    s = load_scenario("wang_load_step")
    assert isinstance(s, DriveConfig) and isinstance(s, Experiment)
    assert type(s.drive) is DriveConfig and type(s.experiment) is Experiment
    assert Scenario.of(s.drive, s.experiment) == s
    assert not {f.name for f in dataclasses.fields(DriveConfig)} & {f.name for f in dataclasses.fields(Experiment)}


def test_every_node_is_one_class_below_rclpys_node():
    pytest.importorskip("rclpy")
    from rclpy.node import Node

    from drive_bridge.bridge_node import InverterBridgeNode
    from drive_common.ros.node import DriveNode
    from foc_controller.node import ControllerNode
    from hf_estimator.commissioning.node import CommissioningNode
    from hf_estimator.node import EstimatorNode
    from pmsm_plant.node import PlantNode

    assert DriveNode.__bases__ == (Node,)
    for node in (PlantNode, EstimatorNode, ControllerNode, CommissioningNode, InverterBridgeNode):
        assert node.__bases__ == (DriveNode,), node
