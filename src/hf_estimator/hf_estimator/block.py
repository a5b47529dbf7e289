"""An estimator core over a block of consecutive samples, one compiled call: what the runner and the
estimator node both run (docs/architecture.md "Block transport")."""
import math

from numba import njit

from control_math.command_delay import applied_voltage
from control_math.current_sensing import corrected_currents

ESTIMATE_COLUMNS = ("theta_e_hat", "omega_e_hat", "u_inj_alpha", "u_inj_beta", "eps", "signal", "state",
                    "injection_amplitude", "observer_weight", "leader")
"""The columns of ``estimator_block``'s output, the step function's results in order."""
ESTIMATE_WIDTH = len(ESTIMATE_COLUMNS)


@njit
def estimator_block(step, x, z, p, k0, n, currents, line, encoder, calibration, trip_A, out):
    """Samples k0 … k0+n−1 of the estimator ``step`` (interface.py) with state x, z and parameters p.

    currents (n × 3): measured i_a, i_b, i_c [A], corrected here by the commissioned ``calibration``;
    line: the drive's delay line (control_math.command_delay) holding the commands of earlier samples;
    encoder (n × 2): θ_e, ω_e read only by `sensored` (zeros otherwise). A sample whose currents are not
    finite or exceed ``trip_A`` is not fed to the core: its row repeats the last estimate, signal, weight
    and leader with no injection and state 0. Rows of ``out`` (n × ESTIMATE_WIDTH): ESTIMATE_COLUMNS.
    Returns the number of such bad samples. Not cached: specialised on each estimator's step function (as
    drive_runner.loop's kernels)."""
    bad = 0
    for i in range(n):
        k = k0 + i
        i_a, i_b, i_c = currents[i, 0], currents[i, 1], currents[i, 2]
        row = out[i]
        if not (math.isfinite(i_a) and math.isfinite(i_b) and math.isfinite(i_c)) or max(
                abs(i_a), abs(i_b), abs(i_c)) > trip_A:
            bad += 1
            row[0], row[1] = x[0], x[1]
            row[2] = row[3] = row[4] = row[6] = row[7] = 0.0
            for j in (5, 8, 9):
                row[j] = out[i - 1, j] if i > 0 else 0.0
            continue
        c_a, c_b, c_c = corrected_currents(i_a, i_b, i_c, calibration)
        u_a, u_b = applied_voltage(line, k - 1)
        result = step(x, z, p, k, c_a, c_b, c_c, u_a, u_b, encoder[i, 0], encoder[i, 1])
        for j in range(ESTIMATE_WIDTH):
            row[j] = result[j]
    return bad
