"""The loaded test (optional, docs/commissioning.md "The loaded test"): ours' own angle under load, which
the standstill tables do not give. The shaft must be held (a brake). After its standstill commissioning,
the drive runs itself (ours, sensorless, its carrier and amplitude as it will run them; its speed loop
soft) and steps its torque feed-forward through loads of both signs; the shaft does not turn, so any move
of ours' estimate θ̂ from where it sat at zero current is ours' error under that load. Plain numpy, once
per test.

Where ours' equilibrium moved by Δθ̂ at q current i_q, its error signal there reads F(i_q)·Δθ̂ more than
the commissioned saliency shift (F: the convergence slope of the standstill table), so the correction
added to ours' shift table is c(i_q) = F(i_q)·Δθ̂(i_q), fitted as an odd polynomial a₁·i_q + a₃·i_q³ (the
rotor is symmetric about its d axis), held at its value beyond the largest current tested.

A load that takes ours' angle (it stops tracking, or θ̂ at zero current does not come back) is the
sensorless limit found, not a refusal: the test runs again up to a lower current (retry_current_A, at most
TRIES runs), and the current the last run completes at is the drive's sensorless limit from then on
(Commissioning.loaded_test_current_A). The drive runs its own current path (MTPA where it gains), so the
holds measure ours where the current will be.
"""
import numpy as np

from drive_common.contract.errors import DriveError
from drive_common.contract.estimator_states import TRACKING
from drive_common.contract.log import COLUMN

LEVELS = (0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0, 0.0, -1.0 / 3.0, -2.0 / 3.0, -1.0, 0.0)
"""The held currents per the test's largest current, in order (three at zero: the reference; the negative
loads mirror the positive ones in the same order)."""
START_S = 0.3
"""Ours starts (alignment, polarity test) on the held shaft before the first hold."""
HOLD_S, RAMP_S, MEASURE_S = 0.12, 0.02, 0.08
"""Each level lasts HOLD_S, reached by a ramp of RAMP_S; θ̂ and i_q are averaged over its last MEASURE_S."""
DURATION_S = START_S + len(LEVELS) * HOLD_S
ZERO_SPREAD_RAD = 0.02
"""θ̂ at zero current may differ by this much between the zero holds: beyond, the shaft turned or ours
drifts, and nothing is measured."""
SPEED_BANDWIDTH_RAD_S = 2.0
"""The test's speed loop: soft, so that the torque feed-forward alone sets the current. A held shaft gives
a stiff speed loop nothing to do but integrate ours' θ̂ moving into a current (a spring on θ̂: 0.17 A and
0.015 rad held at zero load after each loaded hold on a 12 pole-pair joint at 126 rad/s, 0.002 rad at 2)."""
SIGNIFICANCE = 3.0
"""The correction is kept where its odd part (the half-difference of the holds at ±i_q, free of any error
in the zero-current reference, which enters every hold alike) reaches this many times the zero holds'
spread (the test's own noise: the range of three means is about 1.7 σ of one); below, ours' error under
load is lost in that noise and the table is zero (gimbal_20w: an odd part of 0.019 rad near its current
limit against a spread of 0.007; its correction did not help a running drive)."""


TRIES = 3
"""A test whose loads took ours' angle away is run again at a lower largest current (retry_current_A), at
most this many runs in all: the current the last one completes at is the drive's sensorless limit."""


class LoadedTestError(DriveError):
    """The loaded test did not hold its conditions: nothing is measured. ``retry_current_A``: the largest
    current [A] a test run again may reach where the loads were the cause (None: not the load)."""

    def __init__(self, message, retry_current_A=None):
        super().__init__(message)
        self.retry_current_A = retry_current_A


def retry_current_A(level_index, top_current_A):
    """The largest current [A] for a test run again after ours lost its angle first in the hold of LEVELS
    index ``level_index`` of a test up to ``top_current_A``: the largest load held before it (the load before
    a zero hold is taken as the cause), at most two thirds of the test's and at least two thirds of its
    smallest load; None where it was lost before any load (the start, not the load)."""
    if level_index <= 0:
        return None
    before = LEVELS[:level_index - 1] if LEVELS[level_index] == 0.0 else LEVELS[:level_index]
    held = max((abs(level) for level in before), default=0.0)
    return top_current_A * min(2.0 / 3.0, max(held, 2.0 / 3.0 * LEVELS[1]))


def test_current_A(commissioning, current_limit_A):
    """The test's first largest current [A]: the drive's sensorless current limit (where the commissioned
    tables keep a saliency tracker's loop gain), at most ``current_limit_A``."""
    return min(commissioning.tracking_current_limit_A(), current_limit_A)


