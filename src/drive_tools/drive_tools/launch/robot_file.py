"""Robot files (YAML, docs/robot.md): a robot's axes (joint name, drive configuration file, link and device
per axis, brake, command timeouts, limits) and the machine's real-time settings, read by `drive up`. Every
error is one line naming the file, the key and the value."""
import os
from dataclasses import dataclass
from pathlib import Path

from drive_common.config.drive_config import ScenarioError
from drive_common.config.scenario import load_drive_configuration
from drive_common.contract.errors import DriveError
from drive_common.contract.settings import FORMAT_VERSION_KEY, Key, read_format_version, read_keys, shown
from drive_common.runtime.realtime import ROBOT_RT_PRIORITY

ROBOT_FORMAT_VERSION = 1
LINKS = ("serial", "can", "virtual")
VIRTUAL_LINKS = ("pty", "can")
LIFECYCLE_STATES = ("unconfigured", "inactive", "active")

ROBOT_KEYS = (
    Key("joint_states_rate_Hz", "Hz", 0.0, 1000.0, default=100.0, doc="how often /joint_states is published"),
    Key("initial_state", "", choices=LIFECYCLE_STATES, default="inactive",
        doc="the lifecycle state every axis is brought to at start"),
)
REAL_TIME_KEYS = (
    Key("rt_priority", "", 0, 99, low_inclusive=True, integer=True, default=None, nullable=True,
        doc="SCHED_FIFO priority of the drive's threads (0: none; default 50, none with a lock-step virtual axis)"),
    Key("cpu_dma_latency_us", "µs", 0, None, low_inclusive=True, integer=True, default=None, nullable=True,
        doc="the CPUs' wake-up latency limit for the run (null: the system's)"),
)
AXIS_KEYS = (
    Key("command_timeout_s", "s", 0.0, 10.0, default=0.1,
        doc="a command older than this: the speed ramps to zero and the joint is held there"),
    Key("hold_timeout_s", "s", 0.0, None, infinite=True, default=2.0,
        doc="a command older than this: zero torque (∞: hold for good)"),
    Key("brake", "", choices=(True, False), default=False,
        doc="the joint has a holding brake: zero torque once it has stopped after a timeout, no hold"),
    Key("reversed", "", choices=(True, False), default=False,
        doc="the joint turns against the motor's positive direction (REP-103 sign of the joint)"),
    Key("velocity_limit_rad_s", "rad/s", 0.0, None, default=None, nullable=True,
        doc="commands above this are refused (null: the drive's speed limit)"),
    Key("effort_limit_Nm", "N·m", 0.0, None, default=None, nullable=True,
        doc="commands above this are refused (null: the drive's stated torque)"),
    Key("stop_deceleration_rad_s2", "rad/s²", 0.0, None, default=None, nullable=True,
        doc="the ramp to zero after a timeout (null: the speed limit, or rated speed, in 0.2 s)"),
    Key("link_timeout_s", "s", 0.0, 10.0, default=0.5,
        doc="no telemetry for this long after there was some: the link is lost, every axis to its safe state"),
    Key("paced", "", choices=(True, False), default=True,
        doc="virtual: the inverter keeps its own clock (as hardware does); false: it waits for each command up to "
            "50 ms (lock-step: simulation at the machine's pace, for tests)"),
    Key("answer", "", choices=("compiled", "nodes"), default="compiled",
        doc="compiled: the armed axis's answer (estimator, protections, controller, the link read and written) is "
            "one compiled function off the interpreter's lock on a thread of its own; nodes: its nodes answer on "
            "the bridge's link thread"),
    Key("inverter_apart", "", choices=(True, False), default=False,
        doc="virtual, paced: the virtual inverter in a process of its own, as a real inverter is a device of its own "
            "(its simulation then never holds the drive's interpreter lock)"),
    Key("baudrate", "baud", 0, None, integer=True, default=3_000_000),
    Key("drive_id", "", 0, 15, low_inclusive=True, integer=True, default=0, doc="CAN drive number"),
)
HOMING_KEYS = (
    Key("method", "", choices=("hard_stop", "index"), doc="how the joint finds its zero (foc_controller.position)"),
    Key("direction", "", choices=(1, -1), doc="the search's direction in the joint's sign"),
    Key("speed_rad_s", "rad/s", 0.0, None, default=None, nullable=True,
        doc="the search's speed (null: 3 % of the motor's rated speed)"),
    Key("current_A", "A", 0.0, None, default=None, nullable=True,
        doc="hard_stop: the stop is where the pushing current exceeds this (or give torque_Nm)"),
    Key("torque_Nm", "N·m", 0.0, None, default=None, nullable=True,
        doc="hard_stop: the stop is where the pushing torque exceeds this (or give current_A)"),
    Key("offset_rad", "rad", default=0.0, doc="the joint's zero from the stop or index, in the joint's sign"),
    Key("backoff_rad", "rad", 0.0, None, low_inclusive=True, default=0.2,
        doc="hard_stop: how far the joint backs off the stop once found"),
    Key("timeout_s", "s", 0.0, None, default=30.0, doc="no stop found within this: homing failed"),
)
"""An axis's ``homing:`` (docs/robot.md "Position"): without it the joint refuses position commands."""
TOPIC_DEFAULTS = {"command_topic": "/joint_commands", "joint_states_topic": "/joint_states"}
"""The robot's topics (absolute names) and their defaults."""
AXIS_WORDS = ("joint", "drive", "link", "namespace", "port", "can_channel", "can_interface", "scenario",
              "virtual_link")
