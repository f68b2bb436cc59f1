"""Tying mesh vertices to material points, so that a surface follows the particles' motion and deformation.

:func:`embed_points` gives each vertex its k nearest particles with Wendland C2 weights; the engine
(``engine/embedding.py``) places the vertex at the weighted mean of the particles' affine maps.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["embed_points"]


def embed_points(points: np.ndarray, particles: np.ndarray, k: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Each of `points` (m,3) is tied to its k nearest `particles` (n,3) with smooth positive weights summing to 1.

    Wendland C2 weights (1 - q)^4 (1 + 4 q), q = d / (1.5 d_k), d_k the distance to the k-th
    nearest; returns (idx (m,k) int64, w (m,k) float64); if n < k, k = n. A vertex placed at
    sum_i w_i (x_i + F_i (X - X_i)) then moves exactly with any affine motion.
    """
    X = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    Pp = np.ascontiguousarray(particles, dtype=np.float64).reshape(-1, 3)
    if Pp.shape[0] == 0:
        raise ValueError("embed_points needs at least one particle")
    k = int(min(k, Pp.shape[0]))
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    if X.shape[0] == 0:
        return np.zeros((0, k), np.int64), np.zeros((0, k))
    d, idx = cKDTree(Pp).query(X, k=k)
    d = np.asarray(d, dtype=np.float64).reshape(X.shape[0], k)
    idx = np.asarray(idx, dtype=np.int64).reshape(X.shape[0], k)
    support = 1.5 * d[:, -1:]
    q = np.divide(d, support, out=np.zeros_like(d), where=support > 0.0)
    w = (1.0 - q) ** 4 * (1.0 + 4.0 * q)
    w /= w.sum(axis=1, keepdims=True)
    return idx, w
