"""The contract's topics, in one table: name, message type, QoS, whether it is per-sample, whether its
first field is the sample instant, and the log columns its fields fill. Nodes, the launcher, the
recorder, the bag reader and the runner's logs all read this table."""
from typing import NamedTuple

CONTRACT_VERSION = 3
"""The drive interface contract this code follows (docs/drive-interface.md); drive_config carries it. Version 3:
the block topics in a message type of their own (drive_msgs/msg/SampleBlock) instead of sensor_msgs/JointState."""


class QosSpec(NamedTuple):
    """A topic's QoS, independent of rclpy: reliable, keep-last ``depth``, volatile or transient local."""

    depth: int
    transient_local: bool = False


PER_SAMPLE_QOS = QosSpec(depth=1000)
"""The lock-step topics (state, estimates, commands of each sample): read by the next node of the chain (one
message in flight) and by observers (the recorder, `drive echo`): reliable, volatile (a sample of an earlier run is
never taken), 1000 deep: an observer that falls up to 0.1 s behind at 10 kHz loses nothing."""
COMMAND_QOS = QosSpec(depth=100)
"""speed_command / torque_feedforward / load_torque (read by the drive: only the latest counts) and joint_states
(read by a robot's state consumers, 100 Hz by default): reliable, so a one-shot command arrives and both reliable
and best-effort readers match; volatile, so a command published before the drive (re)started is never applied
(`ros2 topic pub` and Foxglove publishers match); 100 deep (1 s of joint_states)."""
OBSERVED_QOS = QosSpec(depth=10000)
"""angle_error (read by plots, the live view, evaluations that count every message): reliable, volatile, 10 000
deep: a reader that falls up to 10 000 messages behind (1 s at 10 kHz, angle_error_decimation 1) loses none of
those published after it matched."""
LATCHED_QOS = QosSpec(depth=10, transient_local=True)
"""drive_config: published once per node start, delivered to late joiners (10 deep, so a subscriber
keeps the configs of all the drive's nodes)."""
DIAGNOSTICS_QOS = QosSpec(depth=100, transient_local=True)
"""/diagnostics (read by supervisors, the launcher, the live view): reliable, transient local, 100 deep per node: a
reader that joins late gets each node's last 100 statuses at once (their fault counters cumulative, so the last
holds every count so far), a slow one loses none of a node's statuses while it is fewer than 100 behind (100 s at
1 Hz, 10 s at the fastest fault reports)."""


class Topic(NamedTuple):
    name: str
    """Relative to the drive's namespace unless absolute."""
    type: str
    qos: QosSpec
    per_sample: bool
    """One message per control period."""
    stamped: bool
    """The first field is the sample instant (header.stamp, or the clock)."""
    log_columns: tuple = ()
    """Log columns (``drive_common.contract.log``) filled by the message's fields in order: x, y, z of a
    Vector3Stamped; position, velocity, effort of a JointState; data of a Float64 (held until the next)."""
    electrical: bool = False
    """The JointState's mechanical values are logged as electrical ones (× pole pairs)."""
    frame_id: str = ""
    """header.frame_id of its messages."""
    block_of: str = ""
    """The per-sample topic whose samples it carries in blocks (docs/ros-graph.md, "Block transport")."""
    channels: bool = False
    """Its messages carry channels of samples (drive_common.contract.wire.decode_block): the block twins and
    `zero_voltage`, drive_msgs/msg/SampleBlock."""


CURRENTS, ROTOR_STATE, ROTOR_ESTIMATE, INJECTION, VOLTAGE_COMMAND = (
    "currents", "rotor_state", "rotor_estimate", "injection", "voltage_command")
ESTIMATOR_STATE, ESTIMATOR_BLEND, CLOCK, ANGLE_ERROR, JOINT_STATES = (
    "estimator_state", "estimator_blend", "/clock", "angle_error", "joint_states")
SPEED_COMMAND, LOAD_TORQUE, TORQUE_FEEDFORWARD, DRIVE_CONFIG, DIAGNOSTICS = (
    "speed_command", "load_torque", "torque_feedforward", "drive_config", "/diagnostics")
ZERO_VOLTAGE = "zero_voltage"
"""The contract's topic names: code names a topic by these, never by a string of its own."""

