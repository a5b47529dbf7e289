"""The shape of the code: at most six packages, whose dependencies point one way in at most five layers, no
import cycle, storage apart from the runner and the estimators, the estimator and controller blind to the
plant, every node with its own executable and a package.xml that declares what it uses, docs/architecture.md's
graph as the code has it, one log-row writer, findable estimators, and a clean linter."""
import ast
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
NODE_EXECUTABLES = {"plant_node": "pmsm_plant", "estimator_node": "hf_estimator",
                    "commissioning_node": "hf_estimator.commissioning", "controller_node": "foc_controller",
                    "bridge_node": "drive_bridge"}
"""Each node's executable → the package (or subpackage) of its module."""
LIBRARY, TOOLS = "drive_common", "drive_tools"
"""What the node packages share, and what composes them: neither has a node."""
MAX_PACKAGES, MAX_LAYERS = 6, 5
ROSDEP_KEYS = {"numpy": "python3-numpy", "numba": "python3-numba", "scipy": "python3-scipy",
               "yaml": "python3-yaml", "matplotlib": "python3-matplotlib", "serial": "python3-serial",
               "can": "python3-can", "mcap": "python3-mcap", "rosbags": "python3-rosbags", "rclpy": "rclpy",
               "dask": "python3-dask", "distributed": "python3-distributed"}
MESSAGE_PACKAGES = {"geometry_msgs", "sensor_msgs", "std_msgs", "rosgraph_msgs", "diagnostic_msgs",
                    "builtin_interfaces", "rcl_interfaces", "std_srvs"}
OWN_ENVIRONMENT = {SRC / TOOLS / TOOLS / "evaluation" / "motulator_reference.py"}
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


def unit(name):
    """The unit a module belongs to in the layer picture: a node package, or a subpackage of the library or
    the tools (``drive_common.motor``, ``drive_tools.bags``)."""
    parts = name.split(".")
    return ".".join(parts[:2]) if parts[0] in (LIBRARY, TOOLS) and len(parts) > 1 else parts[0]


def graph_of(key):
    graph = {}
    for name, successors in module_graph().items():
        graph.setdefault(key(name), set()).update({key(s) for s in successors} - {key(name)})
    return graph


def package_graph():
    return graph_of(lambda name: name.split(".")[0])


def layer_of(graph):
    """{node: its layer} of an acyclic {node: successors} graph: one above the highest it points to (1: none)."""
    depth = {}

    def of(node):
        if node not in depth:
            depth[node] = 1 + max((of(s) for s in graph.get(node, ())), default=0)
        return depth[node]

    for node in graph:
        of(node)
    return depth


def layers(graph):
    """The number of layers of an acyclic {node: successors} graph: the nodes on its longest path."""
    return max(layer_of(graph).values())


def test_no_import_cycle_between_modules_subpackages_or_packages():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle(module_graph()) is None
    assert find_cycle(graph_of(unit)) is None
    assert find_cycle(package_graph()) is None


def test_at_most_six_packages_in_at_most_five_layers():
    """The design card's four node packages, one library (what they share) and one tools package (what
    composes them); the package graph at most five layers deep."""
    assert set(PACKAGES) == {"pmsm_plant", "hf_estimator", "foc_controller", "drive_bridge", LIBRARY, TOOLS}
    assert len(PACKAGES) <= MAX_PACKAGES and layers({"a": {"b"}, "b": {"c"}, "c": set()}) == 3
    assert layers(package_graph()) <= MAX_LAYERS
    assert package_graph()[LIBRARY] == set()


def test_the_library_and_the_tools_have_no_node():
    """Only the node packages install node executables; the tools install the `drive` command."""
    for package in (LIBRARY, TOOLS):
        scripts = re.findall(r'"(\w+) = [\w.]+:main"', (SRC / package / "setup.py").read_text())
        assert scripts == ([] if package == LIBRARY else ["drive"]), package
        assert not list((SRC / package / package).rglob("*node.py")) or package == LIBRARY, package


def test_storage_imports_neither_the_runner_nor_the_estimators():
    """A recording is read and written by drive_tools.bags with the contract alone: no runner, launcher,
    evaluation, estimator, controller or plant behind it."""
    bags = graph_of(unit)[f"{TOOLS}.bags"]
    assert bags <= {f"{LIBRARY}.{sub}" for sub in ("contract", "config", "motor", "math", "runtime")}, bags


