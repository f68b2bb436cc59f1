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


@njit(cache=True, inline="always")
def cubic_weights_grad(fx, w, g):
    """Like cubic_weights, and fill g[4] with dN/dfx (per cell: divide by dx for a gradient in 1/m)."""
    base = cubic_weights(fx, w)
    for i in range(4):
        d = fx - (base + i)
        a = abs(d)
        s = 1.0 if d >= 0.0 else -1.0
        if a < 1.0:
            g[i] = s * (1.5 * a * a - 2.0 * a)
        elif a < 2.0:
            g[i] = -s * 0.5 * (2.0 - a) ** 2
        else:
            g[i] = 0.0
    return base
