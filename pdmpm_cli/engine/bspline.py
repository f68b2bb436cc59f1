"""Cubic B-spline weights (Stomakhin et al. 2013): 4 nodes per axis, support 2 cells each side."""

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def cubic_weights(fx, w):
    """Fill w[4] with N(fx - (base + i)) for i = 0..3 and return base = floor(fx) - 1 (fx in cell units)."""
    base = int(np.floor(fx)) - 1
    for i in range(4):
        d = abs(fx - (base + i))
        if d < 1.0:
            w[i] = 0.5 * d * d * d - d * d + 2.0 / 3.0
        elif d < 2.0:
            t = 2.0 - d
            w[i] = t * t * t / 6.0
        else:
            w[i] = 0.0
    return base