def test_the_drive_knows_the_motor_only_by_its_nameplate_and_what_it_measures():
    """Estimator (commissioning included) and controller import nothing of the plant, nor of what composes
    the drive; the commissioning core imports no rclpy; the plant imports only the library."""
    forbidden = {"pmsm_plant", TOOLS, "drive_bridge"}
    graph = package_graph()
    for package in ("hf_estimator", "foc_controller"):
        assert graph[package] & forbidden == set(), package
    core = SRC / "hf_estimator" / "hf_estimator" / "commissioning"
    for path in (core / "procedure.py", core / "identification.py"):
        assert not {name.split(".")[0] for name in imports(f"hf_estimator.commissioning.{path.stem}", path)} & {
            "rclpy", "geometry_msgs"}, path
    assert graph["pmsm_plant"] == {LIBRARY}


def documented_graph():
    """{unit: imported units} as docs/architecture.md's "who imports whom" table states it."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    table = text[text.index("| unit | imports |"):].split("\n\n")[0].splitlines()[2:]
    graph = {}
    for row in table:
        units, imported = row.strip("|").split("|")
        for name in re.findall(r"`([\w.]+)`", units):
            graph[name] = set(re.findall(r"[\w.]+", imported.replace("—", "")))
    return graph


def documented_layers():
    """{package: layer} as docs/architecture.md's picture states it (a line ``layer N   package …``)."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    return {name: int(number) for number, line in re.findall(r"(?m)^ layer (\d)\s+(.*)$", text)
            for name in re.findall(r"\w+", line) if name in PACKAGES}


def test_the_architecture_page_states_the_graph_the_code_has():
    """docs/architecture.md's picture puts each package in its layer (one above the highest it imports) and
    its table of who imports whom is the code's, unit by unit (a node package, or a subpackage of the library
    or the tools); its package count is the code's."""
    layer = layer_of(package_graph())
    assert documented_layers() == {package: layer[package] for package in PACKAGES}
    units = {name: imported for name, imported in graph_of(unit).items() if name not in (LIBRARY, TOOLS)}
    assert documented_graph() == units
    text = (ROOT / "docs" / "architecture.md").read_text()
    words = {4: "Four", 5: "Five", 6: "Six"}
    assert text.startswith(f"# Architecture\n\n{words[len(PACKAGES)]} packages under `src/`")


def test_the_bridge_package_holds_only_the_inverter_link():
    """The protocol (its serial and CAN codecs' kernels), the links (a serial port, a CAN bus, the CAN cable
    between processes), the bridge and its node, on the library alone: the virtual inverter that stands in for
    a real one lives with the test doubles (drive_tools.doubles)."""
    names = {p.stem for p in (SRC / "drive_bridge" / "drive_bridge").glob("*.py")}
    assert names == {"__init__", "inverter_protocol", "frame_codec", "can_codec", "inverter_link", "can_cable",
                     "compiled_io", "inverter_bridge", "compiled_bridge", "bridge_node"}
    assert package_graph()["drive_bridge"] == {LIBRARY}


TEST_HOOK = re.compile(r"fault_plan|\w*_hook|lose_\w+|hold_collector")
"""Parameter names of fault injection and test hooks."""
MAX_PARAMETERS = 8


def functions(package):
    """(module name, function) of every function and method defined in ``package``'s modules."""
    for name, path in modules().items():
        if name.split(".")[0] == package:
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    yield name, node


def parameters(function):
    """A function's parameter names, ``self``/``cls`` left out."""
    a = function.args
    names = [arg.arg for arg in a.posonlyargs + a.args + a.kwonlyargs]
    return names[1:] if names[:1] in (["self"], ["cls"]) else names


def test_test_doubles_are_apart_from_what_runs_a_drive():
    """Fault injection and test hooks live in drive_tools.doubles (as ros2_control's mock components): no
    function elsewhere takes a fault plan, a hook, a loss rate or a lever of that kind; a test or bench that
    needs faults composes a faulty double (drive_tools.doubles.faults) instead."""
    offending = [f"{module}.{function.name}({name})" for package in PACKAGES for module, function in functions(package)
                 if not module.startswith(f"{TOOLS}.doubles") for name in parameters(function)
                 if TEST_HOOK.fullmatch(name)]
    assert offending == []


def test_every_function_takes_named_records():
    """Kernels, loops and what composes them take named records (inputs, state, parameters, outputs:
    PlantParams, DRIVE_INPUT, ClosedLoop, DriveSpec, GraphOptions, InverterOptions, ...), not long argument
    lists: at most MAX_PARAMETERS parameters each, in every package (``*args``/``**kwargs`` not counted)."""
    offending = [f"{module}.{function.name}: {len(parameters(function))}" for package in PACKAGES
                 for module, function in functions(package) if len(parameters(function)) > MAX_PARAMETERS]
    assert offending == []


