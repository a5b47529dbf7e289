"""Szabó §2.4's PLL model: its identities, Table 2 evaluated, and the PI tuner meeting its margin."""
import math

import pytest

from hf_estimator.pll_model import highest_crossover, margins, open_loop, pll_process, tune_pi

TABLE1 = dict(R_ohm=6.2, L_d_H=20.025e-3, L_q_H=40.17e-3, f_h_Hz=1500.0, u_h_V=40.0, u_star=1.0)
T_F = 0.53e-3


def test_process_identities():
    p = pll_process(**TABLE1)
    omega_h = 2 * math.pi * 1500.0
    admittance_gap = abs(1 / complex(6.2, omega_h * 20.025e-3) - 1 / complex(6.2, omega_h * 40.17e-3))
    assert p.c_S == pytest.approx(admittance_gap, rel=1e-12)
    assert p.G_p(0.0) == pytest.approx(p.c_S, rel=1e-12)
    assert abs(p.p1) < 1e-3 * p.c_S
    assert (p.lambda_d, p.lambda_q) == pytest.approx((-6.2 / 20.025e-3, -6.2 / 40.17e-3))
    assert p.K == pytest.approx(-0.5 * 40.0, rel=1e-3)


def test_table2_gains_evaluated_in_the_model():
    m = margins(pll_process(**TABLE1), 4853.0, 0.136, T_F)
    assert m.crossover_rad_s == pytest.approx(268.3, abs=0.5)
    assert m.phase_margin_deg == pytest.approx(48.4, abs=0.2)
    assert abs(open_loop(pll_process(**TABLE1), 4853.0, 0.136, T_F, m.crossover_rad_s)) == pytest.approx(1.0)


@pytest.mark.parametrize("crossover", [60.0, 120.0, 175.0])
def test_tuner_meets_the_requested_margin(crossover):
    process = pll_process(**TABLE1)
    A_p, T_i = tune_pi(process, T_F, 60.0, crossover)
    m = margins(process, A_p, T_i, T_F)
    assert m.crossover_rad_s == pytest.approx(crossover, rel=1e-6)
    assert m.phase_margin_deg == pytest.approx(60.0, abs=1.0)


def test_highest_crossover_and_unreachable_requests():
    process = pll_process(**TABLE1)
    assert highest_crossover(process, T_F, 60.0) == pytest.approx(177.5, abs=1.0)
    with pytest.raises(ValueError, match="not reachable with a PI"):
        tune_pi(process, T_F, 60.0, 350.0)
    with pytest.raises(ValueError, match="no saliency"):
        pll_process(**{**TABLE1, "L_q_H": TABLE1["L_d_H"]})
