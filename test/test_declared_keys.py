"""Every key a motor, drive or commissioning file sets is declared once (unit, bound, default) and read
through that declaration; typos are refused naming the nearest key; files carry a format version."""
import dataclasses
import math
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import yaml

from drive_common.config.scenario import ScenarioError, load_scenario
from drive_common.contract.settings import FormatMigrated
from drive_common.motor.commissioning import VALUE_KEYS, CommissioningError, load_commissioning, resolve_commissioning
from drive_common.motor.motor_file import INVERTER_KEYS, MotorFileError, load_motor
from drive_common.motor.nameplate import NAMEPLATE_KEYS
from drive_tools.bags import writer
from drive_tools.bags.common import BagError
from drive_tools.bags.reader import bag_topics
from drive_tools.bags.writer import write_run_bag
from drive_tools.runner.runner import run_scenario
from foc_controller.params import SETTINGS, check_settings

DRIVE = [sys.executable, "-m", "drive_tools.cli.cli"]
SHIPPED_MOTOR = Path(load_motor("wang_spmsm").source)


def outside(key):
    """Values just beyond each end of a key's interval (none beyond an open end)."""
    values = []
    for end, inclusive, step in ((key.low, key.low_inclusive, -1.0), (key.high, key.high_inclusive, 1.0)):
        if end is not None:
            beyond = end + step * max(abs(end) * 1e-6, 1e-12)
            values.append(beyond if inclusive else end)
    return values + [math.nan, "1.0", True]


@pytest.mark.parametrize("section, keys", [("nameplate", NAMEPLATE_KEYS), ("inverter", INVERTER_KEYS)])
def test_a_motor_file_value_outside_its_declaration_is_refused_naming_file_key_and_bound(tmp_path, section, keys):
    """For every declared key of the shipped motor's file and each value beyond its bound (or not a
    number): one line naming the file, the key and the bound. The shipped value itself loads."""
    document = yaml.safe_load(SHIPPED_MOTOR.read_text())
    for key in keys:
        if key.choices:
            continue
        for value in outside(key):
            bad = {**document, section: {**document[section], key.name: value}}
            path = tmp_path / f"{key.name}.yaml"
            path.write_text(yaml.safe_dump(bad))
            with pytest.raises(MotorFileError) as raised:
                load_motor(path, "--motor")
            message = str(raised.value)
            assert "\n" not in message and str(path) in message and f"{section}.{key.name}" in message, message
            if isinstance(value, float) and math.isfinite(value):
                assert f"[{key.unit}]" in message or key.bounds() in message, message


def test_every_declared_commissioning_and_controller_key_refuses_what_lies_beyond_it(tmp_path):
    """The same property for a commissioning file's values (one line naming the file and the key) and the
    controller's settings."""
    shipped = Path("commissioning/wang_spmsm.yaml")
    document = yaml.safe_load(shipped.read_text())
    for key in VALUE_KEYS:
        for value in outside(key):
            path = tmp_path / "bad.yaml"
            path.write_text(yaml.safe_dump({**document, "values": {**document["values"], key.name: value}}))
            with pytest.raises(CommissioningError, match=rf"^{path}: values\.{key.name}: "):
                load_commissioning(path)
    for key in SETTINGS:
        for value in ([] if key.choices else outside(key)) + ["typo"]:
            with pytest.raises(ValueError, match=rf"^controller: {key.name}: "):
                check_settings({key.name: value}, 1e-4)


@pytest.mark.parametrize("where, typo, meant", [
    ("nameplate", "R_s_Ohm", "R_s_ohm"), ("inverter", "U_dc", "U_dc_V"), ("", "namplate", "nameplate")])
def test_a_typo_in_a_motor_file_is_refused_naming_the_key_meant(tmp_path, where, typo, meant):
    document = yaml.safe_load(SHIPPED_MOTOR.read_text())
    if where:
        document[where][typo] = 1.0
    else:
        document[typo] = {}
    path = tmp_path / "typo.yaml"
    path.write_text(yaml.safe_dump(document))
    with pytest.raises(MotorFileError, match=rf"{path}: {where + '.' if where else ''}{typo}: unknown key "
                                             rf"\(did you mean {meant}\?\)"):
        load_motor(path)


