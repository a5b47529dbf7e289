"""What an injecting estimator's step writes into its ESTIMATE record (drive_common.contract.estimator_records)."""
from numba import njit

from drive_common.contract.estimator_states import LEADER_INJECTION


@njit(cache=True)
def write_injecting_estimate(out, theta_e_hat, omega_e_hat, u_inj_V, eps, signal, state, injection_amplitude):
    """Fill ``out`` (ESTIMATE) for an estimator that follows its own injection alone (observer weight 0): θ̂_e
    [rad], ω̂_e [rad/s], its injection (α, β) [V], ε, signal, state code and carrier amplitude [V]."""
    out.theta_e_hat = theta_e_hat
    out.omega_e_hat = omega_e_hat
    out.u_inj_alpha, out.u_inj_beta = u_inj_V
    out.eps = eps
    out.signal = signal
    out.state = state
    out.injection_amplitude = injection_amplitude
    out.observer_weight = 0.0
    out.leader = LEADER_INJECTION
