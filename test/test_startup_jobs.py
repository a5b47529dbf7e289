"""The start-up's jobs, each on its own, fed by hand (docs/startup.md): the alignment, the polarity test,
the lock monitor and the re-acquisition after a lost lock. The whole start-up on a simulated motor is
test_startup.py."""
import math

import numpy as np
import pytest

from drive_common.contract.estimator_states import ALIGNING, HOLD, LOCK_LOST, POLARITY, TRACKING
from drive_common.motor.commissioning import nameplate_commissioning
from drive_common.motor.motor_file import load_motor
from hf_estimator.alignment import alignment_step
from hf_estimator.interface import check_settings
from hf_estimator.lock_monitor import backemf_residual, fit_backemf_angle, lock_step, seed_from_backemf
from hf_estimator.polarity_test import polarity_begin, polarity_step
from hf_estimator.startup import DEFAULTS, fresh_startup, make_startup
from hf_estimator.startup_state import NO_SALIENCY, ROTOR_MOVED, STARTUP

pytestmark = pytest.mark.unit

T_S = 1e-4
STATE = np.dtype([("theta", np.float64), ("omega", np.float64), ("startup", STARTUP)])
"""The least estimator state a start-up job works on."""
MOTOR = load_motor("wang_spmsm", "test")
PLATE = MOTOR.nameplate
COMMISSIONING = nameplate_commissioning(PLATE)
INVERTER = MOTOR.inverter._replace(delay_periods=1)


def startup(**settings):
    """(a fresh state record x, aligning; its StartupParams) for the Wang motor known by its nameplate."""
    p = make_startup(PLATE, COMMISSIONING, T_S, INVERTER, 1.0, check_settings("test", settings, DEFAULTS, T_S))
    x = np.zeros(1, STATE)[0]
    fresh_startup(x["startup"])
    return x, p


def test_the_alignment_waits_for_a_settled_error_then_hands_over():
    """ε within tolerance for settle_samples: aligned on that sample, not one before."""
    x, p = startup()
    results = [alignment_step(x, p, k, k, 1.0, 2.0, 0.0, 1.0) for k in range(400)]
    within = next(k for k in range(400) if (1.0 - p.error_smoothing) ** (k + 1) < p.align_tolerance_rad)
    assert [k for k, r in enumerate(results) if r[0]][0] == within + p.settle_samples - 1
    assert results[0][1:] == (1.0, 2.0, float(ALIGNING))


@pytest.mark.parametrize("observable, speed, refusal", [(0.0, 0.0, NO_SALIENCY), (1.0, 0.0, ROTOR_MOVED),
                                                        (0.0, 2000.0, ROTOR_MOVED)])
def test_an_alignment_that_times_out_is_refused_and_says_why(observable, speed, refusal):
    """Not settled by align_timeout: refused at zero voltage. No saliency seen and the rotor still: no
    saliency; saliency seen but never settling, or a rotor turning: it moved."""
    x, p = startup()
    x["omega"] = speed
    eps = 0.5 if observable else 0.0
    aligned, u_alpha, u_beta, code = alignment_step(x, p, p.align_timeout_samples, p.align_timeout_samples,
                                                    1.0, 1.0, eps, observable)
    assert not aligned and (u_alpha, u_beta, code) == (0.0, 0.0, float(HOLD))
    assert x["startup"]["refused"] == refusal


def test_after_a_lost_lock_a_timed_out_alignment_is_another_loss():
    x, p = startup()
    x["startup"]["restarts"] = 1.0
    *_, code = alignment_step(x, p, 5000, p.align_timeout_samples, 1.0, 1.0, 0.0, 0.0)
    assert code == float(LOCK_LOST) and x["startup"]["restarts"] == 2.0 and x["startup"]["refused"] == 0.0


