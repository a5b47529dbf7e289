"""Fixed-seed fuzz of the files a user writes: motor files and scenarios (mutations of the shipped ones)
and drive configuration files (alone and named by a scenario's ``drive:``). Each case is accepted with every value in
its declared range and as written, or refused naming the file and the key; through the command line as
one line, exit 2, no traceback."""
import json
import math
import random
import re
import subprocess
import sys

import pytest
import yaml

from drive_common.config.scenario import SCENARIO_DIR, ScenarioError, load_drive_configuration, load_scenario
from drive_common.contract.errors import DriveError
from drive_common.motor.motor_file import (
    BUS_PER_RATED_SPEED_NEED,
    MOTOR_DIR,
    MotorFileError,
    load_motor,
    rated_speed_bus_V,
)
from drive_common.motor.nameplate import CURRENT_LIMIT_PER_RATED, NAMEPLATE_KEYS
from drive_tools.cli.cli import main
from drive_tools.runner.runner import build_drive
from helpers import blames, mutate
from pmsm_plant.presets import plant_truth

DRIVE = [sys.executable, "-m", "drive_tools.cli"]
SAMPLE_CASES, FULL_CASES = 250, 2500
"""Mutated files per family in the default run, and under the `heavy` marker."""
RELATED = {
    "rated_current_A": ("nameplate.current_limit_A",),
    "current_limit_A": ("nameplate.current_limit_A",),
    "psi_f_Wb": ("inverter.U_dc_V",),
    "rated_speed_rpm": ("inverter.U_dc_V",),
    "n_p": ("inverter.U_dc_V",),
    "L_d_H": ("plant.L_dh_H",),
    "L_q_H": ("plant.L_qh_H",),
    "J_kgm2": ("plant.J_kgm2",),
}
"""A nameplate or plant key whose change another key's rule may refuse (current limit ≤ 3 × rated, a bus ≤ 20 × what
rated speed needs, saturation lowering the plant's inductances, a simulated shaft needing an inertia)."""


def motor_cases(seed, count):
    """(name, motor file text, kind, trail, value, blamed) from mutations of the shipped motor files."""
    rng = random.Random(seed)
    shipped = {path.stem: yaml.safe_load(path.read_text()) for path in sorted(MOTOR_DIR.glob("*.yaml"))}
    for i in range(count):
        motor = rng.choice(sorted(shipped))
        document = yaml.safe_load(yaml.safe_dump(shipped[motor]))
        kind, trail, value, blamed = mutate(rng, document)
        blamed += RELATED.get(trail[-1], ())
        yield (f"{i:03d}_{motor}_{kind}", yaml.safe_dump(document, allow_unicode=True), kind, trail, value, blamed)


def assert_accepted_as_declared(motor, kind, trail, value):
    """Every nameplate value finite (J, B: or not known) and in its declared range, the current-limit and
    bus rules kept, a value changed in the nameplate or inverter taken as written, the plant's truth finite (a DC
    link's ∞: a stiff bus, no chopper; an end stop's ±∞: none)."""
    plate = motor.nameplate
    for key in NAMEPLATE_KEYS:
        v = getattr(plate, key.name)
        assert (key.name in ("J_kgm2", "B_Nms") and math.isnan(v)) or key.read(v) == v, (key.name, v)
    assert isinstance(plate.n_p, int)
    assert plate.current_limit_A <= CURRENT_LIMIT_PER_RATED * plate.rated_current_A
    assert 0.0 < motor.inverter.U_dc_V <= BUS_PER_RATED_SPEED_NEED * rated_speed_bus_V(plate)
    assert motor.inverter.delay_periods in (0, 1, 2)
    if kind in ("hostile", "slip") and len(trail) == 2 and trail[0] in ("nameplate", "inverter"):
        taken = getattr(plate if trail[0] == "nameplate" else motor.inverter, trail[1])
        assert taken == value and type(value) is not bool, (trail, value, taken)
    truth = plant_truth(motor)
    for part in (truth.machine, truth.mechanics, truth.inverter, truth.sensor):
        assert all(math.isfinite(v) or v == math.inf or (k, v) == ("stop_low_rad", -math.inf)
                   for k, v in zip(part._fields, part)), part


