"""An estimator core over a block of consecutive samples, one compiled call: what the runner and the
estimator node both run (docs/architecture.md "Block transport")."""
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.estimator_records import SAMPLE
from drive_common.math.command_delay import applied_voltage
from drive_common.math.current_sensing import bad_currents, corrected_currents


class EstimatorCore(NamedTuple):
    """What the block kernels step with an estimator's step kernel (interface.py): its parameters, its state
    (Estimator.state: the one-element array of its state record, stepped in place) and the SAMPLE record the
    step reads (a one-element array filled sample by sample; the caller sets its R_s_ohm). The step kernel
    goes beside it, not in it: a tuple holding a function costs numba a millisecond per call to type."""

    params: Any
    state: np.ndarray
    sample: np.ndarray


def sample_inputs():
    """A SAMPLE buffer (EstimatorCore.sample), zeroed."""
    return np.zeros(1, SAMPLE)


@njit(_nrt=False, inline='always')
def estimator_block(step, core, k0, n, inputs, line, sensing, out):
    """Samples k0 … k0+n−1 of the estimator ``step`` on ``core`` (EstimatorCore).

    inputs: n DRIVE_INPUT records (drive_common.contract.drive_records): the measured currents [A], corrected
    here by ``sensing``'s calibration (drive_common.math.current_sensing.CurrentSensing), and the encoder's
    θ_e, ω_e, read only by `sensored`; line: the drive's delay line (drive_common.math.command_delay) holding
    the commands of earlier samples. A sample whose currents are not finite or exceed the trip is not fed to
    the core: its record repeats the last estimate, signal, weight and leader with no injection and state 0.
    ``out``: n ESTIMATE records. Returns the number of such bad samples. Called bound to the step
    (drive_common.runtime.bound_kernels: cached on disk per step) or inlined into a kernel that is."""
    p, x = core.params, core.state[0]
    record = core.sample[0]
    bad = 0
    for i in range(n):
        k = k0 + i
        s = inputs[i]
        estimate = out[i]
        if bad_currents(s.i_a_A, s.i_b_A, s.i_c_A, sensing.trip_A):
            bad += 1
            estimate.theta_e_hat, estimate.omega_e_hat = x.theta, x.omega
            estimate.u_inj_alpha = estimate.u_inj_beta = estimate.eps = estimate.state = 0.0
            estimate.injection_amplitude = 0.0
            last = out[i - 1] if i > 0 else out[i]
            estimate.signal = last.signal if i > 0 else 0.0
            estimate.observer_weight = last.observer_weight if i > 0 else 0.0
            estimate.leader = last.leader if i > 0 else 0.0
            continue
        record.i_a, record.i_b, record.i_c = corrected_currents(s.i_a_A, s.i_b_A, s.i_c_A, sensing.calibration)
        record.u_applied_alpha, record.u_applied_beta = applied_voltage(line, k - 1)
        record.theta_e_encoder, record.omega_e_encoder = s.theta_e_encoder_rad, s.omega_e_encoder_rad_s
        step(x, p, k, record, estimate)
    return bad
