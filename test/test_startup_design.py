"""What the drive designs and predicts before a start from what commissioning measured (docs/startup.md
"Pulses from the commissioning", docs/hf-demodulation.md §5): the polarity pulses from the saturation
asymmetry, the sensor noise and the inertia, checked as properties over a seeded draw of many-pole,
low-inertia motors; ours' predicted angle error from its loop's noise gain."""
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from drive_common.motor.commissioning import nameplate_commissioning
from drive_common.motor.motor_file import load_motor
from drive_tools.evaluation.startup_bench import drawn_motor
from hf_estimator.interface import check_settings
from hf_estimator.pll_model import injection_frame_noise_gain, predicted_angle_error_rad
from hf_estimator.polarity_test import (
    DECISION_Z,
    PULSE_CURRENT_MAX_PER_RATED,
    polarity_design,
    pulse_currents,
    quiet_over,
)
from hf_estimator.startup import DEFAULTS, fresh_startup, make_startup
from hf_estimator.startup_state import STARTUP

pytestmark = pytest.mark.unit

T_S = 1e-4
TOLERANCE_RAD = DEFAULTS["align_tolerance_rad"]
STATE = np.dtype([("theta", np.float64), ("omega", np.float64), ("startup", STARTUP)])


def drawn(seed, count):
    """(nameplate, inverter, commissioning) of ``count`` drawn many-pole motors, their commissioning taken
    from the plant's truth (R_s, L_dh, noise) with a saturation asymmetry drawn in [0.02, 0.25]."""
    rng = np.random.default_rng(seed)
    motors = []
    for index in range(count):
        data = drawn_motor(rng, index)
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "drawn.yaml"
            path.write_text(yaml.safe_dump(data))
            motor = load_motor(str(path), "test")
        plate, inverter, plant = motor.nameplate, motor.inverter, data["plant"]
        record = nameplate_commissioning(plate)._replace(
            R_s_ohm=plant["R_s_ohm"], L_dh_H=plant["L_dh_H"], L_qh_H=plant["L_qh_H"],
            sensor_noise_A=plant["sensor"]["noise_std_A"], saturation_asymmetry=float(rng.uniform(0.02, 0.25)),
            source="test")
        motors.append((plate, inverter, record))
    return motors


def test_designed_pulses_resolve_the_asymmetry_and_hold_the_rotor_on_drawn_motors():
    """Over 40 drawn many-pole, low-inertia motors: designed pulses stay within rated current and 0.8 U_dc/√3,
    decide at half the expected S/T with that margin DECISION_Z noise σ clear, and turn the rotor less than
    the alignment tolerance while θ̂ is two tolerances off d; a motor where no pulses can is refused, the
    reason naming the commissioned asymmetry."""
    designed = refused = 0
    for plate, inverter, record in drawn(11, 40):
        design = polarity_design(plate, record, T_S, inverter, TOLERANCE_RAD, 2)
        if design.problem:
            refused += 1
            assert "saturation asymmetry" in design.problem
            continue
        designed += 1
        assert design.pulse_current_A <= PULSE_CURRENT_MAX_PER_RATED * plate.rated_current_A * (1.0 + 1e-9)
        assert design.pulse_V <= 0.8 * inverter.U_dc_V / math.sqrt(3.0) * (1.0 + 1e-9)
        assert design.margin == pytest.approx(0.5 * design.expected_ratio)
        assert design.margin >= DECISION_Z * design.noise_ratio
        assert design.motion_e_rad <= TOLERANCE_RAD
        assert design.sequences % 2 == 0
    assert designed >= 30


def test_the_expected_ratio_is_the_asymmetrys_on_short_pulses():
    """On a winding without resistance, pulses to I_p give S/T = ¼·asymmetry·I_p/I_rated to first order (the
    chord of an incremental inductance linear in the current; docs/startup.md) within 10 %, for asymmetries
    and pulse currents drawn."""
    rng = np.random.default_rng(3)
    for _ in range(10):
        asymmetry, share = rng.uniform(0.02, 0.3), rng.uniform(0.3, 1.0)
        L, I_rated = 2e-4, 8.0
        n = 2
        pulse_V = share * I_rated * L / (n * T_S)
        currents = pulse_currents((0.0, L, I_rated, T_S), (n, pulse_V, 2, 1), asymmetry)
        peaks = currents[1 + n], -currents[1 + 3 * n]
        ratio = (peaks[0] - peaks[1]) / (peaks[0] + peaks[1])
        assert ratio == pytest.approx(0.25 * asymmetry * share, rel=0.1)