def pulse_response(x, p, k0, inductance, resistance=0.05, beside_V=0.0, told=True):
    """The polarity test run on a d-axis winding i[k+1] = i[k] + T_s (u − R i) / L(i), the command issued
    at sample k acting in the period before sample k + d + 1, ``beside_V`` added to it from the first pulse
    on (a frozen fundamental) and, when ``told``, in the applied voltage the test is given; θ̂ held at 0 →
    the test's last answer."""
    i, commands, k, done = 0.0, {}, k0, False

    def acting(issued):
        return commands.get(issued, 0.0) + (beside_V if issued >= k0 else 0.0)
    while not done:
        applied = acting(k - p.delay_periods - 1) if told else commands.get(k - p.delay_periods - 1, 0.0)
        x["startup"]["u_net_alpha"], x["startup"]["u_net_beta"] = applied, 0.0
        done, u_alpha, _, code = polarity_step(x, p, k, k - k0, i, 0.0, 0.0, 0.0)
        if code != float(POLARITY):
            return code
        commands[k] = u_alpha
        i += T_S * (acting(k - p.delay_periods) - resistance * i) / inductance(i)
        k += 1
    return code


@pytest.mark.parametrize("south", [False, True])
def test_the_pulses_tell_the_magnets_polarity_from_the_d_axis_saturation(south):
    """A winding whose inductance drops with positive d current (the magnet's side): north kept; the same
    seen from the south (the current's sign turned): θ̂ turned by π."""
    x, p = startup()
    sign = -1.0 if south else 1.0
    code = pulse_response(x, p, 0, lambda i: PLATE.L_d_H * (1.0 - 0.1 * math.tanh(sign * i / 5.0)))
    assert code == float(POLARITY)
    assert x["startup"]["flipped"] == float(south)
    assert x["theta"] == pytest.approx(math.pi if south else 0.0)


def test_a_voltage_beside_the_pulses_leaves_the_polarity_ratio():
    """The controller's fundamental frozen at a voltage the dead-time zone ate while aligning acts in full
    beside the pulses: its current's exponential rise, given to the test as applied voltage, is modelled
    and taken off (S/T within 0.0012 of the test without it: the model's winding is linear); untold, ±0.5 V
    moves S/T by +0.0024 / −0.0040 on this winding (L/R 3.3 ms against 0.5 ms pulses; at 0.65 ms, a robot
    joint's, the share grows)."""
    def saturating(i):
        return PLATE.L_d_H * (1.0 - 0.1 * math.tanh(i / 5.0))
    ratios = {}
    for beside_V, told in ((0.0, True), (0.5, True), (-0.5, True), (0.5, False), (-0.5, False)):
        x, p = startup()
        pulse_response(x, p, 0, saturating, COMMISSIONING.R_s_ohm, beside_V, told)
        ratios[beside_V, told] = x["startup"]["polarity_ratio"]
    clean = ratios[0.0, True]
    for beside_V in (0.5, -0.5):
        assert ratios[beside_V, True] == pytest.approx(clean, abs=1.2e-3)
    assert abs(ratios[0.5, False] - clean) > 0.002 and abs(ratios[-0.5, False] - clean) > 0.002


def test_pulses_on_a_linear_winding_find_no_polarity_and_turn_a_quarter():
    """No asymmetry: θ̂ a quarter turn further, back to aligning (the q axis is the trackers' other
    equilibrium), and after polarity_tries refused."""
    x, p = startup()
    code = pulse_response(x, p, 0, lambda i: PLATE.L_d_H, resistance=COMMISSIONING.R_s_ohm)
    assert code == float(ALIGNING) and x["theta"] == pytest.approx(0.5 * math.pi)


def test_at_speed_the_back_emf_gives_the_polarity_without_pulses():
    """Aligned on a rotor turning backwards with θ̂ on its south: the back-EMF's sign turns θ̂ by π and
    the flush begins at once."""
    x, p = startup()
    omega = -400.0
    x["omega"] = omega
    x["startup"]["residual_q"] = -2.0 * omega * PLATE.psi_f_Wb
    u_alpha, u_beta, code = polarity_begin(x, p, 100, 1.0, 0.0, math.nan)
    assert code == float(POLARITY) and (u_alpha, u_beta) == (1.0, 0.0)
    assert x["startup"]["flipped"] == 1.0 and x["theta"] == pytest.approx(math.pi)


