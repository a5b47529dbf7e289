"""Honest failure (issue 51 item 5): commissioning refuses a test current the bus cannot drive, naming the current
wanted, the current reached and the bus; a current limit below rated current is refused; every non-zero exit of
`drive run` and `drive commission` says its one reason on stderr and no text contradicts the exit code;
`drive commission --json` always says what was written and what was refused; each refusal names the cause
measured, with its figure; `drive motor show` prints what a run uses and refuses typos anywhere in a motor file."""
import contextlib
import io
import json
import math
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from drive_common.contract.estimator_states import TRACKING
from drive_common.contract.exit_codes import (
    EXIT_NOT_FOLLOWING,
    EXIT_NOT_TRACKING,
    EXIT_RECORDING_FAILED,
    EXIT_REFUSED,
    EXIT_TRIPPED,
)
from drive_common.contract.log import COLUMN, LOG_COLUMNS
from drive_common.motor.motor_file import load_motor, motor_path
from drive_common.motor.nameplate import InverterRating, Nameplate
from drive_tools.cli.cli import main
from hf_estimator.commissioning.procedure import BUS_HEADROOM, CommissioningError, CommissioningProcedure

BUS_12V = """format_version: 1
name: {name}
description: "12 V bus, 3.2 ohm winding, 9 A rated"
nameplate:
  n_p: 7
  R_s_ohm: {R_plate}
  L_d_H: 0.004
  L_q_H: 0.005
  psi_f_Wb: 0.01
  rated_current_A: 9.0
  rated_speed_rpm: 150.0
  J_kgm2: 1.0e-4
inverter:
  U_dc_V: 12.0
plant:
  R_s_ohm: 3.2
  L_dh_drop_at_rated: 0.1
"""

SCALED = """format_version: 1
name: scaled_12v
description: "12 V bus that drives rated current but not the current limit with the HF carrier"
nameplate:
  n_p: 7
  R_s_ohm: 1.0
  L_d_H: 0.0008
  L_q_H: 0.0012
  psi_f_Wb: 0.008
  rated_current_A: 5.0
  rated_speed_rpm: 1000.0
  J_kgm2: 1.0e-4
inverter:
  U_dc_V: 12.0
plant:
  L_dh_drop_at_rated: 0.1
"""

JOINT_21 = """format_version: 1
name: joint21
description: "robot joint, 21 pole pairs, 48 V, J 5e-5 kg·m²"
nameplate:
  n_p: 21
  R_s_ohm: 0.3
  L_d_H: 2.0e-4
  L_q_H: 2.0e-4
  psi_f_Wb: 0.006
  rated_current_A: 8.0
  rated_speed_rpm: 1000.0
  current_limit_A: 12.0
  J_kgm2: 5.0e-5
inverter:
  U_dc_V: 48.0
plant:
  L_dh_H: 1.7e-4
  L_qh_H: 1.98e-4
  L_qh_drop_at_rated: 0.05
  sensor: {noise_std_A: 0.02, adc_bits: 12, adc_range_A: 24.0}
"""

ROUND = """format_version: 1
name: round_rotor
description: "no saliency at all: a round rotor to HF injection"
nameplate:
  n_p: 4
  R_s_ohm: 0.3
  L_d_H: 0.0005
  L_q_H: 0.0005
  psi_f_Wb: 0.01
  rated_current_A: 5.0
  rated_speed_rpm: 1500.0
  J_kgm2: 1.0e-4
inverter:
  U_dc_V: 24.0
"""


def _drive(args, cwd):
    """`drive ARGS` in this process (its kernels compiled once for the module) from the folder ``cwd``:
    (returncode, stdout, stderr) as a subprocess would give them."""
    out, err, here = io.StringIO(), io.StringIO(), os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(args)
            except SystemExit as stop:
                code = stop.code
    finally:
        os.chdir(here)
    return SimpleNamespace(returncode=code, stdout=out.getvalue(), stderr=err.getvalue())


def _reasons(stderr):
    """The reason lines of a command's stderr (its warnings apart)."""
    return [line for line in stderr.splitlines() if line.startswith("drive: ") and
            not line.startswith("drive: warning: ")]


