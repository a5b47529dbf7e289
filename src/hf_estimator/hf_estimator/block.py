"""An estimator core over a block of consecutive samples, one compiled call: what the runner and the
estimator node both run (docs/architecture.md "Block transport")."""
import math

import numpy as np
from numba import njit

from drive_common.contract.estimator_records import SAMPLE
from drive_common.math.command_delay import applied_voltage
from drive_common.math.current_sensing import corrected_currents


def sample_inputs():
    """The SAMPLE buffer estimator_block fills (one per caller, reused for every block)."""
    return np.zeros(1, SAMPLE)


@njit
def estimator_block(step, state, p, k0, n, currents, line, encoder, calibration, trip_A, out, inputs):
    """Samples k0 … k0+n−1 of the estimator ``step`` (interface.py) on its ``state`` (Estimator.state: the
    one-element array of its state record) with parameters p.

    currents (n × 3): measured i_a, i_b, i_c [A], corrected here by the commissioned ``calibration``;
    line: the drive's delay line (drive_common.math.command_delay) holding the commands of earlier samples;
    encoder (n × 2): θ_e, ω_e read only by `sensored` (zeros otherwise). A sample whose currents are not
    finite or exceed ``trip_A`` is not fed to the core: its record repeats the last estimate, signal, weight
    and leader with no injection and state 0. ``out``: n ESTIMATE records; ``inputs``: a one-element SAMPLE
    array the caller keeps (sample_inputs), filled here sample by sample (no allocation per block).
    Returns the number of such bad samples. Not cached: specialised on each estimator's step function (as
    drive_tools.runner.loop's kernels)."""
    x = state[0]
    sample = inputs[0]
    bad = 0
    for i in range(n):
        k = k0 + i
        i_a, i_b, i_c = currents[i, 0], currents[i, 1], currents[i, 2]
        estimate = out[i]
        if not (math.isfinite(i_a) and math.isfinite(i_b) and math.isfinite(i_c)) or max(
                abs(i_a), abs(i_b), abs(i_c)) > trip_A:
            bad += 1
            estimate.theta_e_hat, estimate.omega_e_hat = x.theta, x.omega
            estimate.u_inj_alpha = estimate.u_inj_beta = estimate.eps = estimate.state = 0.0
            estimate.injection_amplitude = 0.0
            last = out[i - 1] if i > 0 else out[i]
            estimate.signal = last.signal if i > 0 else 0.0
            estimate.observer_weight = last.observer_weight if i > 0 else 0.0
            estimate.leader = last.leader if i > 0 else 0.0
            continue
        sample.i_a, sample.i_b, sample.i_c = corrected_currents(i_a, i_b, i_c, calibration)
        sample.u_applied_alpha, sample.u_applied_beta = applied_voltage(line, k - 1)
        sample.theta_e_encoder, sample.omega_e_encoder = encoder[i, 0], encoder[i, 1]
        step(x, p, k, sample, estimate)
    return bad
