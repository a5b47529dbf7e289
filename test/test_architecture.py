"""The shape of the code: packages with one job whose dependencies point one way, no import cycle, the
estimator and controller blind to the plant, every node package with its own executable and a package.xml
that declares what it uses, one log-row writer, findable estimators, and a clean linter."""
import ast
import inspect
import re
import subprocess
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
PACKAGES = sorted(p.name for p in SRC.iterdir() if (p / p.name / "__init__.py").is_file())
NODE_EXECUTABLES = {"pmsm_plant": "plant_node", "hf_estimator": "estimator_node",
                    "foc_controller": "controller_node", "drive_bridge": "bridge_node",
                    "drive_commissioning": "commissioning_node"}
ROSDEP_KEYS = {"numpy": "python3-numpy", "numba": "python3-numba", "scipy": "python3-scipy",
               "yaml": "python3-yaml", "matplotlib": "python3-matplotlib", "serial": "python3-serial",
               "can": "python3-can", "mcap": "python3-mcap", "rosbags": "python3-rosbags", "rclpy": "rclpy"}
MESSAGE_PACKAGES = {"geometry_msgs", "sensor_msgs", "std_msgs", "rosgraph_msgs", "diagnostic_msgs",
                    "builtin_interfaces", "rcl_interfaces", "std_srvs"}
OWN_ENVIRONMENT = {SRC / "drive_evaluation" / "drive_evaluation" / "motulator_reference.py"}
"""Runs in motulator's own environment, importing nothing of this project."""