def _file(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.unit
def test_a_test_current_is_refused_before_any_current_where_the_bus_cannot_drive_it():
    """9 A through 3.2 Ω needs 28.8 V against U_dc/√3 = 6.93 V on a 12 V bus: refused when the procedure is made,
    naming the current wanted, the current reachable and the bus. Over a draw of windings, rated currents and
    buses the refusal comes exactly where R_s·I_rated exceeds BUS_HEADROOM·U_dc/√3 (the DC points' largest)."""
    plate = Nameplate("bus12", 7, 3.2, 0.004, 0.005, 0.01, 30.0, 9.0, 150.0, 0.4, 13.5, 1e-4, 0.0)
    with pytest.raises(CommissioningError, match=r"before any current: the 12 V bus cannot drive the DC test current: "
                                                 r"9 A wanted, at most 2\.06 A reachable"):
        CommissioningProcedure(plate, InverterRating(12.0, 1), 1e-4)
    rng = np.random.default_rng(51)
    for _ in range(200):
        R, current, bus = 10 ** rng.uniform(-2, 1), 10 ** rng.uniform(-0.5, 2), 10 ** rng.uniform(1, 2.8)
        drawn = plate._replace(R_s_ohm=R, rated_current_A=current, current_limit_A=1.5 * current)
        drivable = R * current <= BUS_HEADROOM * bus / math.sqrt(3.0)
        try:
            CommissioningProcedure(drawn, InverterRating(bus, 1), 1e-4)
            refused = False
        except CommissioningError as error:
            refused = True
            assert f"{current:.3g} A wanted" in str(error) and f"{bus:g} V bus" in str(error)
        assert refused == (not drivable), (R, current, bus)


def test_commission_refuses_the_bus_in_one_line_and_says_so_in_json(tmp_path):
    """`drive commission --json` on the 12 V motor: exit 2, one reason line naming wanted, reachable and the bus;
    the JSON says nothing was written and what was refused; no file. Where the nameplate understates R_s
    (0.5 Ω told, 3.2 Ω true), the DC point is tried and its shortfall refused with the current reached."""
    told = _file(tmp_path, "bus12.yaml", BUS_12V.format(name="bus12", R_plate=3.2))
    done = _drive(["commission", "wang_100rpm", "--motor", str(told), "--out", "c.yaml", "--json"], tmp_path)
    assert done.returncode == EXIT_REFUSED, done.stderr
    (reason,) = _reasons(done.stderr)
    assert "9 A wanted, at most 2.06 A reachable" in reason and "12 V bus" in reason
    report = json.loads(done.stdout)
    assert report["written"] is None and report["refused"]["test"] == "standstill"
    assert not (tmp_path / "c.yaml").exists()
    hidden = _file(tmp_path, "bus12b.yaml", BUS_12V.format(name="bus12b", R_plate=0.5))
    done = _drive(["commission", "wang_100rpm", "--motor", str(hidden), "--out", "c.yaml"], tmp_path)
    assert done.returncode == EXIT_REFUSED
    (reason,) = _reasons(done.stderr)
    assert "4.5 A wanted, 2.1" in reason and "A reached" in reason and "12 V bus" in reason, reason
    assert "commissioning refused" in done.stdout and "commissioned at standstill" not in done.stdout
    assert not (tmp_path / "c.yaml").exists()


def test_a_bus_that_drives_rated_current_but_not_the_limit_scales_the_tables_and_says_so(tmp_path):
    """Rated 5 A through 1 Ω on 12 V with the HF carrier: the carrier, the polarity current and the tables are
    scaled to what the bus drives, the output and the file say so, and the inductances stay within 2 %."""
    motor = _file(tmp_path, "scaled.yaml", SCALED)
    done = _drive(["commission", "wang_100rpm", "--motor", str(motor), "--out", "c.yaml", "--json"], tmp_path)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["written"].endswith("c.yaml") and report["refused"] is None
    assert any(note.startswith("tables up to") for note in report["scaled"]), report["scaled"]
    for key in ("L_dh_H", "L_qh_H", "R_s_ohm"):
        assert report["identified"][key] == pytest.approx(report["truth"][key], rel=0.02), key
    assert "scaled" in (tmp_path / "c.yaml").read_text()


def test_a_current_limit_below_rated_current_is_refused_naming_file_key_value_and_rating(tmp_path):
    text = Path(motor_path("wang_spmsm")).read_text()
    rated = load_motor("wang_spmsm").nameplate.rated_current_A
    limit = f"nameplate:\n  current_limit_A: {rated / 2:g}\n"
    low = _file(tmp_path, "low.yaml", text.replace("nameplate:\n", limit, 1))
    done = _drive(["motor", "show", str(low)], tmp_path)
    assert done.returncode == EXIT_REFUSED
    (reason,) = _reasons(done.stderr)
    assert str(low) in reason and "nameplate.current_limit_A" in reason and f"{rated / 2:g} A" in reason
    assert f"below the rated current {rated:g} A" in reason


GOOD = """motor: wang_spmsm
estimator: sensored
commissioning: nameplate
duration_s: 0.3
sampling_period_s: 1.0e-4
speed: {unit: rpm, points: [[0.0, 50.0]]}
"""


def _exit_cases(tmp_path):
    """(name, argv, expected exit) of `drive run` and `drive commission` runs ending in each code they give."""
    link = Path(motor_path("wang_spmsm")).read_text().replace(
        "  delay_periods: 1\n", "  delay_periods: 1\n  C_dc_F: 1.0e-3\n  U_overvoltage_V: 27.0\n", 1)
    linked = _file(tmp_path, "wang_link.yaml", link.replace("name: wang_spmsm", "name: wang_link"))
    round_rotor = _file(tmp_path, "round.yaml", ROUND)
    joint = _file(tmp_path, "joint21.yaml", JOINT_21)
    files = {
        "good": GOOD,
        "bad": GOOD.replace("duration_s: 0.3", "duration_s: -1"),
        "dragged": GOOD.replace("duration_s: 0.3", "duration_s: 0.8") + "controller: {current_limit_A: 4.0}\n"
                   "load: {unit: rated, interpolation: linear, points: [[0.0, 0.0], [0.2, 0.0], [0.3, 2.0]]}\n",
        "refused_start": GOOD.replace("motor: wang_spmsm", f"motor: {round_rotor}").replace(
            "estimator: sensored", "estimator: injection_frame"),
        "tripped": GOOD.replace("motor: wang_spmsm", f"motor: {linked}").replace("duration_s: 0.3", "duration_s: 0.25")
                   .replace("points: [[0.0, 50.0]]", "interpolation: step, points: [[0.0, 2000.0], [0.05, 0.0]]")
                   + "initial: {omega_m_rpm: 2000.0}\n",
        "lock_lost": f"motor: {joint}\nestimator: injection_frame\ncommissioning: nameplate\nduration_s: 1.0\n"
                     "sampling_period_s: 1.0e-4\ninjection: {frequency_Hz: 900.0, amplitude_V: 5.0}\n"
                     "speed: {unit: rpm, points: [[0.0, 100.0]]}\n"
                     "load: {unit: rated, points: [[0.0, 0.0], [0.3, 1.0]]}\n",
    }
    paths = {name: _file(tmp_path, f"{name}.yaml", text) for name, text in files.items()}
    (tmp_path / "not_a_dir").write_text("")
    bus = _file(tmp_path, "bus12.yaml", BUS_12V.format(name="bus12", R_plate=3.2))
    return [("run done", ["run", str(paths["good"]), "--no-plot"], 0),
            ("run refused", ["run", str(paths["bad"])], EXIT_REFUSED),
            ("run plot unwritable", ["run", str(paths["good"]), "--out", str(tmp_path / "not_a_dir")],
             EXIT_RECORDING_FAILED),
            ("run start refused", ["run", str(paths["refused_start"]), "--no-plot"], EXIT_NOT_TRACKING),
            ("run lock lost", ["run", str(paths["lock_lost"]), "--no-plot"], EXIT_NOT_TRACKING),
            ("run dragged", ["run", str(paths["dragged"]), "--no-plot"], EXIT_NOT_FOLLOWING),
            ("run tripped", ["run", str(paths["tripped"]), "--no-plot"], EXIT_TRIPPED),
            ("commission refused", ["commission", "wang_100rpm", "--motor", str(bus), "--out", "c.yaml"],
             EXIT_REFUSED)]


def test_every_exit_says_its_one_reason_and_no_text_claims_success(tmp_path):
    """Each case ends in its exit code; a non-zero one prints exactly one reason line on stderr (warnings apart)
    and its text does not end in done (nor, where the shaft was not driven to the end, say it followed its
    command); exit 0 prints no reason."""
    for name, argv, code in _exit_cases(tmp_path):
        done = _drive(argv, tmp_path)
        assert done.returncode == code, (name, done.returncode, done.stderr)
        reasons = _reasons(done.stderr)
        if code == 0:
            assert reasons == [] and "exit 0: done" in done.stdout, (name, done.stderr)
            continue
        assert len(reasons) == 1, (name, done.stderr)
        if code in (EXIT_NOT_TRACKING, EXIT_NOT_FOLLOWING, EXIT_TRIPPED):
            assert "the shaft followed its command" not in done.stdout, name
        assert "exit 0" not in done.stdout and "commissioned at standstill" not in done.stdout, name
        if argv[0] == "run" and code != EXIT_REFUSED:
            assert f"exit {code}: " in done.stdout, (name, done.stdout)
        if name == "run lock lost":
            assert "lost its lock" in reasons[0] and "holds zero torque from" in reasons[0], reasons
    json_run = _drive(["run", str(tmp_path / "refused_start.yaml"), "--no-plot", "--json"], tmp_path)
    outcome = json.loads(json_run.stdout)["outcome"]
    assert outcome["exit_code"] == EXIT_NOT_TRACKING and outcome["reason"] in json_run.stderr
    assert "nameplate L_q/L_d = 1" in outcome["reason"], outcome


def test_a_later_test_refused_still_reports_what_was_written(tmp_path):
    """The rotating test on a shaft a brake drags (viscous, 0.15 N·m·s: at the test's first speed, 15.7 rad/s,
    twice the torque the current limit makes) cannot hold its speeds: `drive commission --rotating --json`
    exits 2, its JSON names the file written with the standstill test and the rotating test refused with its
    measured cause (the q current at its limit: a load or a brake); the file holds the standstill test only."""
    text = (Path(__file__).parent.parent / "docs" / "motors" / "robot_joint_10pp.yaml").read_text()
    heavy = _file(tmp_path, "dragged.yaml", text.replace("plant:\n", "plant:\n  B_Nms: 0.15\n", 1))
    done = _drive(["commission", "wang_100rpm", "--motor", str(heavy), "--out", "c.yaml", "--rotating", "--json"],
                  tmp_path)
    assert done.returncode == EXIT_REFUSED, done.stderr
    report = json.loads(done.stdout)
    assert report["written"].endswith("c.yaml") and report["tests_completed"] == ["standstill"]
    assert report["refused"]["test"] == "rotating" and "ψ_f and J not measured" in report["refused"]["reason"]
    assert "a load or a brake on the shaft" in report["refused"]["reason"], report["refused"]["reason"]
    (reason,) = _reasons(done.stderr)
    assert reason == f"drive: {report['refused']['reason']}"
    assert "tests_completed:\n  - standstill\n" in (tmp_path / "c.yaml").read_text()


def _rotating_log(lost_at_s=None, i_q_ref=1.0, held_share=1.0, T_s=1e-4):
    """A rotating test's log as the drive writes it: ω̂ at the profile's speeds (``held_share`` of them), the
    q current reference ``i_q_ref``, tracking until ``lost_at_s``."""
    from hf_estimator.commissioning.rotating import DURATION_S, speed_profile
    t = np.arange(int(round(DURATION_S / T_s))) * T_s
    log = np.zeros((t.size, len(LOG_COLUMNS)))
    log[:, COLUMN["t"]] = t
    profile = np.array(speed_profile(1000.0))
    log[:, COLUMN["omega_e_hat"]] = 10 * held_share * np.interp(t, profile[:, 0], profile[:, 1]) * math.pi / 30.0
    log[:, COLUMN["state"]] = TRACKING
    log[:, COLUMN["i_q_ref"]] = i_q_ref
    if lost_at_s is not None:
        log[t >= lost_at_s, COLUMN["state"]] = 0
    return t, log


@pytest.mark.unit
@pytest.mark.parametrize("case, words", [
    ({"lost_at_s": 0.5, "i_q_ref": 10.0}, "the q current at its limit (10 of 10 A): a load on the shaft"),
    ({"lost_at_s": 0.5, "saliency": 0.03}, "weak saliency (|Δ|/Σ = 0.03 < 0.05)"),
    ({"lost_at_s": 0.5}, "|Δ|/Σ = 0.095: neither a load nor a weak saliency"),
    ({"held_share": 0.5, "i_q_ref": 10.0}, "the q current at its limit (10 of 10 A): a load or a brake on the shaft"),
    ({"held_share": 0.5}, "the q current 1 A, below its limit 10 A: the speed loop did not settle"),
])
def test_the_rotating_tests_refusal_names_the_cause_measured(case, words):
    """The same loss of track or missed speed, told apart by what the drive measured: the q current at its
    limit (a load), a weak commissioned saliency, or neither; the figure that decided it in the words."""
    from hf_estimator.commissioning.rotating import RotatingTestError, _check_followed
    case = dict(case)
    saliency = case.pop("saliency", 0.095)
    t, log = _rotating_log(**case)
    with pytest.raises(RotatingTestError) as refused:
        _check_followed(t, log, log[:, COLUMN["omega_e_hat"]] / 10, 1000.0 * math.pi / 30.0, 10.0, saliency, False)
    assert words in str(refused.value)
    for other in ("a load on the shaft", "weak saliency", "neither a load"):
        if other not in words:
            assert other not in str(refused.value)


@pytest.mark.unit
def test_the_starts_refusal_names_the_commissioned_saliency():
    """No angle signal while aligning: with a commissioned |Δ|/Σ of 0.095 the refusal says the signal was lost
    in the noise although the saliency is there (not "a round rotor"); with 0.004 it says a round rotor; on the
    nameplate alone it gives the nameplate's L_q/L_d and says to commission."""
    from drive_common.config.scenario import load_scenario
    from drive_common.motor.commissioning import nameplate_commissioning
    from drive_tools.evaluation.run_report import refusal_cause
    from hf_estimator.startup import REFUSALS
    from hf_estimator.startup_state import NO_SALIENCY

    scenario = load_scenario("wang_100rpm")
    plate = scenario.motor.nameplate
    startup = {"refused": REFUSALS[NO_SALIENCY]}

    def cause(L_dh_H, L_qh_H, source="commissioning/x.yaml"):
        record = nameplate_commissioning(plate)._replace(L_dh_H=L_dh_H, L_qh_H=L_qh_H, source=source)
        return refusal_cause(startup, SimpleNamespace(commissioning=record, scenario=scenario, startup={}))
    salient = cause(1.0e-3, 1.0e-3 * 1.095 / 0.905)
    assert "although commissioning measured |Δ|/Σ = 0.095" in salient and "round rotor" not in salient
    assert "a round rotor" in cause(1.0e-3, 1.008e-3) and "|Δ|/Σ = 0.00398" in cause(1.0e-3, 1.008e-3)
    assert f"nameplate L_q/L_d = {plate.L_q_H / plate.L_d_H:.3g}" in cause(1e-3, 1e-3, "nameplate")


def test_motor_show_prints_what_the_run_uses(tmp_path):
    """`drive motor show F --scenario S --json` gives the carrier, amplitude, tracking bandwidth and current limit
    `drive run S --motor F --json` reports it ran with (with another motor, ours' carrier scaled to it, not the
    paper scenario's 909 Hz)."""
    motor = str(Path(__file__).parent.parent / "docs" / "motors" / "gimbal_20w.yaml")
    shown = _drive(["motor", "show", motor, "--scenario", "wang_100rpm", "--commissioning", "nameplate", "--json"],
                   tmp_path)
    assert shown.returncode == 0, shown.stderr
    uses = json.loads(shown.stdout)["run"]
    ran = _drive(["run", "wang_100rpm", "--motor", motor, "--commissioning", "nameplate", "--duration", "0.02",
                  "--no-plot", "--json"], tmp_path)
    loops = json.loads(ran.stdout)["loops"]
    for key in ("injection_frequency_Hz", "injection_amplitude_V", "tracking_bandwidth_Hz", "current_limit_A",
                "sample_period_s"):
        assert uses[key] == pytest.approx(loops[key], rel=1e-12), key
    assert uses["injection_frequency_Hz"] == pytest.approx(1e4 / 9)


@pytest.mark.parametrize("change, said", [
    (("  L_dh_H: 1.08e-3", "  L_dh_HH: 1.08e-3"), "plant.L_dh_HH: unknown key (did you mean L_dh_H?)"),
    (("noise_std_A", "noise_sd_A"), "plant.sensor.noise_sd_A: unknown key (did you mean noise_std_A?)"),
    (("  n_p: 7", "  np: 7"), "nameplate.np: unknown key (did you mean n_p?)"),
    (("inverter:", "invertor:"), "invertor: unknown key (did you mean inverter?)"),
])
def test_motor_show_refuses_a_typo_anywhere_naming_the_nearest_key(tmp_path, change, said):
    text = (Path(__file__).parent.parent / "docs" / "motors" / "gimbal_20w.yaml").read_text()
    assert change[0] in text
    path = _file(tmp_path, "typo.yaml", text.replace(*change, 1))
    done = _drive(["motor", "show", str(path)], tmp_path)
    assert done.returncode == EXIT_REFUSED
    (reason,) = _reasons(done.stderr)
    assert str(path) in reason and said in reason, reason