def test_a_typo_in_a_commissioning_file_is_refused(tmp_path):
    text = Path("commissioning/wang_spmsm.yaml").read_text()
    path = tmp_path / "typo.yaml"
    path.write_text(text.replace("  sensor_noise_A:", "  sensor_noise_A: 0.0\n  sensor_nosie_A:"))
    with pytest.raises(CommissioningError, match=r"values.sensor_nosie_A: unknown key \(did you mean sensor_noise_A"):
        load_commissioning(path)
    path.write_text(text.replace("method:", "methd:"))
    with pytest.raises(CommissioningError, match=r"typo.yaml: methd: unknown key \(did you mean method"):
        load_commissioning(path)


def test_the_inverter_rating_bounds_the_current_limit(tmp_path):
    """A current limit beyond the inverter's stated peak current is refused, naming both."""
    document = yaml.safe_load(SHIPPED_MOTOR.read_text())
    limit = load_motor("wang_spmsm").nameplate.current_limit_A
    path = tmp_path / "rated.yaml"
    for rating, refused in ((0.9 * limit, True), (1.1 * limit, False)):
        path.write_text(yaml.safe_dump({**document, "inverter": {**document["inverter"], "current_rating_A": rating}}))
        if refused:
            with pytest.raises(MotorFileError, match=r"nameplate.current_limit_A: .*inverter.current_rating_A"):
                load_motor(path)
        else:
            assert load_motor(path).inverter.current_rating_A == rating


def test_swapped_inductances_contradict_a_salient_nameplate(tmp_path):
    """L_dh and L_qh swapped in the IPM's file (L_q = 2 L_d on its nameplate): refused naming both keys; on
    a motor whose nameplate states no saliency the order is the measurement's to tell."""
    text = Path("commissioning/szabo_ipmsm.yaml").read_text()
    swapped = text.replace("L_dh_H:", "L_xx_H:").replace("L_qh_H:", "L_dh_H:").replace("L_xx_H:", "L_qh_H:")
    path = tmp_path / "swapped.yaml"
    path.write_text(swapped)
    with pytest.raises(CommissioningError, match=r"values.L_dh_H, values.L_qh_H: .*swapped"):
        resolve_commissioning(load_motor("szabo_ipmsm").nameplate, str(path), "--commissioning")
    assert resolve_commissioning(load_motor("szabo_ipmsm").nameplate, "commissioning/szabo_ipmsm.yaml").L_qh_H > 0


@pytest.mark.parametrize("version, refused", [(99, "newer format"), ("1", "whole number"), (-1, "whole number")])
def test_a_format_version_not_read_is_refused_in_one_line(tmp_path, version, refused):
    """Motor, drive configuration and commissioning files alike."""
    motor = tmp_path / "m.yaml"
    motor.write_text(SHIPPED_MOTOR.read_text().replace("format_version: 1", f"format_version: {version!r}"))
    with pytest.raises(MotorFileError, match=rf"{motor}: format_version: .*{refused}"):
        load_motor(motor)
    commissioning = tmp_path / "c.yaml"
    commissioning.write_text(Path("commissioning/wang_spmsm.yaml").read_text().replace(
        "format_version: 1", f"format_version: {version!r}"))
    with pytest.raises(CommissioningError, match=rf"{commissioning}: format_version: .*{refused}"):
        load_commissioning(commissioning)
    drive = tmp_path / "d.yaml"
    drive.write_text(f"format_version: {version!r}\nmotor: wang_spmsm\nestimator: injection_frame\n"
                     f"sampling_period_s: 1.0e-4\n")
    scenario = tmp_path / "s.yaml"
    scenario.write_text("drive: d.yaml\nduration_s: 0.1\nspeed: {unit: rpm, points: [[0.0, 0.0]]}\n")
    with pytest.raises(ScenarioError, match=rf"{drive}: format_version: .*{refused}"):
        load_scenario(str(scenario))