AXIS_SECTIONS = ("homing",)


class RobotFileError(DriveError):
    """A robot file that cannot run: one line naming the file, the key and the value."""


@dataclass(frozen=True)
class AxisSpec:
    """One axis of a robot: its joint, its drive configuration file (what the drive's nodes read, no
    scenario) and namespace, how its inverter is reached (``link``: serial, can, or virtual: a simulated
    machine running ``scenario``'s experiment behind the virtual inverter on ``virtual_link``), and how it
    takes commands (timeouts [s], brake, limits, sign)."""

    joint: str
    drive: str
    namespace: str
    link: str
    port: str = ""
    baudrate: int = 3_000_000
    can_channel: str = "can0"
    can_interface: str = ""
    drive_id: int = 0
    scenario: str = ""
    virtual_link: str = "pty"
    paced: bool = True
    answer: str = "compiled"
    inverter_apart: bool = False
    command_timeout_s: float = 0.1
    link_timeout_s: float = 0.5
    hold_timeout_s: float = 2.0
    brake: bool = False
    reversed: bool = False
    velocity_limit_rad_s: float = None
    effort_limit_Nm: float = None
    stop_deceleration_rad_s2: float = None
    homing: dict = None
    """HOMING_KEYS' values, or None: no homing (position commands refused)."""

    @property
    def sign(self):
        """+1, or −1 where the joint turns against the motor."""
        return -1.0 if self.reversed else 1.0


@dataclass(frozen=True)
class RobotSpec:
    """A robot file: its axes (AxisSpec), topics, the lifecycle state the axes start in, and the machine's
    real-time settings (``rt_priority``, ``cpus``, ``workqueue_cpus``, ``cpu_dma_latency_us``)."""

    source: str
    axes: tuple
    command_topic: str = "/joint_commands"
    joint_states_topic: str = "/joint_states"
    joint_states_rate_Hz: float = 100.0
    initial_state: str = "inactive"
    rt_priority: int = ROBOT_RT_PRIORITY
    cpus: frozenset = None
    workqueue_cpus: frozenset = None
    cpu_dma_latency_us: int = None


