"""The rules every test module keeps (docs/architecture.md, "Tests"): each test function asserts something,
and the `unit` tier reads no wall clock (timing goes to `drive bench`, never into a quick test's verdict)."""
import ast
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

TEST_DIR = Path(__file__).resolve().parent
ASSERTING_CALLS = ("raises", "warns", "fail")
"""pytest's calls that are verdicts themselves; besides them any call named ``assert…`` or ``check…``
(`np.testing.assert_*`, the modules' own checks)."""
WALL_CLOCKS = {"monotonic", "perf_counter", "time", "process_time", "monotonic_ns", "perf_counter_ns", "time_ns"}
"""The ``time`` module's clocks: a unit test that reads one measures the machine's pace."""


def modules():
    return sorted(TEST_DIR.glob("test_*.py"))


def called_name(call):
    return call.func.attr if isinstance(call.func, ast.Attribute) else getattr(call.func, "id", "")


def asserts(function):
    """Whether ``function`` holds an assert, a pytest verdict or a call to an ``assert…``/``check…`` helper."""
    for node in ast.walk(function):
        if isinstance(node, ast.Assert):
            return True
        if isinstance(node, ast.Call):
            name = called_name(node)
            if name in ASSERTING_CALLS or name.startswith(("assert", "check")):
                return True
    return False


def collected_tests(tree):
    return [node for node in ast.walk(tree)
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.name.startswith("test")]


def is_unit(tree):
    return any(isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "pytestmark" for t in node.targets)
               and "unit" in ast.unparse(node.value) for node in tree.body)


def test_every_test_function_asserts():
    silent = [f"{path.name}:{function.lineno} {function.name}" for path in modules()
              for function in collected_tests(ast.parse(path.read_text())) if not asserts(function)]
    assert silent == []


def test_the_rule_finds_a_test_that_only_runs():
    tree = ast.parse("def test_runs():\n    run()\n\ndef test_checks():\n    np.testing.assert_allclose(1, 1)\n\n"
                     "def test_refuses():\n    with pytest.raises(ValueError):\n        run()\n")
    assert [asserts(function) for function in collected_tests(tree)] == [False, True, True]


def test_the_unit_tier_reads_no_wall_clock():
    units = [path for path in modules() if is_unit(ast.parse(path.read_text()))]
    assert len(units) >= 10
    clocked = [f"{path.name}:{node.lineno}" for path in units for node in ast.walk(ast.parse(path.read_text()))
               if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
               and getattr(node.func.value, "id", "") == "time" and node.func.attr in WALL_CLOCKS]
    assert clocked == []


def test_two_test_processes_on_one_machine_never_share_a_ros_domain():
    """This process holds its domain (conftest); another test process started beside it, as another run's worker or
    another clone's run, takes a different one."""
    import os
    import subprocess
    import sys
    claimed = subprocess.run([sys.executable, "-c", "import conftest; print(conftest.DOMAIN)"], cwd=TEST_DIR,
                             capture_output=True, text=True, check=True).stdout.split()[-1]
    assert os.environ["ROS_DOMAIN_ID"] != claimed and 30 <= int(claimed) <= 99
