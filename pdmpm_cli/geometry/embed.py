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


#: refuse a refined surface with more triangles than this
MAX_REFINED_TRIANGLES = 20_000_000


def refine_surface(V: np.ndarray, T: np.ndarray, edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Split every edge longer than `edge` at its midpoint until none is (the shape is unchanged: the new vertices
    lie on the old triangles). A triangle with one, two or three split edges becomes two, three or four, oriented
    as it was (with two, the remaining quad is cut along its shorter diagonal). The original vertices keep their
    indices, so pins by vertex index still name them; new ones are appended.

    An embedded vertex follows the particles near it, and a triangle between vertices many spacings apart stays
    flat while the particles under it bend: a coarse mesh file, refined to the spacing, follows them instead."""
    V = np.ascontiguousarray(V, dtype=np.float64)
    T = np.ascontiguousarray(T, dtype=np.int64)
    while T.shape[0]:
        E = np.sort(T[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        uniq, eid = np.unique(E, axis=0, return_inverse=True)
        split = np.linalg.norm(V[uniq[:, 1]] - V[uniq[:, 0]], axis=1) > edge * (1.0 + 1e-9)
        if not split.any():
            break
        mid = np.full(uniq.shape[0], -1, np.int64)
        mid[split] = V.shape[0] + np.arange(int(split.sum()))
        V = np.concatenate([V, 0.5 * (V[uniq[split, 0]] + V[uniq[split, 1]])])
        M = mid[eid.reshape(-1, 3)]  # midpoint of edges (0-1, 1-2, 2-0) of each triangle, or -1
        T = np.concatenate([_split(T, M, V, k) for k in range(4)])
        if T.shape[0] > MAX_REFINED_TRIANGLES:
            raise ValueError(f"refining the surface to {edge:g} m edges gives over {MAX_REFINED_TRIANGLES:,} triangles")
    return V, T


def _split(T, M, V, count) -> np.ndarray:
    """The triangles with `count` split edges, split: each rotated so that its split edges come first."""
    n = (M >= 0).sum(axis=1)
    sel = np.flatnonzero(n == count)
    if count == 0 or sel.size == 0:
        return T[sel]
    t, m = T[sel], M[sel]
    if count == 3:
        a, b, c, ab, bc, ca = t[:, 0], t[:, 1], t[:, 2], m[:, 0], m[:, 1], m[:, 2]
        return np.concatenate([np.stack(x, 1) for x in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    # rotate so that edge 0 (a-b) is split and, with two splits, edge 2 (c-a) is not
    first = np.argmax(m >= 0, axis=1) if count == 1 else (np.argmin(m >= 0, axis=1) + 1) % 3
    rows = np.arange(sel.size)[:, None]
    order = (first[:, None] + np.arange(3)) % 3
    t, m = t[rows, order], m[rows, order]
    a, b, c, ab, bc = t[:, 0], t[:, 1], t[:, 2], m[:, 0], m[:, 1]
    if count == 1:
        return np.concatenate([np.stack((a, ab, c), 1), np.stack((ab, b, c), 1)])
    # two splits (a-b and b-c): the corner (ab, b, bc), then the quad a, ab, bc, c cut along its shorter diagonal
    short = np.linalg.norm(V[a] - V[bc], axis=1) <= np.linalg.norm(V[ab] - V[c], axis=1)
    quad1 = np.where(short[:, None], np.stack((a, ab, bc), 1), np.stack((a, ab, c), 1))
    quad2 = np.where(short[:, None], np.stack((a, bc, c), 1), np.stack((ab, bc, c), 1))
    return np.concatenate([np.stack((ab, b, bc), 1), quad1, quad2])
