"""Lookup of tabulated quantities (e.g. commissioning tables) inside per-sample kernels."""
from numba import njit


@njit(cache=True, _nrt=False)
def table_value(x, grid, table):
    """``table`` at ``x`` by linear interpolation over the uniform ascending ``grid``, held at its ends;
    0 for an empty table."""
    n = grid.shape[0]
    if n == 0:
        return 0.0
    position = (x - grid[0]) / (grid[n - 1] - grid[0]) * (n - 1)
    if position <= 0.0:
        return table[0]
    if position >= n - 1:
        return table[n - 1]
    j = int(position)
    fraction = position - j
    return table[j] + fraction * (table[j + 1] - table[j])