def test_the_expected_ratio_grows_with_the_asymmetry_and_a_weak_one_takes_the_torque_test():
    """Twice the asymmetry, twice the expected S/T within 10 % (the same pulses and count: on a winding whose
    L/R is as short as its pulses, the first sequence, starting from zero, differs from the later ones, so the
    ratio depends on the count too); an asymmetry the noise hides gives the pulses a problem naming it, and
    make_startup then tells the polarity by a torque pulse (torque_polarity.py), a resolved one by the pulses."""
    plate, inverter, record = drawn(5, 1)[0]
    one = polarity_design(plate, record._replace(saturation_asymmetry=0.2), T_S, inverter, TOLERANCE_RAD, 2)
    two = polarity_design(plate, record._replace(saturation_asymmetry=0.4), T_S, inverter, TOLERANCE_RAD, 2)
    assert (one.pulse_current_A, one.n, one.sequences) == (two.pulse_current_A, two.n, two.sequences)
    assert two.expected_ratio / one.expected_ratio == pytest.approx(2.0, rel=0.1)
    weak = record._replace(saturation_asymmetry=1e-4)
    settings = check_settings("test", {}, DEFAULTS, T_S)
    problem = polarity_design(plate, weak, T_S, inverter, TOLERANCE_RAD, 2).problem
    assert problem.startswith("saturation asymmetry 0.01 %")
    assert make_startup(plate, weak, T_S, inverter, 1.0, settings).torque_pulse_A > 0.0
    assert make_startup(plate, record._replace(saturation_asymmetry=0.2), T_S, inverter, 1.0,
                        settings).torque_pulse_A == 0.0


def test_without_an_asymmetry_or_an_inertia_the_settings_fix_the_pulses():
    """A commissioning file written before the asymmetry was kept, or a nameplate without inertia: the
    pulses of DEFAULTS (pulse_sequences, polarity_margin)."""
    plate, inverter, record = drawn(5, 1)[0]
    settings = check_settings("test", {}, DEFAULTS, T_S)
    for plate_, record_ in ((plate, record._replace(saturation_asymmetry=math.nan)),
                            (plate._replace(J_kgm2=math.nan), record)):
        assert polarity_design(plate_, record_, T_S, inverter, TOLERANCE_RAD, 2) is None
        p = make_startup(plate_, record_, T_S, inverter, 1.0, settings)
        assert (p.pulse_sequences, p.polarity_margin) == (DEFAULTS["pulse_sequences"], DEFAULTS["polarity_margin"])


def test_a_retry_scores_its_own_pulses_only():
    """A quarter turn and another try: S and T start again from zero (before, the second try summed the
    first's pulses into its own and halved its ratio)."""
    plate, inverter, record = drawn(5, 1)[0]
    p = make_startup(plate, record, T_S, inverter, 1.0, check_settings("test", {}, DEFAULTS, T_S))
    x = np.zeros(1, STATE)[0]
    fresh_startup(x["startup"])
    x["startup"]["score"], x["startup"]["span"], x["startup"]["quiet"] = -0.7, 54.0, 1.0
    assert quiet_over(x, p, p.quiet_samples + 1)
    assert (x["startup"]["score"], x["startup"]["span"]) == (0.0, 0.0)


@pytest.mark.parametrize("bandwidth_Hz, damping", [(10.0, 0.7), (18.0, 0.9), (40.0, 1.0)])
def test_ours_noise_gain_is_the_loops_noise_bandwidth(bandwidth_Hz, damping):
    """A short fit window and no delay: Σh² is the continuous type-2 loop's 2·B_n·T_s, B_n = ω_n(ζ + 1/4ζ)/2
    (its noise bandwidth, docs/hf-demodulation.md §5), within 10 %."""
    omega_n = 2.0 * math.pi * bandwidth_Hz
    gain = injection_frame_noise_gain((2.0 * damping * omega_n, omega_n ** 2, 0.0), 2, 0, T_S)
    assert gain == pytest.approx(omega_n * (damping + 0.25 / damping) * T_S, rel=0.1)


def test_a_loop_that_does_not_settle_predicts_no_angle():
    """80 Hz type 3 behind a 22-sample fit and a period of delay (a light rotor's scaled loop at a 909 Hz
    carrier): its impulse response does not decay, the prediction is ∞ (the drive refuses)."""
    omega_n, pole = 2.0 * math.pi * 80.0, 0.5 * 2.0 * math.pi * 80.0
    gains = (2.0 * 0.9 * omega_n + pole, omega_n ** 2 + 2.0 * 0.9 * omega_n * pole, pole * omega_n ** 2)
    gain = injection_frame_noise_gain(gains, 22, 1, T_S)
    assert gain == math.inf and predicted_angle_error_rad(0.2, 0.02, gain, 11) == math.inf
