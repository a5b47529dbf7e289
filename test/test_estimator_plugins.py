"""Estimators from outside src/ (docs/estimator-plugins.md): the example package installed into a scratch
environment registers through the entry-point group and runs closed loop and in replay like ours; a
``module:factory`` reference needs no install; a plugin that fails to import, raises, answers NaN or is too
slow is reported as that, never aborting the command or the corpus."""
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from drive_common.config.scenario import load_scenario
from drive_tools.bags.writer import write_run_bag
from drive_tools.evaluation.recording import read_recording
from drive_tools.evaluation.replay import replay, summarise
from drive_tools.runner.runner import run_scenario

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "rotating_injection"


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """A short recording of ours on wang_100rpm, through its start-up into tracking."""
    scenario = dataclasses.replace(load_scenario("wang_100rpm"), duration_s=0.4)
    return write_run_bag(run_scenario(scenario), tmp_path_factory.mktemp("bags") / "wang")


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    """A venv that sees the drive's installed packages (a site directory of its own pointing at them, as
    --system-site-packages would at a system's), the example (a copy: its build stays out of the repository)
    installed into it without dependencies. Its python."""
    env = tmp_path_factory.mktemp("scratch") / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env)], check=True)
    python = env / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    (site / "drive.pth").write_text(f"import site; site.addsitedir({sysconfig.get_paths()['purelib']!r})\n")
    source = env.parent / "rotating_injection"
    shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                    "--target", str(site), str(source)], check=True, cwd=env.parent)
    return python


def drive(python, *argv, cwd=ROOT):
    return subprocess.run([str(python), "-m", "drive_tools.cli", *argv], capture_output=True, text=True, cwd=cwd,
                          env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})