def modules():
    """{module name: path} of every module under src/."""
    found = {}
    for package in PACKAGES:
        for path in (SRC / package / package).rglob("*.py"):
            parts = path.relative_to(SRC / package).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imports(name, path):
    """The absolute names a module imports, anywhere in it (function-level imports included)."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([node.module] if node.module else []))
            names.add(base)
            names |= {f"{base}.{alias.name}" for alias in node.names}
    return names


def module_graph():
    known = modules()
    return {name: {i for i in imports(name, path) if i in known and i != name} for name, path in known.items()}


def find_cycle(graph):
    """One cycle of a {node: successors} graph as a list, or None."""
    state, stack = {}, []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for successor in sorted(graph.get(node, ())):
            if state.get(successor) == "open":
                return stack[stack.index(successor):] + [successor]
            if successor not in state and (cycle := visit(successor)):
                return cycle
        state[node] = "done"
        stack.pop()
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def package_graph():
    graph = {package: set() for package in PACKAGES}
    for name, successors in module_graph().items():
        graph[name.split(".")[0]] |= {s.split(".")[0] for s in successors} - {name.split(".")[0]}
    return graph


def test_no_import_cycle_between_modules_or_packages():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle(module_graph()) is None
    assert find_cycle(package_graph()) is None


def test_the_drive_knows_the_motor_only_by_its_nameplate_and_what_it_measures():
    """Estimator, controller and commissioning import nothing of the plant, nor of what composes the
    drive; the commissioning core imports no rclpy."""
    forbidden = {"pmsm_plant", "drive_runner", "drive_launch", "drive_bags", "drive_evaluation", "drive_cli",
                 "drive_bridge"}
    graph = package_graph()
    for package in ("hf_estimator", "foc_controller", "drive_commissioning"):
        assert graph[package] & forbidden == set(), package
    core = SRC / "drive_commissioning" / "drive_commissioning"
    for path in (core / "procedure.py", core / "identification.py"):
        assert not {name.split(".")[0] for name in imports(f"drive_commissioning.{path.stem}", path)} & {
            "rclpy", "geometry_msgs"}, path
    shared = {"control_math", "motor_params", "drive_interface", "drive_scenarios"}
    assert graph["pmsm_plant"] <= shared
    for package in shared:
        assert graph[package] <= shared, package


def test_the_bridge_package_holds_only_the_inverter_link():
    """The protocol, the links (a serial port, a CAN bus, the CAN cable between processes), the bridge and
    its node; and the virtual inverter that stands in for a real one, with its own process."""
    names = {p.stem for p in (SRC / "drive_bridge" / "drive_bridge").glob("*.py")}
    assert names == {"__init__", "inverter_protocol", "inverter_link", "can_cable", "inverter_bridge", "bridge_node",
                     "virtual_inverter", "inverter_process"}


def declared(package):
    root = ElementTree.parse(SRC / package / "package.xml").getroot()
    assert root.findtext("name") == package
    return {element.text for element in root.iter() if element.tag.endswith("depend")}


@pytest.mark.parametrize("package", PACKAGES)
def test_package_xml_declares_every_dependency_it_uses(package):
    used = set()
    for name, path in modules().items():
        if name.split(".")[0] != package or path in OWN_ENVIRONMENT:
            continue
        for imported in imports(name, path):
            top = imported.split(".")[0]
            if top in PACKAGES and top != package:
                used.add(top)
            elif top in ROSDEP_KEYS:
                used.add(ROSDEP_KEYS[top])
            elif top in MESSAGE_PACKAGES:
                used.add(top)
    assert used <= declared(package), f"{package}/package.xml lacks {sorted(used - declared(package))}"


@pytest.mark.parametrize("package, executable", sorted(NODE_EXECUTABLES.items()))
def test_each_node_package_has_its_own_executable(package, executable):
    setup = (SRC / package / "setup.py").read_text()
    assert re.search(rf'"{executable} = {package}\.[a-z_]+:main"', setup)
    script = Path(sys.executable).with_name(executable)
    assert script.is_file(), f"{executable} not installed (./setup.sh)"
    out = subprocess.run([str(script), "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "--executor" in out.stdout


def test_one_writer_fills_a_log_row_in_the_log_layout():
    from drive_interface.log import LOG_COLUMNS
    from drive_runner.loop import write_row
    assert tuple(inspect.signature(write_row.py_func).parameters)[1:] == LOG_COLUMNS


def test_the_topic_table_serves_qos_types_and_log_columns():
    from drive_interface.log import COLUMN
    from drive_interface.topics import SAMPLE_LOGGED, TOPICS
    assert {t.name for t in TOPICS.values() if t.per_sample} == {"currents", "rotor_state", "rotor_estimate",
                                                                  "injection", "voltage_command",
                                                                  "estimator_state", "estimator_blend", "/clock"}
    assert set(SAMPLE_LOGGED) == {"currents", "rotor_state", "rotor_estimate", "injection", "voltage_command",
                                  "estimator_state", "estimator_blend"}
    for topic in TOPICS.values():
        assert all(column in COLUMN for column in topic.log_columns), topic.name


def test_estimator_modules_are_named_after_their_registered_names():
    """An ``_aligned`` variant lives in its method's module."""
    from hf_estimator.registry import describe, estimator_names
    for name in estimator_names():
        entry = describe(name)
        assert entry["module"] == f"hf_estimator.{name.removesuffix('_aligned')}" and entry["paper"], name


def test_every_numba_kernel_has_a_docstring():
    missing = []
    for name, path in modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and not ast.get_docstring(node) and any(
                    ast.unparse(d).startswith("njit") for d in node.decorator_list):
                missing.append(f"{name}.{node.name}")
    assert missing == []


def test_every_estimator_steps_on_named_records():
    """Each registered estimator's step reads a SAMPLE and writes an ESTIMATE record, on a state record
    whose first fields are θ̂ and ω̂; the ESTIMATE fields are the log's columns of the same names."""
    import inspect

    from drive_interface.estimator_records import ESTIMATE_FIELDS
    from drive_interface.log import COLUMN
    from hf_estimator.registry import estimator_names, make_estimator
    from motor_params.commissioning import nameplate_commissioning
    from motor_params.motor_file import load_motor

    assert set(ESTIMATE_FIELDS) <= set(COLUMN)
    motor = load_motor("wang_spmsm", "test")
    for name in estimator_names():
        e = make_estimator(name, motor.nameplate, 1e-4, {}, nameplate_commissioning(motor.nameplate),
                           motor.inverter._replace(delay_periods=1))
        assert list(inspect.signature(e.step.py_func).parameters) == ["x", "p", "k", "sample", "out"], name
        assert e.state.shape == (1,) and e.state.dtype.names[:2] == ("theta", "omega"), name