def test_every_path_the_docs_cite_exists():
    """A `src/…` path named in README.md or docs/ is a file or folder of the repository."""
    cited = set()
    for page in [ROOT / "README.md", *(ROOT / "docs").rglob("*.md")]:
        cited |= {(page.name, p.rstrip(".")) for p in re.findall(r"src/[\w/.]+", page.read_text())}
    assert [f"{page}: {path}" for page, path in sorted(cited) if not (ROOT / path).exists()] == []


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


def test_each_node_has_its_own_executable():
    """Every node's console script is declared by its package and answers --help (all started at once)."""
    started = {}
    for executable, package in sorted(NODE_EXECUTABLES.items()):
        setup = (SRC / package.split(".")[0] / "setup.py").read_text()
        assert re.search(rf'"{executable} = {re.escape(package)}\.[a-z_]+:main"', setup), executable
        script = Path(sys.executable).with_name(executable)
        assert script.is_file(), f"{executable} not installed (./setup.sh)"
        started[executable] = subprocess.Popen([str(script), "--help"], stdout=subprocess.PIPE,
                                               stderr=subprocess.PIPE, text=True)
    for executable, process in started.items():
        out, err = process.communicate(timeout=60)
        assert process.returncode == 0 and "--executor" in out, (executable, err)


def test_one_writer_fills_a_log_row_in_the_log_layout():
    """write_row puts every value of its records into the log column of the same quantity: the plant's truth,
    the drive's inputs (DRIVE_INPUT), the estimate (ESTIMATE, columns of its field names) and the command
    (COMMAND), each given a value of its own, land where LOG_COLUMNS names them, every column once."""
    import numpy as np

    from drive_common.contract.drive_records import commands, drive_inputs
    from drive_common.contract.estimator_records import ESTIMATE_FIELDS, estimates
    from drive_common.contract.log import LOG_COLUMNS
    from drive_tools.runner.loop import write_row
    truth = ("theta_m", "omega_m", "tau_e", "tau_load", "i_a", "i_b", "i_c")
    from_inputs = {"i_a_meas": "i_a_A", "i_b_meas": "i_b_A", "i_c_meas": "i_c_A", "omega_m_ref": "omega_m_ref_rad_s"}
    from_command = {"u_alpha": "u_alpha_V", "u_beta": "u_beta_V", "i_d": "i_d_A", "i_q": "i_q_A",
                    "i_d_ref": "i_d_ref_A", "i_q_ref": "i_q_ref_A"}
    value = {name: float(i + 1) for i, name in enumerate(LOG_COLUMNS)}
    inputs, estimate, command = drive_inputs(1), estimates(1), commands(1)
    for column, field in from_inputs.items():
        inputs[field] = value[column]
    for field in ESTIMATE_FIELDS:
        estimate[field] = value[field]
    for column, field in from_command.items():
        command[field] = value[column]
    assert sorted(("t", *truth, *from_inputs, *ESTIMATE_FIELDS, *from_command)) == sorted(LOG_COLUMNS)
    row = np.zeros(len(LOG_COLUMNS))
    write_row(row, value["t"], tuple(value[name] for name in truth), inputs[0], estimate[0], command[0])
    assert row.tolist() == [value[name] for name in LOG_COLUMNS]


def test_the_topic_table_serves_qos_types_and_log_columns():
    from drive_common.contract.log import COLUMN
    from drive_common.contract.topics import SAMPLE_LOGGED, TOPICS
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

    from drive_common.contract.estimator_records import ESTIMATE_FIELDS
    from drive_common.contract.log import COLUMN
    from drive_common.motor.commissioning import nameplate_commissioning
    from drive_common.motor.motor_file import load_motor
    from hf_estimator.registry import estimator_names, make_estimator

    assert set(ESTIMATE_FIELDS) <= set(COLUMN)
    motor = load_motor("wang_spmsm", "test")
    for name in estimator_names():
        e = make_estimator(name, motor.nameplate, 1e-4, {}, nameplate_commissioning(motor.nameplate),
                           motor.inverter._replace(delay_periods=1))
        assert list(inspect.signature(e.step.py_func).parameters) == ["x", "p", "k", "sample", "out"], name
        assert e.state.shape == (1,) and e.state.dtype.names[:2] == ("theta", "omega"), name