def test_the_installed_example_is_listed_run_closed_loop_and_replayed_without_touching_src(scratch, bag, tmp_path):
    """Installed, the example is an estimator like ours: listed, run closed loop through its start-up into a
    held lock, recorded, and replayed (`drive bench replay`: scored and timed) beside ours on its own
    recording; on ours' recording it is not applicable (its carrier is not there), said so."""
    listed = drive(scratch, "estimators", "--json")
    assert listed.returncode == 0, listed.stderr
    entry = next(e for e in json.loads(listed.stdout) if e["name"] == "rotating_injection")
    assert entry["module"] == "rotating_injection.estimator" and "Jansen" in entry["paper"]
    assert "rotating_injection" not in drive(sys.executable, "estimators").stdout
    recorded = tmp_path / "rotating"
    run = drive(scratch, "run", "wang_100rpm", "--estimator", "rotating_injection", "--duration", "0.6", "--json",
                "--no-plot", "--record", str(recorded), cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    metrics = json.loads(run.stdout)
    assert metrics["startup"]["completed"] and metrics["lock_lost"] == 0
    assert metrics["angle_error_peak"] < 0.3
    for recording, applicable in ((recorded, True), (bag, False)):
        replayed = drive(scratch, "bench", "replay", str(recording), "--estimators",
                         "rotating_injection,injection_frame", "--json", "--no-plot", "--out", str(tmp_path / "r"))
        assert replayed.returncode == 0, replayed.stderr
        results = {e["estimator"]: e for e in json.loads(replayed.stdout)["results"]}
        assert results["injection_frame"]["applicable"]
        mine = results["rotating_injection"]
        assert mine["applicable"] is applicable and mine["samples_per_second"] > 10_000
        if applicable:
            assert mine["angle_error_rms"] < 0.2 and not mine["lost"]
        else:
            assert "carrier" in mine["reason"]


PLUGINS = '''
import math
import numpy as np
from numba import njit
from hf_estimator.interface import Estimator, register

STATE = np.dtype([("theta", np.float64), ("omega", np.float64), ("n", np.float64)])


def made(name, step):
    return lambda nameplate, T_s, settings, commissioning, inverter: Estimator(name, step, 0.0,
                                                                               np.zeros(1, STATE), 0.0)


@njit(cache=False)
def raising_step(x, p, k, sample, out):
    x.n += 1.0
    if k == 700:
        raise ValueError("a plugin's own bug")
    out.theta_e_hat = 0.0


@njit(cache=False)
def nan_step(x, p, k, sample, out):
    out.theta_e_hat = math.nan if k >= 900 else 0.0


@njit(cache=False)
def slow_step(x, p, k, sample, out):
    s = 0.0
    for j in range(400000):
        s += math.sin(j * 1e-3 + k)
    out.theta_e_hat = s * 0.0


raising = register("raising", "raises at sample 700", "none", injects=False, excitation="backemf",
                   injection_kind="none")(made("raising", raising_step))
answering_nan = register("answering_nan", "NaN from sample 900", "none", injects=False, excitation="backemf",
                         injection_kind="none")(made("answering_nan", nan_step))
slow = register("slow", "400 000 sines per sample", "none", injects=False, excitation="backemf",
                injection_kind="none")(made("slow", slow_step))
'''


def test_a_plugin_that_raises_answers_nan_or_is_too_slow_is_reported_per_bag_never_aborting(bag, tmp_path):
    plugins = tmp_path / "plugins.py"
    plugins.write_text(PLUGINS)
    names = [f"{plugins}:{factory}" for factory in ("raising", "answering_nan", "slow")] + ["injection_frame"]
    entries, results = replay(read_recording(bag), names)
    reasons = {e["estimator"]: e["reason"] for e in entries}
    assert reasons[names[0]].startswith("failed: ValueError: a plugin's own bug")
    assert reasons[names[1]] == "answered NaN or ∞ from sample 900 on"
    assert reasons[names[2]].startswith("too slow: ") and "more than the recording's sampling period of 100 µs" \
        in reasons[names[2]]
    assert [r is None for r in results] == [True, True, True, False]
    assert entries[3]["applicable"] and not entries[3]["lost"] and entries[3]["samples_per_second"] > 10_000
    row = {r["estimator"]: r for r in summarise([{"results": entries}], names)}
    assert [row[n]["failed"] for n in names] == [1, 1, 1, 0]


def test_a_plugin_reference_that_cannot_load_is_one_line_naming_it(tmp_path):
    broken = tmp_path / "broken.py"
    broken.write_text("import numpy\nraise RuntimeError('the plugin author forgot something')\n")
    plain = tmp_path / "plain.py"
    plain.write_text("def factory(*args):\n    return None\n")
    for reference, words in ((f"{broken}:factory", "RuntimeError: the plugin author forgot something"),
                             (f"{plain}:factory", "has no factory 'factory' registered with"),
                             (f"{tmp_path / 'absent.py'}:factory", "no file"),
                             ("no_such_module:factory", "ModuleNotFoundError")):
        done = drive(sys.executable, "run", "wang_100rpm", "--estimator", reference, "--duration", "0.01",
                     "--no-plot", cwd=tmp_path)
        assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
        assert done.stderr.startswith(f"drive: --estimator: estimator '{reference}': ") and words in done.stderr


def test_a_plugin_reference_names_its_factory_by_function_or_by_registered_name(tmp_path):
    """`module:factory` takes the factory's function name or the name it registered (the example's
    `rotating_injection.estimator:make_rotating` and `…:rotating_injection` alike); any other name is refused
    listing what the module registers."""
    from hf_estimator.interface import describe, known_estimator

    plugin = tmp_path / "renamed.py"
    plugin.write_text("from hf_estimator.interface import register\n\n\n"
                      "@register('renamed_plugin', 'a factory named apart', 'none', injects=False, "
                      "excitation='backemf', injection_kind='none')\n"
                      "def make_renamed(nameplate, T_s, settings, commissioning, inverter):\n"
                      "    return None\n")
    for factory in ("make_renamed", "renamed_plugin"):
        reference = f"{plugin}:{factory}"
        assert known_estimator(reference) and describe(reference)["description"] == "a factory named apart"
    with pytest.raises(KeyError, match="has no factory 'renamed' registered with .* \\(it registers: "
                                       "renamed_plugin\\)"):
        known_estimator(f"{plugin}:renamed")