@pytest.mark.parametrize("cases", [SAMPLE_CASES, pytest.param(FULL_CASES, marks=pytest.mark.heavy)])
def test_mutated_motor_files_are_taken_as_declared_or_refused_naming_file_and_key(tmp_path, cases):
    outcomes = {"accepted": 0, "refused": 0}
    for name, text, kind, trail, value, blamed in motor_cases(20261127, cases):
        path = tmp_path / f"{name}.yaml"
        path.write_text(text, encoding="utf-8")
        try:
            motor = load_motor(path, "--motor")
            assert_accepted_as_declared(motor, kind, trail, value)
            outcomes["accepted"] += 1
        except MotorFileError as error:
            message = str(error)
            assert str(path) in message and "--motor" in message, (name, message)
            assert blames(message, blamed), (name, blamed, message)
            outcomes["refused"] += 1
    assert outcomes["accepted"] > cases // 10 and outcomes["refused"] > cases // 2, outcomes


BROKEN = {
    "non_utf8": b"name: \xff\xfe joint\n",
    "empty": b"",
    "list": b"- 1\n- 2\n",
    "syntax": b"nameplate: {n_p: [\n",
    "deep": b"nameplate: " + b"[" * 1200 + b"]" * 1200 + b"\n",
    "huge": b"# " + b"x" * (1 << 20) + b"\n",
    "tab": b"name:\tjoint\n\tnameplate: {}\n",
}


