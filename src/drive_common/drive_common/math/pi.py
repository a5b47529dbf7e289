"""The discrete PI regulator with output limit shared by the controller's loops."""
from numba import njit


@njit(cache=True, _nrt=False)
def pi_limited(x, index, kp, ki, T_s, error, limit, feedforward):
    """PI plus ``feedforward`` with output limit ±limit and back-calculation anti-windup; integral state
    in x[index].

    The integral is updated so that it stays consistent with the realised (limited) output, as in
    motulator's PI with the 'realised reference'.
    """
    u = kp * error + x[index] + feedforward
    u_lim = min(max(u, -limit), limit)
    x[index] += T_s * ki * error + (u_lim - u)
    return u_lim