def test_record_types_are_mangled_alike_in_every_process():
    """Kernels cached on disk by one process are linked by name in another: a record type's mangled name
    must not depend on what else the process typed first (numba issue #7654, drive_common.contract.numba_records),
    and two layouts must never share one."""
    program = ("import sys, numpy as np, numba; from drive_common.contract import numba_records; "
               "from numba.core.itanium_mangler import mangle_type; "
               "[numba.typeof(np.zeros(1, [(n, 'f8')])[0]) for n in sys.argv[1:]]; "
               "print(*(mangle_type(numba.typeof(np.zeros(1, [('theta', 'f8'), ('ring', 'f8', (n,))])[0])) "
               "for n in (3, 5)))")
    names = [subprocess.run([sys.executable, "-c", program, *before], capture_output=True, text=True,
                            check=True).stdout.split() for before in ((), ("a", "b", "c"))]
    assert names[0] == names[1] and names[0][0] != names[0][1]


def test_a_kernel_taking_a_step_is_loaded_from_the_cache_in_the_next_process():
    """The runner's loop bound to an estimator's step (drive_common.runtime.bound_kernels) compiles in one process
    at most and loads from numba's cache in the next (a kernel passed as an argument would compile in every one);
    a step from outside the project's packages (a plugin's) is passed as an argument, never cached."""
    program = ("import dataclasses; from drive_common.config.scenario import load_scenario; "
               "from drive_common.runtime.bound_kernels import bound; from drive_tools.runner.loop import run_blocks; "
               "from drive_tools.runner.runner import run_scenario; "
               "run_scenario(dataclasses.replace(load_scenario('wang_100rpm'), duration_s=0.002)); "
               "from hf_estimator.injection_frame import injection_frame_step as step; "
               "print(sum(bound(run_blocks, step).stats.cache_hits.values()))")
    hits = [int(subprocess.run([sys.executable, "-c", program], capture_output=True, text=True,
                               check=True).stdout.split()[-1]) for _ in range(2)]
    assert hits[1] == 1, hits
    from drive_common.runtime.bound_kernels import bound
    from drive_tools.runner.loop import run_blocks

    def plugin_step():
        pass
    plugin_step.__module__ = "my_estimators.step"
    assert bound(run_blocks, plugin_step).args == (plugin_step,)


def test_topic_names_come_only_from_the_topic_table():
    """Nodes, the launcher and the bags name a contract topic by drive_common.contract.topics' constants, never
    by a string of their own (a JSON key of drive_config that happens to share a topic's name is not one)."""
    from drive_common.contract.topics import TOPICS
    names = "|".join(re.escape(name) for name in TOPICS)
    quoted = re.compile(rf"""(["'])({names})\1(?!\s*:)""")
    places = [*SRC.rglob("node.py"), *SRC.rglob("*_node.py"), *(SRC / TOOLS / TOOLS / "launch").glob("*.py"),
              *(SRC / TOOLS / TOOLS / "bags").glob("*.py")]
    offending = [f"{path.relative_to(SRC)}:{number}" for path in places
                 for number, line in enumerate(path.read_text().splitlines(), 1)
                 if quoted.search(line) and ".get(" not in line]
    assert offending == []


CLI_MODULE_MAX_LINES = 300


def test_the_command_line_is_one_module_per_family():
    """Each drive_tools.cli module stays under CLI_MODULE_MAX_LINES (a report's text lines live with the
    report: drive_tools.evaluation.*_report, drive_tools.bags)."""
    for path in (SRC / TOOLS / TOOLS / "cli").glob("*.py"):
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
            seen = set()
            for name, sub in action.choices.items():
                if id(sub) not in seen:
                    seen.add(id(sub))
                    yield from _commands(sub, words + [name])
            return
    yield words


def test_every_command_is_on_the_commands_page_and_the_readme_stays_short():
    """docs/commands.md lists every subcommand the parser has (in a row of its group); README.md, the front
    door, stays within 10,000 bytes and links to the page."""
    from drive_tools.cli.cli import build_parser
    rows = [line for line in (ROOT / "docs" / "commands.md").read_text().splitlines() if line.startswith("| `drive")]
    commands = list(_commands(build_parser(), []))
    assert len(commands) >= 20
    for words in commands:
        leaf = re.escape(words[-1])
        assert any(f"`drive {words[0]}" in row and re.search(rf"[\s`/|]{leaf}([\s`\[\]\\|]|$)", row)
                   for row in rows), f"drive {' '.join(words)} is not on docs/commands.md"
    readme = (ROOT / "README.md").read_bytes()
    assert len(readme) <= 10_000 and b"docs/commands.md" in readme