def test_a_file_without_a_format_version_is_read_and_says_so_in_one_line(tmp_path):
    """Format 0 (written before versions): read as format 1; the command says so on one line of stderr and
    runs (exit 0)."""
    motor = tmp_path / "old.yaml"
    motor.write_text(SHIPPED_MOTOR.read_text().replace("format_version: 1\n", ""))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert load_motor(motor).nameplate == load_motor("wang_spmsm").nameplate
    assert [w.category for w in caught] == [FormatMigrated] and str(motor) in str(caught[0].message)
    done = subprocess.run([*DRIVE, "motor", "show", str(motor)], capture_output=True, text=True)
    warned = [line for line in done.stderr.splitlines() if "format" in line]
    assert done.returncode == 0 and len(warned) == 1 and warned[0].startswith("drive: warning: ")
    assert "Traceback" not in done.stderr


def test_a_bad_value_in_a_drive_file_is_blamed_on_the_drive_file(tmp_path):
    (tmp_path / "d.yaml").write_text("format_version: 1\nmotor: wang_spmsm\nestimator: injection_frame\n"
                                     "sampling_period_s: 1.0e-4\ninjection: {amplitude_V: -5.0}\n"
                                     "controller: {current_limit_A: 1.0e+9}\n")
    scenario = tmp_path / "s.yaml"
    scenario.write_text("drive: d.yaml\nduration_s: 0.1\nspeed: {unit: rpm, points: [[0.0, 0.0]]}\n")
    with pytest.raises(ScenarioError) as raised:
        load_scenario(str(scenario))
    assert str(raised.value).startswith(f"{tmp_path / 'd.yaml'}: injection.amplitude_V: ")
    done = subprocess.run([*DRIVE, "run", str(scenario), "--no-plot"], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "d.yaml: injection.amplitude_V" in done.stderr


def test_a_recording_of_a_newer_contract_is_refused_and_an_older_one_read(tmp_path, monkeypatch):
    """A drive_config whose contract_version is beyond this drive's: one line naming it; an older one is
    read, with a warning naming its version."""
    result = run_scenario(dataclasses.replace(load_scenario("wang_100rpm"), duration_s=0.01))
    for version in (9, 1):
        monkeypatch.setattr(writer, "CONTRACT_VERSION", version)
        write_run_bag(result, tmp_path / f"v{version}")
    with pytest.raises(BagError, match=r"v9: .*contract_version 9: .*newer contract"):
        bag_topics(tmp_path / "v9")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, _, configs = bag_topics(tmp_path / "v1")
    assert configs[0]["contract_version"] == 1
    assert [str(w.message).split(": ")[-1] for w in caught if w.category is FormatMigrated] == [
        "contract_version 1, read as version 3 (its motor a name, its missing keys from the command line)"]


def test_a_typo_in_a_scenario_or_its_drive_file_names_the_key_meant(tmp_path):
    drive = tmp_path / "d.yaml"
    drive.write_text("format_version: 1\nmotor: wang_spmsm\nestimator: injection_frame\nsampling_period_s: 1.0e-4\n"
                     "comissioning: nameplate\n")
    scenario = tmp_path / "s.yaml"
    scenario.write_text("drive: d.yaml\nduration_s: 0.1\nspeed: {unit: rpm, points: [[0.0, 0.0]]}\n")
    with pytest.raises(ScenarioError, match=rf"^{drive}: comissioning: unknown key \(did you mean commissioning\?\)"):
        load_scenario(str(scenario))
    drive.write_text(drive.read_text().replace("comissioning", "commissioning"))
    scenario.write_text(scenario.read_text() + "duraton_s: 3\n")
    with pytest.raises(ScenarioError, match=rf"^{scenario}: duraton_s: unknown key \(did you mean duration_s\?\)"):
        load_scenario(str(scenario))


def test_a_scenario_file_may_state_its_drive_parts_format(tmp_path):
    """A scenario holding its drive part inline may carry that part's format_version: the current one is
    read, a newer one refused naming the key."""
    text = Path(load_scenario("wang_100rpm").source).read_text()
    path = tmp_path / "s.yaml"
    path.write_text("format_version: 1\n" + text)
    assert load_scenario(str(path)).motor.name == "wang_spmsm"
    path.write_text("format_version: 2\n" + text)
    with pytest.raises(ScenarioError, match=rf"^{path}: format_version: 2: .*newer format"):
        load_scenario(str(path))