def load_robot(path):
    """The RobotSpec of a robot file; RobotFileError naming the file, key and value. Each axis's drive
    configuration is loaded once here, so a bad one is refused before anything runs."""
    import yaml
    file = Path(path)
    if not file.is_file():
        raise RobotFileError(f"{path}: no such robot file")
    source = str(file)

    def fail(key, problem):
        raise RobotFileError(f"{source}: {key}: {problem}")
    try:
        data = yaml.safe_load(file.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise RobotFileError(f"{source}: not YAML ({' '.join(str(error).split())})") from None
    if not isinstance(data, dict):
        raise RobotFileError(f"{source}: top level must be a mapping of keys, not {shown(data)}")
    try:
        read_format_version(data, ROBOT_FORMAT_VERSION, "robot file", source)
        top = read_keys({k: v for k, v in data.items() if k != FORMAT_VERSION_KEY}, ROBOT_KEYS,
                        known_extra=("axes", "real_time", *TOPIC_DEFAULTS))
        real_time = data.get("real_time") or {}
        rt = read_keys(real_time, REAL_TIME_KEYS, "real_time.", known_extra=("cpus", "workqueue_cpus"))
    except ValueError as error:
        raise RobotFileError(f"{source}: {error}") from None
    for key, default in TOPIC_DEFAULTS.items():
        top[key] = data.get(key, default)
        if not isinstance(top[key], str) or not top[key].startswith("/"):
            fail(key, f"must be an absolute topic name, not {shown(top[key])}")
    axes = data.get("axes")
    if not isinstance(axes, list) or not axes:
        fail("axes", f"must be a list of at least one axis, not {shown(axes)}")
    specs = tuple(_axis(entry, f"axes[{i}]", file.parent, fail) for i, entry in enumerate(axes))
    for what in ("joint", "namespace"):
        seen = [getattr(a, what) for a in specs]
        for i, value in enumerate(seen):
            if value in seen[:i]:
                fail(f"axes[{i}].{what}", f"{value!r} is another axis's already")
    # A virtual inverter in lock-step simulates as fast as it is answered: on SCHED_FIFO it would keep the CPU until
    # the kernel throttles real-time work (`drive launch` without --paced takes none of the levers either).
    lock_step = any(a.link == "virtual" and not a.paced for a in specs)
    if rt["rt_priority"] is None:
        rt["rt_priority"] = 0 if lock_step else ROBOT_RT_PRIORITY
    cpus = _cpus(real_time, "cpus", fail, None if lock_step else _last_cpu())
    serial = not lock_step and any(a.link == "serial" or (a.link == "virtual" and a.virtual_link == "pty")
                                   for a in specs)
    workqueue = _cpus(real_time, "workqueue_cpus", fail, cpus if serial else None)
    return RobotSpec(source, specs, top["command_topic"], top["joint_states_topic"], top["joint_states_rate_Hz"],
                     top["initial_state"], rt["rt_priority"], cpus, workqueue, rt["cpu_dma_latency_us"])


def _axis(entry, where, folder, fail):
    """The AxisSpec of one entry of ``axes`` (``where``: its key, e.g. axes[0])."""
    if not isinstance(entry, dict):
        fail(where, f"must be a mapping of keys, not {shown(entry)}")
    try:
        values = read_keys(entry, AXIS_KEYS, f"{where}.", known_extra=AXIS_WORDS + AXIS_SECTIONS)
    except ValueError as error:
        key, problem = str(error).split(": ", 1)
        fail(key, problem)
    for word in AXIS_WORDS:
        if word in entry and (not isinstance(entry[word], str) or not entry[word]):
            fail(f"{where}.{word}", f"must be a non-empty text, not {shown(entry[word])}")
    for word in ("joint", "drive", "link"):
        if word not in entry:
            fail(f"{where}.{word}", "missing")
    joint, link = entry["joint"], entry["link"]
    if link not in LINKS:
        fail(f"{where}.link", f"must be one of {', '.join(LINKS)}, not {shown(link)}")
    needed = {"serial": "port", "virtual": "scenario"}.get(link)
    if needed and needed not in entry:
        fail(f"{where}.{needed}", f"missing (a {link} axis names its {needed})")
    if entry.get("virtual_link", "pty") not in VIRTUAL_LINKS:
        fail(f"{where}.virtual_link", f"must be one of {', '.join(VIRTUAL_LINKS)}, not {shown(entry['virtual_link'])}")
    if values.get("inverter_apart") and (link != "virtual" or not values.get("paced", True)):
        fail(f"{where}.inverter_apart", "a virtual inverter apart needs link: virtual and paced: true")
    drive = Path(entry["drive"])
    drive = drive if drive.is_absolute() else folder / drive
    try:
        load_drive_configuration(drive, f"{where}.drive")
    except ScenarioError as error:
        fail(f"{where}.drive", str(error).split(": ", 1)[1])
    namespace = entry.get("namespace", f"/{joint}")
    if not namespace.startswith("/"):
        fail(f"{where}.namespace", f"must be absolute (/{namespace}), not {shown(namespace)}")
    scenario = entry.get("scenario", "")
    if scenario and (folder / scenario).is_file():
        scenario = str(folder / scenario)
    words = {w: entry[w] for w in ("port", "can_channel", "can_interface", "virtual_link") if w in entry}
    return AxisSpec(joint=joint, drive=str(drive), namespace=namespace, link=link, scenario=scenario,
                    homing=_homing(entry.get("homing"), f"{where}.homing", fail), **words, **values)


def _homing(section, where, fail):
    """The values of an axis's ``homing:`` section (HOMING_KEYS), None where it has none."""
    if section is None:
        return None
    if not isinstance(section, dict):
        fail(where, f"must be a mapping of keys, not {shown(section)}")
    try:
        values = read_keys(section, HOMING_KEYS, f"{where}.")
    except ValueError as error:
        key, problem = str(error).split(": ", 1)
        fail(key, problem)
    if values["method"] == "hard_stop" and (values["current_A"] is None) == (values["torque_Nm"] is None):
        fail(where, "hard_stop: give current_A or torque_Nm (one of them): where the stop is found")
    return values


def _cpus(section, key, fail, default):
    """The CPU set of ``real_time.KEY`` (a list of CPU numbers or null), else ``default``."""
    if key not in section:
        return default
    value = section[key]
    if value is None:
        return None
    allowed = os.sched_getaffinity(0)
    if not isinstance(value, list) or not value or not all(isinstance(c, int) and not isinstance(c, bool)
                                                            for c in value):
        fail(f"real_time.{key}", f"must be a list of CPU numbers, or null, not {shown(value)}")
    if not set(value) <= allowed:
        fail(f"real_time.{key}", f"{shown(value)} is not among this process's CPUs {sorted(allowed)}")
    return frozenset(value)


def _last_cpu():
    """The robot's default CPU: the last of two or more (as `drive launch --paced` takes), else None."""
    cpus = sorted(os.sched_getaffinity(0))
    return frozenset({cpus[-1]}) if len(cpus) > 1 else None