def torque_profile(top_current_A, k_t_Nm_per_A):
    """The torque feed-forward [[t_s, N·m], ...] (linear) reaching each LEVELS current through a torque
    constant ``k_t_Nm_per_A`` (the controller's: 1.5·n_p·ψ_f)."""
    points = [[0.0, 0.0]]
    for j, level in enumerate(LEVELS):
        start = START_S + j * HOLD_S
        torque = level * top_current_A * k_t_Nm_per_A
        points += [[start + RAMP_S, torque], [start + HOLD_S, torque]]
    return points


def hold_windows(t):
    """Per level: the samples (a mask over the times ``t`` [s]) of the last MEASURE_S of its hold."""
    ends = [START_S + (j + 1) * HOLD_S for j in range(len(LEVELS))]
    return [(t >= end - MEASURE_S) & (t < end) for end in ends]


def _hold_means(t, angle, i_q):
    """Per level: (mean of the unwrapped θ̂ [rad], mean i_q [A]) over its window (hold_windows)."""
    return [(float(np.mean(angle[w])), float(np.mean(i_q[w]))) for w in hold_windows(t)]


def loaded_shift(log, commissioning, top_current_A):
    """Ours' correction from the ``log`` (drive_common.contract.log columns) of a test up to ``top_current_A``
    [A] on top of the standstill record ``commissioning``: {"estimator_shift_rad": the table over
    commissioning.saliency_shift_i_q_A (zero where not ``significant``, SIGNIFICANCE), "significant", "holds":
    [{i_q_A, moved_rad, correction_rad}], "zero_spread_rad", "top_current_A"}. LoadedTestError where ours did
    not track throughout (with retry_current_A where a load took its angle) or θ̂ at zero current moved
    between the zero holds (the loads moved it: retry at two thirds of the largest)."""
    t = log[:, COLUMN["t"]]
    tracking = log[t >= START_S, COLUMN["state"]] == TRACKING
    if not tracking.all():
        lost = 100.0 * (1.0 - tracking.mean())
        first = int(np.argmax((t >= START_S) & (log[:, COLUMN["state"]] != TRACKING)))
        level = min(int((t[first] - START_S) // HOLD_S), len(LEVELS) - 1)
        retry = retry_current_A(level, top_current_A)
        i_q = float(log[first, COLUMN["i_q"]])
        where = (f"first at {t[first]:.3f} s at i_q {i_q:+.3g} A in the hold at {LEVELS[level] * top_current_A:+.3g} A"
                 + (": the load took its angle" if retry is not None else
                    ", before any load: ours did not start on the held shaft, not the load"))
        raise LoadedTestError(f"the loaded test: ours stopped tracking for {lost:.0f} % of the test ({where}): its "
                              f"loaded error not measured", retry)
    angle = np.unwrap(log[:, COLUMN["theta_e_hat"]])
    means = _hold_means(t, angle, log[:, COLUMN["i_q"]])
    zero = [m for (m, _), level in zip(means, LEVELS) if level == 0.0]
    spread = float(max(zero) - min(zero))
    if spread > ZERO_SPREAD_RAD:
        raise LoadedTestError(f"the loaded test: θ̂ at zero current moved by {spread:.3g} rad between holds up to "
                              f"{top_current_A:.3g} A, more than {ZERO_SPREAD_RAD:g} rad (the loads moved ours' angle, "
                              f"or the shaft turned): its loaded error not measured",
                              2.0 / 3.0 * top_current_A)
    reference = float(np.mean(zero))
    currents = commissioning.saliency_shift_i_q_A
    held = [(i_q, m - reference) for (m, i_q), level in zip(means, LEVELS) if level != 0.0]
    i_held = np.array([i for i, _ in held])
    slope = np.interp(i_held, currents, commissioning.convergence_slope)
    correction = slope * np.array([moved for _, moved in held])
    basis = np.column_stack([i_held, i_held ** 3])
    (a1, a3), *_ = np.linalg.lstsq(basis, correction, rcond=None)
    top = float(np.max(np.abs(i_held)))
    clipped = np.clip(currents, -top, top)
    half = len(correction) // 2
    odd = 0.5 * (correction[:half] - correction[half:])
    significant = bool(np.max(np.abs(odd)) >= SIGNIFICANCE * spread)
    table = a1 * clipped + a3 * clipped ** 3 if significant else np.zeros_like(currents)
    return {"estimator_shift_rad": table, "significant": significant, "zero_spread_rad": spread, "top_current_A": top,
            "holds": [{"i_q_A": float(i), "moved_rad": float(moved), "correction_rad": float(c)}
                      for (i, moved), c in zip(held, correction)]}