VECTOR3 = "geometry_msgs/msg/Vector3Stamped"
JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64 = "std_msgs/msg/Float64"
SAMPLE_BLOCK = "drive_msgs/msg/SampleBlock"
"""A block of samples (drive_common/contract/msg/SampleBlock.msg, built by ./setup.sh): header, labels, three
float64 channels a, b, c; its CDR layout is a JointState's (header, string[], three float64[])."""
LEGACY_TYPES = {SAMPLE_BLOCK: (JOINT_STATE,)}
"""Types a topic had in recordings of older contracts, still read: the blocks were sensor_msgs/JointState (its
position, velocity, effort the channels) up to contract version 2."""

TOPICS = {t.name: t for t in (
    Topic(CURRENTS, VECTOR3, PER_SAMPLE_QOS, True, True, ("i_a_meas", "i_b_meas", "i_c_meas"), frame_id="abc"),
    Topic(ROTOR_STATE, JOINT_STATE, PER_SAMPLE_QOS, True, True, ("theta_m", "omega_m", "tau_e")),
    Topic(ROTOR_ESTIMATE, JOINT_STATE, PER_SAMPLE_QOS, True, True, ("theta_e_hat", "omega_e_hat"),
          electrical=True),
    Topic(INJECTION, VECTOR3, PER_SAMPLE_QOS, True, True, ("u_inj_alpha", "u_inj_beta"), frame_id="alpha_beta"),
    Topic(VOLTAGE_COMMAND, VECTOR3, PER_SAMPLE_QOS, True, True, ("u_alpha", "u_beta"), frame_id="alpha_beta"),
    Topic(ESTIMATOR_STATE, VECTOR3, PER_SAMPLE_QOS, True, True, ("eps", "signal", "state")),
    Topic(ESTIMATOR_BLEND, VECTOR3, PER_SAMPLE_QOS, True, True,
          ("injection_amplitude", "observer_weight", "leader")),
    Topic(CLOCK, "rosgraph_msgs/msg/Clock", PER_SAMPLE_QOS, True, True),
    Topic(ANGLE_ERROR, VECTOR3, OBSERVED_QOS, False, True),
    Topic(JOINT_STATES, JOINT_STATE, COMMAND_QOS, False, True),
    Topic(SPEED_COMMAND, FLOAT64, COMMAND_QOS, False, False, ("omega_m_ref",)),
    Topic(LOAD_TORQUE, FLOAT64, COMMAND_QOS, False, False, ("tau_load",)),
    Topic(TORQUE_FEEDFORWARD, FLOAT64, COMMAND_QOS, False, False),
    Topic(DRIVE_CONFIG, "std_msgs/msg/String", LATCHED_QOS, False, False),
    Topic(DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray", DIAGNOSTICS_QOS, False, False),
    Topic(ZERO_VOLTAGE, SAMPLE_BLOCK, PER_SAMPLE_QOS, False, True, channels=True),
)}
"""`zero_voltage` (behind an inverter, docs/ros-graph.md "Block transport"): the periods of a block (or a
sample) that ran at zero volts instead of their command (1.0 in channel a), published before that block's
currents."""
TOPICS.update({f"{t.name}_block": t._replace(name=f"{t.name}_block", type=SAMPLE_BLOCK, per_sample=False,
                                             block_of=t.name, channels=True)
               for t in list(TOPICS.values()) if t.per_sample and t.log_columns})
"""Each logged per-sample topic has a block twin (``currents_block`` …): drive_msgs/msg/SampleBlock, stamped
with its first sample's instant, the per-sample message's three values as three channels of N samples
(x, y, z of a Vector3Stamped; position, velocity, effort of a JointState) in a, b, c."""
BLOCK_TOPIC = {t.block_of: t.name for t in TOPICS.values() if t.block_of}
"""Per-sample topic → its block twin."""


def block(topic):
    """The block twin of the per-sample topic ``topic`` (``currents`` → ``currents_block``)."""
    return BLOCK_TOPIC[topic]

SAMPLE_LOGGED = tuple(t.name for t in TOPICS.values() if t.per_sample and t.log_columns)
"""The per-sample topics whose content goes into a run's log, each message into its sample's row."""
BLOCK_LOGGED = tuple(BLOCK_TOPIC[topic] for topic in SAMPLE_LOGGED)
"""Their block twins, each message into the rows of its block's samples."""
HELD_LOGGED = tuple(t.name for t in TOPICS.values() if not t.stamped and t.log_columns)
"""Unstamped commands logged from their arrival on, held until the next."""


def full_name(namespace, topic):
    """A contract topic's name in a drive's namespace."""
    return topic if topic.startswith("/") else f"{namespace.rstrip('/')}/{topic}"
