"""Numba kernels shared by the drive's cores: reference frames, digital filters, the PI regulator, table
lookup, the command delay, dead time, current sensing, the winding's temperature and the safe states."""
