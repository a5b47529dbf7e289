"""PLL models (Szabó §2.4 and the carrier model): identities, Table 2 evaluated, the PI tuner meeting its
margin, and the carrier model against the closed loop measured in the runner."""
import math

import numpy as np
import pytest

from drive_common.math.filters import first_order_lowpass
from drive_tools.evaluation.pll_check import (
    check_scenario,
    closed_loop_figures,
    design_for_motor,
    measure_tracking_response,
    model_figures,
)
from hf_estimator.pll_model import (
    CarrierPath,
    carrier_loop,
    highest_crossover,
    margins,
    pll_process,
    szabo_loop,
    tune_pi,
)

pytestmark = pytest.mark.unit

TABLE1 = dict(R_s_ohm=6.2, L_dh_H=20.025e-3, L_qh_H=40.17e-3, injection_frequency_Hz=1500.0,
              injection_amplitude_V=40.0, u_star=1.0)
T_F = 0.53e-3


def first_order_response(T_f_s):
    """ω → 1/(jωT_f + 1): Szabó's first-order filter in the loop."""
    return lambda omega: 1.0 / (1j * np.asarray(omega) * T_f_s + 1.0)


def szabo_table1_loop(T_f=T_F):
    return szabo_loop(pll_process(**TABLE1), first_order_response(T_f))


def test_process_identities():
    p = pll_process(**TABLE1)
    omega_h = 2 * math.pi * 1500.0
    admittance_gap = abs(1 / complex(6.2, omega_h * 20.025e-3) - 1 / complex(6.2, omega_h * 40.17e-3))
    assert p.c_S == pytest.approx(admittance_gap, rel=1e-12)
    assert p.G_p(0.0) == pytest.approx(p.c_S, rel=1e-12)
    assert abs(p.p1) < 1e-3 * p.c_S
    assert (p.lambda_d, p.lambda_q) == pytest.approx((-6.2 / 20.025e-3, -6.2 / 40.17e-3))
    assert p.K == pytest.approx(-0.5 * 40.0, rel=1e-3)


def test_table2_gains_evaluated_in_szabos_model():
    loop = szabo_table1_loop()
    m = margins(loop, 4853.0, 0.136)
    assert m.crossover_rad_s == pytest.approx(268.3, abs=0.5)
    assert m.phase_margin_deg == pytest.approx(48.4, abs=0.2)
    assert abs(loop.open_loop(4853.0, 0.136, m.crossover_rad_s)) == pytest.approx(1.0)


@pytest.mark.parametrize("crossover", [60.0, 120.0, 175.0])
def test_tuner_meets_the_requested_margin(crossover):
    loop = szabo_table1_loop()
    A_p, T_i = tune_pi(loop, 60.0, crossover)
    m = margins(loop, A_p, T_i)
    assert m.crossover_rad_s == pytest.approx(crossover, rel=1e-6)
    assert m.phase_margin_deg == pytest.approx(60.0, abs=1.0)


def test_highest_crossover_and_unreachable_requests():
    loop = szabo_table1_loop()
    assert highest_crossover(loop, 60.0) == pytest.approx(177.5, abs=1.0)
    with pytest.raises(ValueError, match="not reachable with a PI"):
        tune_pi(loop, 60.0, 350.0)
    with pytest.raises(ValueError, match="no saliency"):
        pll_process(**{**TABLE1, "L_qh_H": TABLE1["L_dh_H"]})


def ideal_carrier_path(T_s):
    """Szabó's continuous loop as a sampled one: no delay, no band-pass, carriers in quadrature."""
    return CarrierPath(6.2, 20.025e-3, 40.17e-3, T_s, 0, 2 * math.pi * 1500.0, 40.0, 1.0, -math.pi / 2, -1.0,
                       np.zeros((0, 6)), first_order_lowpass(T_F, T_s), False)


def test_carrier_model_tends_to_szabos_gain_when_sampling_is_fast():
    """K·c (Eq. 30, 38) is the slope of the demodulated error: the carrier model without delay, at a
    sampling rate far above the carrier, has the same low-frequency loop gain."""
    expected = abs(pll_process(**TABLE1).K) * pll_process(**TABLE1).c_S
    loop = carrier_loop(ideal_carrier_path(1e-6))
    omega = 1.0
    assert abs(loop.rest(np.array([omega]))[0]) * omega == pytest.approx(expected, rel=0.01)


def test_carrier_model_of_the_sampled_synchronous_estimator():
    """At 10 kHz the sampled q̂ current lags by ω_h·1.5·T_s = 81°: Table 2's loop crosses over at 69 rad/s;
    aligned demodulation recovers the gain and 60° at 350 rad/s becomes reachable. From Table 1's values
    (the nameplate alone: the paper's design)."""
    paper = design_for_motor("szabo_ipmsm", "synchronous", {}, commissioning="nameplate")
    m = margins(paper.carrier, 4853.0, 0.136)
    assert m.crossover_rad_s == pytest.approx(68.7, abs=0.5)
    assert m.phase_margin_deg == pytest.approx(78.9, abs=0.3)
    aligned = design_for_motor("szabo_ipmsm", "synchronous", {"demodulation": "aligned"},
                               commissioning="nameplate")
    assert margins(aligned.carrier, 4853.0, 0.136).crossover_rad_s == pytest.approx(263.8, abs=1.0)
    A_p, T_i = tune_pi(aligned.carrier, 60.0, 350.0)
    m = margins(aligned.carrier, A_p, T_i)
    assert (m.crossover_rad_s, m.phase_margin_deg) == pytest.approx((350.0, 60.0), abs=0.5)


def test_improved_is_covered_by_the_carrier_model_only():
    design = design_for_motor("wang_spmsm", "improved", {})
    assert design.szabo is None
    assert margins(design.carrier, *design.current_gains).crossover_rad_s == pytest.approx(87.9, abs=1.0)


def test_closed_loop_bandwidth_matches_the_carrier_model():
    """A short stepped-sine run on the ideal plant (no dead time or sensor errors): θ̂/θ at 8 frequencies up
    to ω_h/10, where the baseband model holds, against the carrier model, for the aligned PLL tuned to
    60° at 350 rad/s (measured: within 2 % and 5°)."""
    design = design_for_motor("szabo_ipmsm", "synchronous", {"demodulation": "aligned"})
    A_p, T_i = tune_pi(design.carrier, 60.0, 350.0)
    settings = {"demodulation": "aligned", "A_p": A_p, "T_i_s": T_i}
    scenario = check_scenario("szabo_ipmsm", "synchronous", settings, ideal_plant=True)
    omega = np.logspace(2.0, 2.95, 8)
    measured = measure_tracking_response(scenario, omega, lead_in_s=0.15)
    model = design.carrier.closed_loop(A_p, T_i, omega)
    assert np.abs(measured.T) == pytest.approx(np.abs(model), rel=0.05)
    assert np.degrees(np.angle(measured.T / model)) == pytest.approx(np.zeros(8), abs=7.0)
    bandwidth = closed_loop_figures(omega, measured.T)["bandwidth_rad_s"]
    expected = model_figures(design.carrier, A_p, T_i, 900.0)["bandwidth_rad_s"]
    assert bandwidth == pytest.approx(expected, rel=0.10)