def test_record_types_are_mangled_alike_in_every_process():
    """Kernels cached on disk by one process are linked by name in another: a record type's mangled name
    must not depend on what else the process typed first (numba issue #7654, drive_interface.numba_records),
    and two layouts must never share one."""
    program = ("import sys, numpy as np, numba; from drive_interface import numba_records; "
               "from numba.core.itanium_mangler import mangle_type; "
               "[numba.typeof(np.zeros(1, [(n, 'f8')])[0]) for n in sys.argv[1:]]; "
               "print(*(mangle_type(numba.typeof(np.zeros(1, [('theta', 'f8'), ('ring', 'f8', (n,))])[0])) "
               "for n in (3, 5)))")
    names = [subprocess.run([sys.executable, "-c", program, *before], capture_output=True, text=True,
                            check=True).stdout.split() for before in ((), ("a", "b", "c"))]
    assert names[0] == names[1] and names[0][0] != names[0][1]


def test_topic_names_come_only_from_the_topic_table():
    """Nodes, the launcher and the bags name a contract topic by drive_interface.topics' constants, never
    by a string of their own (a JSON key of drive_config that happens to share a topic's name is not one)."""
    from drive_interface.topics import TOPICS
    names = "|".join(re.escape(name) for name in TOPICS)
    quoted = re.compile(rf"""(["'])({names})\1(?!\s*:)""")
    places = [*SRC.glob("*/*/node.py"), *SRC.glob("*/*/*_node.py"), *SRC.glob("drive_launch/drive_launch/*.py"),
              *SRC.glob("drive_bags/drive_bags/*.py")]
    offending = [f"{path.relative_to(SRC)}:{number}" for path in places
                 for number, line in enumerate(path.read_text().splitlines(), 1)
                 if quoted.search(line) and ".get(" not in line]
    assert offending == []


CLI_MODULE_MAX_LINES = 300


def test_the_command_line_is_one_module_per_family():
    """Each drive_cli module stays under CLI_MODULE_MAX_LINES (a report's text lines live with the report:
    drive_evaluation.*_report, drive_bags)."""
    for path in (SRC / "drive_cli" / "drive_cli").glob("*.py"):
        assert len(path.read_text().splitlines()) < CLI_MODULE_MAX_LINES, path.name


def test_nothing_cites_a_path_outside_the_repository():
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True)
    offending = []
    for line in tracked.stdout.splitlines():
        path = ROOT / line
        if path.suffix in (".py", ".md", ".yaml", ".xml", ".cfg", ".toml", ".sh") and path.is_file():
            if re.search(r"\.\./shared|shared/(notes|papers|drive-interface)", path.read_text()):
                offending.append(line)
    assert offending == []


def test_ruff_is_clean():
    out = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "."], cwd=ROOT, capture_output=True,
                         text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def _commands(parser, words):
    """Every leaf command of the `drive` parser, as its words."""
    import argparse
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, words + [name])
            return
    yield words


def test_every_command_is_on_the_commands_page_and_the_readme_stays_short():
    """docs/commands.md lists every subcommand the parser has (in a row of its group); README.md, the front
    door, stays within 10,000 bytes and links to the page."""
    from drive_cli.cli import build_parser
    rows = [line for line in (ROOT / "docs" / "commands.md").read_text().splitlines() if line.startswith("| `drive")]
    commands = list(_commands(build_parser(), []))
    assert len(commands) >= 20
    for words in commands:
        leaf = re.escape(words[-1])
        assert any(f"`drive {words[0]}" in row and re.search(rf"[\s`/|]{leaf}([\s`\[\]\\|]|$)", row)
                   for row in rows), f"drive {' '.join(words)} is not on docs/commands.md"
    readme = (ROOT / "README.md").read_bytes()
    assert len(readme) <= 10_000 and b"docs/commands.md" in readme