@pytest.mark.parametrize("case", BROKEN)
def test_a_broken_motor_file_is_refused_in_one_line_naming_it(tmp_path, capsys, case):
    path = tmp_path / f"{case}.yaml"
    path.write_bytes(BROKEN[case])
    with pytest.raises(MotorFileError, match=re.escape(str(path))):
        load_motor(path, "--motor")
    assert main(["motor", "show", str(path)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and str(path) in err, err


LAUGHS = "".join(f"    - &{a} [{', '.join([item] * 9)}]\n"
                 for a, item in zip("abcde", ["x", "*a", "*b", "*c", "*d"]))
"""Five anchors, each nine of the one before: 59049 strings where the last is named."""


def test_a_value_made_huge_by_yaml_aliases_is_refused_in_a_short_line(tmp_path, capsys):
    path = tmp_path / "laughs.yaml"
    path.write_text(f"plant:\n  assumptions:\n{LAUGHS}name: joint\nnameplate: {{n_p: *e, R_s_ohm: 0.3, L_d_H: 0.001, "
                    f"L_q_H: 0.001, psi_f_Wb: 0.01, rated_current_A: 5.0}}\ninverter: {{U_dc_V: 24.0}}\n")
    assert main(["motor", "show", str(path)]) == 2
    err = capsys.readouterr().err
    assert "nameplate.n_p" in err and len(err) < 1000 + len(str(path)), len(err)


def test_mutated_motor_files_through_the_command_line(tmp_path):
    """A few cases refused by their nameplate or inverter through `drive motor show` and `drive run --motor`
    as a user runs them: exit 2, one line naming the file and the key, no traceback; an accepted one shows
    its nameplate as taken."""
    refused, accepted = [], []
    for name, text, *_, blamed in motor_cases(20261128, 60):
        path = tmp_path / f"{name}.yaml"
        path.write_text(text, encoding="utf-8")
        try:
            load_motor(path)
            accepted.append(path)
        except MotorFileError:
            refused.append((path, blamed))
    for path, blamed in refused[:2]:
        for argv in (["motor", "show", str(path)],
                     ["run", "wang_100rpm", "--motor", str(path), "--duration", "0.01", "--no-plot"]):
            done = subprocess.run(DRIVE + argv, cwd=tmp_path, capture_output=True, text=True)
            assert done.returncode == 2 and done.stdout == "", (argv, done.stderr)
            assert done.stderr.count("\n") == 1 and str(path) in done.stderr, done.stderr
            assert "Traceback" not in done.stderr and blames(done.stderr, blamed), done.stderr
    path = accepted[0]
    shown = subprocess.run(DRIVE + ["motor", "show", str(path), "--json"], cwd=tmp_path, capture_output=True, text=True)
    assert shown.returncode == 0 and shown.stderr == "", shown.stderr
    assert json.loads(shown.stdout)["nameplate"] == load_motor(path).nameplate._asdict()


DRIVE_FILE = {"format_version": 1, "description": "the Wang drive", "motor": "wang_spmsm",
              "estimator": {"type": "injection_frame", "settings": {"pll_bandwidth_Hz": 18.0}},
              "commissioning": "nameplate", "injection": {"frequency_Hz": 900.0, "amplitude_V": 5.0},
              "sampling_period_s": 1.0e-4, "controller": {"current_limit_A": 5.0, "speed_limit_rad_s": 100.0},
              "block_samples": 1, "answer_periods": 0}
EXPERIMENT = {"drive": "drive.yaml", "duration_s": 0.02, "speed": {"unit": "rpm", "points": [[0.0, 0.0], [0.01, 60.0]]}}
DRIVE_RELATED = {"sampling_period_s": ("injection.frequency_Hz",), "frequency_Hz": ("sampling_period_s",)}
"""A drive key whose change another key's rule may refuse (the carrier below the Nyquist frequency)."""


def drive_cases(seed, count):
    """(name, drive configuration document, kind, trail, value, blamed) from mutations of DRIVE_FILE."""
    rng = random.Random(seed)
    for i in range(count):
        document = json.loads(json.dumps(DRIVE_FILE))
        kind, trail, value, blamed = mutate(rng, document)
        yield f"{i:03d}_{kind}", document, kind, trail, value, blamed + DRIVE_RELATED.get(trail[-1], ())


def as_written(scenario, document):
    """What the scenario took of a drive configuration's keys, in the document's terms."""
    estimator = document.get("estimator")
    settings = estimator.get("settings") or {} if isinstance(estimator, dict) else {}
    return {"estimator": scenario.estimator if isinstance(estimator, str) else
            {"type": scenario.estimator, "settings": scenario.estimator_settings},
            "injection": scenario.injection, "sampling_period_s": scenario.T_s, "controller": scenario.controller,
            "block_samples": scenario.block_samples, "answer_periods": scenario.answer_periods}, \
        {"estimator": estimator if isinstance(estimator, str) else {"type": estimator["type"], "settings": settings},
         "injection": document.get("injection") or {}, "sampling_period_s": document["sampling_period_s"],
         "controller": document.get("controller") or {}, "block_samples": document.get("block_samples", 1),
         "answer_periods": document.get("answer_periods", 0)}


def same(a, b):
    """Equal, NaN equal to NaN."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same(a[key], b[key]) for key in a)
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


@pytest.mark.parametrize("cases", [SAMPLE_CASES, pytest.param(FULL_CASES, marks=pytest.mark.heavy)])
def test_mutated_drive_configurations_are_taken_as_written_or_refused_naming_file_and_key(tmp_path, cases):
    outcomes = {"accepted": 0, "refused": 0}
    for name, document, *_, blamed in drive_cases(20261127, cases):
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(document, allow_unicode=True), encoding="utf-8")
        try:
            drive = load_drive_configuration(str(path), "parameter drive_configuration")
        except ScenarioError as error:
            message = str(error)
            assert message.startswith("parameter drive_configuration: ") and str(path) in message, (name, message)
            assert blames(message, blamed), (name, blamed, message)
            outcomes["refused"] += 1
            continue
        taken, written = as_written(drive, document)
        assert same(taken, written), (name, taken, written)
        assert drive.open_ended and drive.motor.name == "wang_spmsm"
        outcomes["accepted"] += 1
    assert outcomes["accepted"] > cases // 10 and outcomes["refused"] > cases // 3, outcomes


def test_a_bad_value_in_a_scenarios_drive_file_is_blamed_on_the_drive_file(tmp_path):
    """The scenario naming the mutated drive file, read and its drive built (controller and estimator
    settings): a refusal names the drive file and the key."""
    blamed_elsewhere = []
    for name, document, *_, blamed in drive_cases(20261129, 120):
        case = tmp_path / name
        case.mkdir()
        (case / "drive.yaml").write_text(yaml.safe_dump(document, allow_unicode=True), encoding="utf-8")
        (case / "experiment.yaml").write_text(yaml.safe_dump(EXPERIMENT), encoding="utf-8")
        try:
            build_drive(load_scenario(str(case / "experiment.yaml")))
        except DriveError as error:
            message = str(error)
            if not (str(case / "drive.yaml") in message and blames(message, blamed)):
                blamed_elsewhere.append((name, message))
    assert blamed_elsewhere == []


SCENARIO_RELATED = {
    "duration_s": ("speed.points", "load.points", "torque_feedforward.points", "metrics.start_s", "sampling_period_s"),
    "sampling_period_s": ("duration_s",),
    "settle_s": ("metrics.start_s",),
}
"""A scenario key whose change another key's rule may refuse (table times within the run, the metrics'
start before its end, a sample within the run and the sample cap)."""


@pytest.mark.parametrize("cases", [SAMPLE_CASES, pytest.param(FULL_CASES, marks=pytest.mark.heavy)])
def test_mutated_shipped_scenarios_are_taken_as_written_or_refused_naming_file_and_key(tmp_path, cases):
    rng = random.Random(20261127)
    shipped = {path.stem: yaml.safe_load(path.read_text()) for path in sorted(SCENARIO_DIR.glob("*.yaml"))}
    outcomes = {"accepted": 0, "refused": 0}
    for i in range(cases):
        name = rng.choice(sorted(shipped))
        document = json.loads(json.dumps(shipped[name]))
        kind, trail, _, blamed = mutate(rng, document)
        path = tmp_path / f"{i:04d}_{name}_{kind}.yaml"
        path.write_text(yaml.safe_dump(document, allow_unicode=True), encoding="utf-8")
        try:
            scenario = load_scenario(str(path))
        except ScenarioError as error:
            message = str(error)
            assert str(path) in message, (path.name, message)
            assert blames(message, blamed + SCENARIO_RELATED.get(trail[-1], ())), (path.name, trail, message)
            outcomes["refused"] += 1
            continue
        taken = {"duration_s": scenario.duration_s, "sampling_period_s": scenario.T_s, "seed": scenario.seed,
                 "block_samples": scenario.block_samples, "description": scenario.description}
        assert same(taken, {key: document.get(key, taken[key]) for key in taken}), (path.name, trail)
        assert scenario.n_samples >= 1 and scenario.speed.times_s == tuple(t for t, _ in document["speed"]["points"])
        outcomes["accepted"] += 1
    assert outcomes["accepted"] > cases // 10 and outcomes["refused"] > cases // 3, outcomes


def test_mutated_drive_configurations_through_drive_run(tmp_path, capsys):
    """A scenario naming a mutated drive file, run by `drive run`: metrics in strict JSON, or exit 2 with one
    line naming the key (its drive built too: controller and estimator settings), never a traceback. (The
    injection's values are checked by the estimator, named as its settings: `injection.frequency_Hz` as
    "estimator 'injection_frame': frequency_Hz".)"""
    outcomes = {0: 0, 2: 0}
    for name, document, _, trail, _, blamed in drive_cases(20261130, 24):
        case = tmp_path / name
        case.mkdir()
        (case / "drive.yaml").write_text(yaml.safe_dump(document, allow_unicode=True), encoding="utf-8")
        (case / "experiment.yaml").write_text(yaml.safe_dump(EXPERIMENT), encoding="utf-8")
        code = main(["run", str(case / "experiment.yaml"), "--duration", "0.005", "--no-plot", "--json"])
        out, err = capsys.readouterr()
        assert code in outcomes, (name, trail, code, err)
        outcomes[code] += 1
        if code == 2:
            assert out == "" and err.count("\n") == 1 and blames(err, blamed + (str(trail[-1]),)), (name, trail, err)
        else:
            assert json.loads(out, parse_constant=lambda constant: pytest.fail(constant))["samples"] == 50, name
    assert outcomes[0] > 3 and outcomes[2] > 6, outcomes
