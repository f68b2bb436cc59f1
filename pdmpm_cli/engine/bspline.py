"""Cubic B-spline weights (Stomakhin et al. 2013): 4 nodes per axis, support 2 cells each side."""

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def cubic_weight(d):
    """N(d), the cubic B-spline at an offset d from its node (in cells): one node at a time."""
    a = abs(d)
    if a < 1.0:
        return 0.5 * a * a * a - a * a + 2.0 / 3.0
    if a < 2.0:
        t = 2.0 - a
        return t * t * t / 6.0
    return 0.0


@njit(cache=True, inline="always")
def cubic_weights(fx, w):
    """Fill w[4] with N(fx - (base + i)) for i = 0..3 and return base = floor(fx) - 1 (fx in cell units)."""
    base = int(np.floor(fx)) - 1
    for i in range(4):
        w[i] = cubic_weight(fx - (base + i))
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
