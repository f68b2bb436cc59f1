"""Filling shapes with material points of spacing ``h`` (metres); each point stands for h**3.

The box [lo, hi] is covered by a cubic lattice of ``n = ceil((hi - lo) / h)`` cells per axis,
anchored at ``lo`` (cell centres at ``lo + (i + 0.5) h``), with exactly one point per cell:

* ``sampling="lattice"``: the cell centre;
* ``sampling="jittered"``: a uniformly random point of the cell (stratified sampling: the
  peridynamic bond families become statistically isotropic, a regular lattice with horizon
  ~2h is strongly anisotropic), then a minimum separation of ``MIN_SEPARATION * h`` is
  enforced: pairs closer than that are found with ``scipy.spatial.cKDTree`` and one point of
  each pair is re-drawn inside its own cell, repeatedly, until no pair remains;
* ``sampling="relaxed"`` (``fill_shape`` only): the jittered points moved by ``LLOYD_ITERATIONS``
  Lloyd steps towards a centroidal Voronoi tessellation of the shape (blue noise). Jitter alone
  leaves clumps and gaps whose bonds relax non-affinely under load: a beam six particles thick
  came out 30 % soft in tension and bending (docs/method.md, 'Discretisation').

Everything is vectorised; all randomness comes from the ``rng`` argument, so a seeded
generator reproduces the points exactly.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.spatial import cKDTree

from pdmpm_cli.errors import InputError, PdmpmError
from pdmpm_cli.geometry.shapes import _positive

__all__ = ["SAMPLINGS", "MIN_SEPARATION", "MAX_CELLS", "lattice_points", "fill_shape", "lloyd_relax"]

SAMPLINGS = ("lattice", "jittered", "relaxed")
#: minimum distance between jittered points, in units of h
MIN_SEPARATION = 0.5
#: refuse lattices with more cells than this (memory: 24 bytes per cell, plus temporaries)
MAX_CELLS = 100_000_000
#: Lloyd steps of "relaxed" sampling, and the fixed uniform samples per point that estimate each cell's centroid
LLOYD_ITERATIONS = 10
LLOYD_SAMPLES = 32
#: re-draw rounds before giving up (each round keeps ~30 % of the conflicts; ~10-15 needed)
MAX_REDRAW_ROUNDS = 200


def _check_box(lo, hi, h) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    lo = np.asarray(lo, dtype=np.float64).reshape(-1)
    hi = np.asarray(hi, dtype=np.float64).reshape(-1)
    if lo.shape != (3,) or hi.shape != (3,):
        raise InputError(f"bounds must be two points of 3 coordinates, got lo={lo!r}, hi={hi!r}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(hi < lo):
        raise InputError(f"invalid bounds lo={lo.tolist()}, hi={hi.tolist()} (need finite lo <= hi)")
    h = _positive(h, "particle spacing h")
    # tolerance so that an extent that is an exact multiple of h (up to rounding) is not padded
    n = np.maximum(1, np.ceil((hi - lo) / h - 1e-9)).astype(np.int64)
    total = int(np.prod(n.astype(object)))
    if total > MAX_CELLS:
        ext = hi - lo
        h_min = float((np.prod(ext) / MAX_CELLS) ** (1.0 / 3.0)) if np.all(ext > 0) else h
        raise InputError(
            f"particle spacing h={h:g} m over the box {lo.tolist()} .. {hi.tolist()} needs "
            f"{total:,} lattice cells (limit {MAX_CELLS:,}); use a larger spacing, at least "
            f"h={h_min:.3g} m"
        )
    return lo, hi, h, n


def _redraw(pts, idx, cells, lo, h, rng):
    """Re-draw the points ``idx`` uniformly inside their own cells (in place)."""
    pts[idx] = lo + (cells[idx] + rng.random((idx.shape[0], 3))) * h


def lattice_points(lo, hi, h, *, sampling: str, rng: np.random.Generator) -> np.ndarray:
    """One point per cell of the cubic lattice of spacing ``h`` covering [lo, hi] -> (n, 3).

    Cells are ordered x-slowest (C order over (ix, iy, iz)). ``sampling`` is "lattice"
    (cell centres; ``rng`` unused) or "jittered" (random point per cell, min separation
    ``MIN_SEPARATION * h``).
    """
    if sampling not in SAMPLINGS[:2]:
        raise InputError(f"unknown sampling {sampling!r}; use one of: {', '.join(SAMPLINGS[:2])}")
    lo, hi, h, n = _check_box(lo, hi, h)
    ix, iy, iz = np.meshgrid(
        np.arange(n[0], dtype=np.float64),
        np.arange(n[1], dtype=np.float64),
        np.arange(n[2], dtype=np.float64),
        indexing="ij",
    )
    cells = np.stack([ix.ravel(), iy.ravel(), iz.ravel()], axis=1)
    del ix, iy, iz
    if sampling == "lattice":
        return lo + (cells + 0.5) * h

    pts = lo + (cells + rng.random(cells.shape)) * h
    r = MIN_SEPARATION * h
    # Points of non-adjacent cells are >= h apart, so only neighbouring cells can conflict.
    # Round 1 checks all pairs. Afterwards only re-drawn ("moved") points change: they are
    # checked against the unmoved points with the original tree (whose unmoved entries are
    # still exact) and against each other with a small tree. Unmoved points never move.
    tree0 = cKDTree(pts, balanced_tree=False, compact_nodes=False)
    pairs = tree0.query_pairs(r, output_type="ndarray")
    if pairs.shape[0] == 0:
        return pts
    moved = np.zeros(pts.shape[0], dtype=bool)
    redo = np.unique(pairs.max(axis=1))
    for _ in range(MAX_REDRAW_ROUNDS):
        moved[redo] = True
        _redraw(pts, redo, cells, lo, h, rng)
        # re-drawn points vs. points that never moved
        sdm = cKDTree(pts[redo]).sparse_distance_matrix(tree0, r, output_type="ndarray")
        bad_cross = redo[sdm["i"][~moved[sdm["j"]]]]
        # moved points among themselves (includes those moved in earlier rounds)
        m_idx = np.flatnonzero(moved)
        mp = cKDTree(pts[m_idx]).query_pairs(r, output_type="ndarray")
        bad_moved = m_idx[mp.max(axis=1)] if mp.shape[0] else np.empty(0, np.int64)
        redo = np.unique(np.concatenate([bad_cross, bad_moved]))
        if redo.shape[0] == 0:
            return pts
    raise PdmpmError(
        f"jittered sampling could not reach the minimum separation {MIN_SEPARATION} h after "
        f"{MAX_REDRAW_ROUNDS} rounds ({redo.shape[0]} points still too close); this should not "
        'happen, please report it; sampling: "lattice" avoids it'
    )


def fill_shape(
    inside_fn: Callable[[np.ndarray], np.ndarray],
    lo,
    hi,
    h,
    *,
    sampling: str,
    rng: np.random.Generator,
    what: str = "shape",
) -> np.ndarray:
    """Points (n, 3) of ``lattice_points(lo, hi, h, ...)`` for which ``inside_fn`` is true.

    ``lo, hi`` are the shape's axis-aligned bounds, ``inside_fn(points (m, 3)) -> bool (m,)``.
    Raises :class:`InputError` (naming ``what``) if no point falls inside, i.e. the shape is
    too small for the spacing.
    """
    if sampling not in SAMPLINGS:
        raise InputError(f"unknown sampling {sampling!r}; use one of: {', '.join(SAMPLINGS)}")
    pts = lattice_points(lo, hi, h, sampling="lattice" if sampling == "lattice" else "jittered", rng=rng)
    mask = np.asarray(inside_fn(pts), dtype=bool)
    if mask.shape != (pts.shape[0],):
        raise ValueError(f"inside_fn returned shape {mask.shape}, expected ({pts.shape[0]},)")
    if not mask.any():
        ext = np.asarray(hi, dtype=np.float64) - np.asarray(lo, dtype=np.float64)
        smallest = float(ext.min())
        suggestion = smallest / 4.0 if smallest > 0 else float("nan")
        raise InputError(
            f"{what}: no particle falls inside it with particle spacing h={float(h):g} m (its "
            f"bounding box is {' x '.join(f'{e:.3g}' for e in ext)} m); the shape is too small "
            f"(or too thin) for this spacing: use h <= {suggestion:.3g} m (about 4 particles "
            "across its thinnest dimension) or make the shape larger"
        )
    if sampling == "relaxed":
        return lloyd_relax(pts[mask], inside_fn, np.asarray(lo, dtype=np.float64), float(h), rng)
    return pts[mask]


def lloyd_relax(pts, inside_fn, lo, h, rng, iterations: int = LLOYD_ITERATIONS, samples: int = LLOYD_SAMPLES):
    """Jittered points ``pts`` (one per lattice cell of spacing ``h`` anchored at ``lo``) after Lloyd steps.

    The shape is represented by ``samples`` uniform points in each point's own cell that lie inside it
    (drawn once: the region the points stand for, n h^3 in volume, clipped by the shape). Each step moves every
    point to the mean of the samples nearest to it (the centroid of its Voronoi cell within that region), which
    evens out the spacing while keeping the jitter's isotropy. A move that would leave a non-convex shape is not
    made. Points keep their volume h^3."""
    n = len(pts)
    cells = np.floor((pts - lo) / h)
    smp = lo + (np.repeat(cells, samples, axis=0) + rng.random((n * samples, 3))) * h
    smp = smp[np.asarray(inside_fn(smp), dtype=bool)]
    for _ in range(iterations):
        idx = cKDTree(pts).query(smp)[1]
        count = np.bincount(idx, minlength=n)
        moved = np.flatnonzero(count > 0)
        new = np.stack([np.bincount(idx, smp[:, a], minlength=n)[moved] for a in range(3)], axis=1)
        new /= count[moved, None]
        ok = np.asarray(inside_fn(new), dtype=bool)
        pts[moved[ok]] = new[ok]
    return pts
