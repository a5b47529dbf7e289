"""What an estimator core reads and writes per sample, as named records (numpy structured dtypes that
numba kernels read and write by field name): one definition each, for the estimators, the controller,
the runner, the nodes, replay and the benches (docs/architecture.md "Estimator records")."""
import numpy as np

from . import numba_records  # noqa: F401  (record kernels cached safely: numba_records.py)

SAMPLE = np.dtype([("i_a", np.float64), ("i_b", np.float64), ("i_c", np.float64),
                   ("u_applied_alpha", np.float64), ("u_applied_beta", np.float64),
                   ("theta_e_encoder", np.float64), ("omega_e_encoder", np.float64), ("R_s_ohm", np.float64)])
"""An estimator's inputs at sample k: the measured phase currents i_a, i_b, i_c [A] (corrected by the
commissioned calibration), the voltage that acted in the period before sample k (αβ) [V], the
encoder's electrical angle [rad] and speed [rad/s] (read only by ``sensored``, and in replay by an
estimator taking the recording's polarity), and the stator resistance [Ω] the drive tracks as its winding
warms (foc_controller.protection; 0: the commissioned one, hf_estimator.interface.stator_resistance)."""

ESTIMATE = np.dtype([("theta_e_hat", np.float64), ("omega_e_hat", np.float64), ("u_inj_alpha", np.float64),
                     ("u_inj_beta", np.float64), ("eps", np.float64), ("signal", np.float64), ("state", np.float64),
                     ("injection_amplitude", np.float64), ("observer_weight", np.float64),
                     ("leader", np.float64)])
"""An estimator's outputs at sample k: θ̂_e [rad] (unwrapped), ω̂_e [rad/s] (for the speed loop), the HF
voltage u_inj (αβ) [V] to superimpose in the period after sample k, its demodulated error ε, its signal
strength (estimator-specific units), its start-up state code (drive_common.contract.estimator_states), the
carrier amplitude it injects with [V] (0: none), the back-EMF observer's weight in θ̂ (0 … 1) and the
source θ̂ follows; the log's columns of the same names."""
ESTIMATE_FIELDS = ESTIMATE.names


def estimates(n):
    """A block of n ESTIMATE records, zeroed."""
    return np.zeros(n, ESTIMATE)