def backemf_samples(x, p, theta_offset, omega, samples):
    """The lock monitor fed a Wang rotor turning at ω [rad/s el.] at zero current (the voltage its
    back-EMF: ω ψ_f (−sin θ, cos θ) at mid-period), θ̂ = θ + ``theta_offset`` → the state codes."""
    codes = []
    for k in range(samples):
        theta = omega * k * T_S
        x["theta"], x["omega"] = theta + theta_offset, omega
        mid = theta - 0.5 * omega * T_S
        e = omega * PLATE.psi_f_Wb
        residual = backemf_residual(x, p, k, 0.0, 0.0, -e * math.sin(mid), e * math.cos(mid), 0.0)
        codes.append(lock_step(x, p, k, residual, 1.0))
    return codes


def test_the_lock_monitor_keeps_a_right_estimate_and_loses_a_slipped_one():
    """θ̂ on the rotor: tracking throughout; θ̂ half a turn off (a π slip): the residual 2ωψ_f loses the
    lock within lock_persist_samples once the residual's filter has risen."""
    x, p = startup()
    assert set(backemf_samples(x, p, 0.0, 300.0, 400)) == {float(TRACKING)}
    x, p = startup()
    codes = backemf_samples(x, p, math.pi, 300.0, 400)
    lost = codes.index(float(LOCK_LOST))
    assert lost < 0.01 / T_S + p.lock_persist_samples


def test_after_a_lost_lock_the_back_emf_gives_angle_speed_and_polarity():
    """During the hold the back-EMF of a rotor turning backwards is fitted; at its end θ̂ and ω̂ start on
    the rotor (the magnet's side included)."""
    x, p = startup()
    omega, theta0 = -300.0, 1.0
    e = abs(omega) * PLATE.psi_f_Wb
    for since in range(p.lost_hold_samples):
        theta = theta0 + omega * since * T_S
        x["startup"]["e_alpha"] = -math.copysign(e, omega) * math.sin(theta)
        x["startup"]["e_beta"] = math.copysign(e, omega) * math.cos(theta)
        fit_backemf_angle(x, p, since)
    x["theta"] = 0.0
    assert seed_from_backemf(x, p, p.lost_hold_samples - 1)
    assert x["omega"] == pytest.approx(omega, rel=1e-6)
    error = math.remainder(x["theta"] - (theta0 + omega * (p.lost_hold_samples - 1) * T_S), 2.0 * math.pi)
    assert abs(error) < 1e-6


def _warm_residual(R_told_ohm):
    """The lock monitor's residual [V] after 0.1 s of a Wang rotor at 300 rpm carrying 4.6 A on q (θ̂ on
    the rotor, the steady voltage of a winding 40 % above the nameplate's R_s), told ``R_told_ohm`` as the
    drive's tracked R_s (0: the commissioned one)."""
    x, p = startup()
    omega, i_q, R_hot, L = 300.0 * math.pi / 30.0 * PLATE.n_p, 4.6, 1.4 * PLATE.R_s_ohm, PLATE.L_q_H
    u_d, u_q = -omega * L * i_q, R_hot * i_q + omega * PLATE.psi_f_Wb
    residual = 0.0
    for k in range(1000):
        theta = omega * k * T_S
        x["theta"], x["omega"] = theta, omega
        mid = theta - 0.5 * omega * T_S
        i_alpha, i_beta = -i_q * math.sin(theta), i_q * math.cos(theta)
        u_alpha, u_beta = u_d * math.cos(mid) - u_q * math.sin(mid), u_d * math.sin(mid) + u_q * math.cos(mid)
        residual = backemf_residual(x, p, k, i_alpha, i_beta, u_alpha, u_beta, R_told_ohm)
    return residual


def test_the_lock_monitor_takes_the_drives_tracked_resistance():
    """A winding 40 % above its commissioned R_s carrying rated current leaves the resistive error in the
    lock monitor's residual (0.4 R_s·4.6 A = 0.50 V, within 5 %); told the drive's tracked R_s it is gone
    (under 0.02 V)."""
    assert _warm_residual(0.0) == pytest.approx(0.4 * PLATE.R_s_ohm * 4.6, rel=0.05)
    assert _warm_residual(1.4 * PLATE.R_s_ohm) < 0.02
