"""Voronoi mode geometry: random seeds inside a convex polytope, their Voronoi cells clipped to it.

Each clipped cell becomes one material point (its centroid, with its volume); cells sharing a
face are bonded, so cracks run along cell faces, and the cell polyhedra (triangulated, one
private copy of the vertices per cell) are written moving with their points, so fragments
render as solid pieces.

Only convex shapes are supported. A shape is a convex polytope: an array ``planes`` (k, 4) of
half-spaces ``[nx, ny, nz, d]``, inside where ``n . x + d <= 0`` (scipy ``ConvexHull.equations``
convention, unit normals). Curved primitives are approximated by the convex hull of points on
their surface (:func:`polytope_from_points`).

Cell ``i`` is the polytope intersected with the bisector half-spaces towards the seed's
Delaunay neighbours (the exact Voronoi cell: other seeds never contribute a face). Each cell is
one qhull call, the convex hull of its half-spaces' dual points (see :class:`_Clipper`), which
gives the vertices and, exactly, the half-space (so the neighbour or the boundary) of every
face. Polytope planes are added lazily: those whose facet is near the seed first, then any plane
a finished cell's vertex still violates, until every cell lies inside the polytope; so a finely
faceted sphere costs only the few facets near each cell.

All randomness comes from the ``rng`` argument, so a seeded generator reproduces the cells.
SI units (metres, m^2, m^3). Bad input raises :class:`pdmpm_cli.errors.InputError`.
"""

from __future__ import annotations

import itertools
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree

from pdmpm_cli.errors import InputError
from pdmpm_cli.geometry.shapes import _positive

__all__ = [
    "MAX_SEEDS",
    "VoronoiCells",
    "polytope_from_points",
    "box_planes",
    "polytope_volume",
    "voronoi_cells",
]

#: refuse to build more cells than this (each costs ~0.2 ms and ~2 kB of polyhedron)
MAX_SEEDS = 2_000_000
#: refuse jittered lattices whose bounding box has more cells than this (thin, tilted shapes)
MAX_LATTICE_CELLS = 50 * MAX_SEEDS
#: planes closer than this (normals, and offsets / shape size) are the same plane
PLANE_TOL = 1e-9
#: seeds must be inside every plane by this fraction of the spacing (or mean cell size)
INSIDE_TOL = 1e-9
#: a shared face is a bond when its area exceeds this times (cell size)^2 on both sides
FACE_TOL = 1e-6
#: a cell vertex outside a polytope plane by more than this times the cell size adds that plane
VIOLATION_TOL = 1e-10
#: cell vertices closer than this times the cell size are one vertex (qhull splits a vertex where
#: more than 3 faces meet into several coincident ones)
MERGE_TOL = 1e-12
#: a seed closer to a polytope plane than this fraction of its nearest bisector distance would
#: give qhull a huge dual point; such cells start from their Chebyshev centre instead
INTERIOR_RATIO = 0.02
#: points x planes evaluated per vectorised chunk (memory bound)
_CHUNK = 4_000_000


@dataclass
class VoronoiCells:
    """Clipped Voronoi cells of a convex polytope: material points, bonds and render polyhedra."""

    seeds: np.ndarray  # (n, 3) float64 generator points
    centroids: np.ndarray  # (n, 3) float64 centroid of each clipped cell -> the material points
    volumes: np.ndarray  # (n,) float64 volume of each clipped cell [m^3]
    pairs: np.ndarray  # (m, 2) int64, i < j, cells sharing a face (sorted lexicographically)
    face_area: np.ndarray  # (m,) float64 area of that shared face [m^2]
    poly_vertices: np.ndarray  # (nv, 3) float64 polyhedron vertices, private copies per cell
    poly_triangles: np.ndarray  # (nt, 3) int64 triangles, counter-clockwise seen from outside
    poly_cell: np.ndarray  # (nt,) int64 owning cell of each triangle
    vertex_cell: np.ndarray  # (nv,) int64 owning cell of each vertex


# ----------------------------------------------------------------------------------------
# polytopes
# ----------------------------------------------------------------------------------------
def _as_planes(planes, what: str = "polytope") -> np.ndarray:
    """Validated (k, 4) float64 half-spaces with unit normals (so offsets are distances)."""
    try:
        p = np.array(planes, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{what}: half-spaces must be a (k, 4) array of numbers [nx, ny, nz, d]") from None
    if p.ndim != 2 or p.shape[1] != 4 or p.shape[0] < 4:
        raise InputError(f"{what}: half-spaces must be a (k, 4) array [nx, ny, nz, d] with k >= 4 "
                         f"(a bounded polytope needs at least 4 planes), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise InputError(f"{what}: half-spaces contain NaN or infinite values")
    norm = np.linalg.norm(p[:, :3], axis=1)
    if np.any(norm <= 1e-300):
        raise InputError(f"{what}: a half-space has a zero normal; every plane needs a direction")
    return p / norm[:, None]


def _chebyshev(planes: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Centre and radius of the largest ball inside the half-spaces (unit normals); None if unbounded."""
    k = planes.shape[0]
    A = np.hstack([planes[:, :3], np.ones((k, 1))])
    res = linprog(np.array([0.0, 0.0, 0.0, -1.0]), A_ub=A, b_ub=-planes[:, 3],
                  bounds=[(None, None)] * 3 + [(0.0, None)], method="highs")
    if res.status == 3:
        return None
    if res.status != 0:
        return np.zeros(3), 0.0  # infeasible: empty
    return np.asarray(res.x[:3], dtype=np.float64), float(res.x[3])


@dataclass
class _Polytope:
    """What the seeding and clipping need to know about a convex polytope."""

    planes: np.ndarray  # (k, 4) its non-redundant half-spaces (each one carries a facet)
    lo: np.ndarray  # (3,) exact bounds (from its vertices)
    hi: np.ndarray
    centre: np.ndarray  # (3,) a deep interior point (Chebyshev centre)
    inner: float  # radius of the ball around centre inside the polytope
    outer: float  # radius of the ball around centre containing the polytope
    volume: float
    facet_centre: np.ndarray  # (k, 3) mean of each facet's vertices
    facet_radius: np.ndarray  # (k,) farthest facet vertex from that mean


def _polytope(planes: np.ndarray, what: str) -> _Polytope:
    """Describe a validated polytope; InputError if it is empty, flat or unbounded.

    One LP (Chebyshev centre) and one hull of the dual points ``n / slack`` seen from it: the
    polytope is bounded exactly when the centre is strictly inside the dual hull, whose facets
    are the polytope's vertices and whose vertices are its non-redundant planes.
    """
    cheb = _chebyshev(planes)
    if cheb is None:
        raise InputError(f"{what}: the half-spaces do not enclose a bounded region; the shape needs planes "
                         "closing it on every side")
    centre = cheb[0]
    slack = -(planes[:, :3] @ centre + planes[:, 3])
    if not slack.min() > 0.0:
        raise InputError(f"{what}: the half-spaces have no common interior (the shape is empty or flat); check "
                         "the planes' signs (inside is where n . x + d <= 0) and the shape's size")
    try:
        dual = ConvexHull(planes[:, :3] / slack[:, None])
    except QhullError:
        dual = None
    if dual is None or not np.all(dual.equations[:, 3] < 0.0):
        raise InputError(f"{what}: the half-spaces do not enclose a bounded region; the shape needs planes "
                         "closing it on every side")
    eq = dual.equations
    verts = centre - eq[:, :3] / eq[:, 3:4]
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    inner = float(slack.min())
    if not inner > 1e-9 * float(np.max(hi - lo)):
        raise InputError(f"{what}: the half-spaces enclose no volume (the shape is flat); check the planes' "
                         "signs (inside is where n . x + d <= 0) and the shape's size")
    keep = np.unique(dual.simplices)  # planes that are dual hull vertices carry a facet
    new = np.full(planes.shape[0], -1, dtype=np.int64)
    new[keep] = np.arange(keep.shape[0])
    plane = new[dual.simplices.ravel()]
    vert = np.repeat(verts, 3, axis=0)
    cnt = np.bincount(plane, minlength=keep.shape[0])
    fc = np.stack([np.bincount(plane, vert[:, a], minlength=keep.shape[0]) for a in range(3)], axis=1)
    fc /= cnt[:, None]
    fr = np.zeros(keep.shape[0])
    np.maximum.at(fr, plane, np.linalg.norm(vert - fc[plane], axis=1))
    return _Polytope(planes[keep], lo, hi, centre, inner, float(np.linalg.norm(verts - centre, axis=1).max()),
                     float(ConvexHull(verts).volume), fc, fr)


def polytope_from_points(points: np.ndarray) -> np.ndarray:
    """Half-spaces (k, 4) of the convex hull of ``points`` (unit normals, inside n . x + d <= 0).

    Qhull triangulates flat faces, so equal planes (to 1e-9, offsets relative to the shape's
    size) are merged: each face of the hull appears once.
    """
    try:
        pts = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("convex hull: points must be an (n, 3) array of numbers") from None
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 4:
        raise InputError(f"convex hull: need an (n, 3) array of at least 4 points, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise InputError("convex hull: points contain NaN or infinite coordinates")
    try:
        hull = ConvexHull(pts)
    except QhullError:
        raise InputError("convex hull: the points are flat (all on one plane or line) and enclose no volume; "
                         "a Voronoi body needs a solid shape") from None
    eq = hull.equations / np.linalg.norm(hull.equations[:, :3], axis=1)[:, None]
    key = eq.copy()
    key[:, 3] /= float(np.max(np.ptp(pts, axis=0)))
    close = cKDTree(key).query_pairs(PLANE_TOL, output_type="ndarray")
    keep = np.ones(eq.shape[0], dtype=bool)
    if close.shape[0]:
        _, group = connected_components(coo_matrix((np.ones(close.shape[0]), (close[:, 0], close[:, 1])),
                                                   shape=(eq.shape[0],) * 2), directed=False)
        keep[:] = False
        keep[np.unique(group, return_index=True)[1]] = True  # first plane of each group
    return np.ascontiguousarray(eq[keep])


def box_planes(center, size, R) -> np.ndarray:
    """The 6 half-spaces of a box with full edge lengths ``size``, rotated by ``R`` about ``center``.

    The box's local axes are the columns of ``R`` (``x_world = center + R @ x_local``).
    """
    c = np.asarray(center, dtype=np.float64).reshape(-1)
    s = np.asarray(size, dtype=np.float64).reshape(-1)
    R = np.asarray(R, dtype=np.float64)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise InputError(f"box: center must be 3 finite numbers, got {center!r}")
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0.0):
        raise InputError(f"box: size must be 3 positive edge lengths in metres, got {size!r}")
    if R.shape != (3, 3) or not np.all(np.isfinite(R)) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6):
        raise InputError("box: R must be a 3x3 rotation matrix (orthonormal columns)")
    planes = np.empty((6, 4))
    for a in range(3):
        n = R[:, a] / np.linalg.norm(R[:, a])
        planes[2 * a, :3], planes[2 * a, 3] = n, -(n @ c) - 0.5 * s[a]
        planes[2 * a + 1, :3], planes[2 * a + 1, 3] = -n, (n @ c) - 0.5 * s[a]
    return planes


def polytope_volume(planes) -> float:
    """Volume [m^3] of the convex polytope (its vertices seen from its Chebyshev centre)."""
    return _polytope(_as_planes(planes), "polytope").volume


# ----------------------------------------------------------------------------------------
# seeds
# ----------------------------------------------------------------------------------------
def _inside(poly: _Polytope, pts: np.ndarray, tol: float) -> np.ndarray:
    """Strictly-inside mask (by ``tol`` from every plane).

    Points deep in the inscribed ball are in and points beyond the enclosing ball are out
    without testing every plane, which is most of the work for finely faceted (sphere-like)
    polytopes; the rest is tested in chunks so the (points x planes) products stay small.
    """
    d = pts - poly.centre
    r2 = np.einsum("ij,ij->i", d, d)
    out = r2 < (poly.inner - 2.0 * tol) ** 2
    check = np.flatnonzero(~out & (r2 <= poly.outer**2))
    P = poly.planes
    step = max(1, _CHUNK // P.shape[0])
    for a in range(0, check.shape[0], step):
        idx = check[a:a + step]
        out[idx] = np.all(pts[idx] @ P[:, :3].T + P[:, 3] < -tol, axis=1)
    return out


def _jittered_seeds(poly: _Polytope, h: float, rng, what: str) -> np.ndarray:
    """One random point per cell of the cubic lattice of spacing h over the bounds, kept if inside."""
    if poly.volume / h**3 > MAX_SEEDS:
        raise InputError(f"{what}: spacing {h:g} m needs about {poly.volume / h**3:,.0f} Voronoi cells (limit "
                         f"{MAX_SEEDS:,}); use a spacing of at least {(poly.volume / MAX_SEEDS) ** (1 / 3):.3g} m")
    n = np.maximum(1, np.ceil((poly.hi - poly.lo) / h - 1e-9)).astype(np.int64)
    total = int(np.prod(n))
    if total > MAX_LATTICE_CELLS:
        raise InputError(f"{what}: spacing {h:g} m over its bounding box needs {total:,} lattice cells (limit "
                         f"{MAX_LATTICE_CELLS:,}); use a larger spacing")
    out = []
    step = _CHUNK // 4
    for a in range(0, total, step):
        idx = np.arange(a, min(total, a + step), dtype=np.int64)
        cell = np.stack(np.unravel_index(idx, tuple(n)), axis=1).astype(np.float64)
        pts = poly.lo + (cell + rng.random(cell.shape)) * h
        out.append(pts[_inside(poly, pts, INSIDE_TOL * h)])
    return np.concatenate(out)


def _random_seeds(poly: _Polytope, count: int, rng) -> np.ndarray:
    """``count`` uniform points inside the polytope, by rejection in its bounding box."""
    tol = INSIDE_TOL * (poly.volume / count) ** (1.0 / 3.0)
    accept = max(poly.volume / float(np.prod(poly.hi - poly.lo)), 1e-6)
    out, got = [], 0
    while got < count:
        m = int(min(_CHUNK, max(64, 1.2 * (count - got) / accept)))
        pts = poly.lo + rng.random((m, 3)) * (poly.hi - poly.lo)
        pts = pts[_inside(poly, pts, tol)][: count - got]
        out.append(pts)
        got += pts.shape[0]
    return np.concatenate(out)


# ----------------------------------------------------------------------------------------
# cells
# ----------------------------------------------------------------------------------------
def _neighbours(seeds: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    """CSR (indptr, indices) of each seed's Delaunay neighbours; all others for tiny sets."""
    n = seeds.shape[0]
    if n >= 5:
        try:
            tri = Delaunay(seeds)
        except QhullError:
            tri = None
        if tri is not None:
            if len(tri.coplanar):
                raise InputError(f"{what}: two Voronoi seeds coincide; use another random seed or spacing")
            indptr, indices = tri.vertex_neighbor_vertices
            return indptr.astype(np.int64), indices.astype(np.int64)
    if n > 64:
        raise InputError(f"{what}: the Voronoi seeds are degenerate (all on one plane); the shape is too flat "
                         "for this spacing: use a smaller spacing")
    # few seeds (or all coplanar): every other seed is a candidate; redundant bisectors drop out
    idx = np.array([j for i in range(n) for j in range(n) if j != i], dtype=np.int64)
    return np.arange(0, n * (n - 1) + 1, n - 1, dtype=np.int64), idx


def _ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenated ``arange(s, s + c)`` for all (s, c), vectorised."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    return np.repeat(starts - (np.cumsum(counts) - counts), counts) + np.arange(total, dtype=np.int64)


class _Clipper:
    """Clips every seed's Voronoi cell to the polytope.

    A cell is one qhull call: the convex hull of the dual points ``n_h / slack_h`` of its
    half-spaces (slack seen from an interior point, normally the seed). Each dual facet is a cell
    vertex, each dual hull vertex a face (so the half-space, hence the neighbour, of every face
    is known exactly) and each dual edge a polyhedron edge. That is ``HalfspaceIntersection``
    without the second hull it would need to recover the faces. Everything around the qhull
    calls is vectorised over the cells; the calls run in a small thread pool (qhull itself runs
    without the GIL, but scipy's wrapper around it does not, so the gain is modest).

    A cell needs a polytope plane only where it crosses that plane's facet, i.e. only planes
    whose facet is within the cell's reach (farthest vertex) of the seed. They are added lazily:
    those near the seed first, then those a finished cell's vertex violates, until no vertex is
    outside any plane whose facet it could reach (then the cell lies inside the polytope: the
    segment from the seed to an outside vertex would leave through such a facet).
    """

    def __init__(self, seeds, poly: _Polytope, size: float, indptr, indices, what: str):
        self.seeds, self.poly, self.P, self.size, self.what = seeds, poly, poly.planes, size, what
        self.indptr, self.indices = indptr, indices
        self.nb = np.diff(indptr)
        # bisector of every Delaunay edge, in the frame of its cell's seed: unit normal towards the
        # neighbour, at half the distance
        dv = seeds[indices] - np.repeat(seeds, self.nb, axis=0)
        dist = np.linalg.norm(dv, axis=1)
        self.bis = np.empty((indices.shape[0], 4))
        self.bis[:, :3] = dv / dist[:, None]
        self.bis[:, 3] = -0.5 * dist
        self.far = np.maximum.reduceat(dist, indptr[:-1])  # farthest neighbour of each seed
        self.near = np.minimum.reduceat(dist, indptr[:-1])
        # no plane is closer to a seed than its depth inside the inscribed ball
        self.depth = poly.inner - np.linalg.norm(seeds - poly.centre, axis=1)
        self.tree = cKDTree(poly.facet_centre)
        self.rmax = float(poly.facet_radius.max())
        # an enlarged bounding box keeps cells on the seeds' hull bounded before polytope planes are added;
        # the polytope is strictly inside it, so it never survives as a face of a finished cell
        lo, hi = poly.lo, poly.hi
        m = 0.05 * float(np.max(hi - lo)) + size
        self.box = np.array([[1, 0, 0, -(hi[0] + m)], [-1, 0, 0, lo[0] - m],
                             [0, 1, 0, -(hi[1] + m)], [0, -1, 0, lo[1] - m],
                             [0, 0, 1, -(hi[2] + m)], [0, 0, -1, lo[2] - m]], dtype=np.float64)
        self.tol = VIOLATION_TOL * size
        self.workers = max(1, min(8, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                  else os.cpu_count() or 1))

    def _near_planes(self, cells: np.ndarray, reach: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(cell, plane) pairs, sorted, whose facet (and plane) is within ``reach`` of the cell's seed."""
        reach = reach + self.tol
        m = reach >= self.depth[cells]
        cells, reach = cells[m], reach[m]
        if cells.shape[0] == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        s = self.seeds[cells]
        found = self.tree.query_ball_point(s, reach + self.rmax, return_sorted=False, workers=self.workers)
        cnt = np.fromiter(map(len, found), dtype=np.int64, count=len(found))
        sp = np.fromiter(itertools.chain.from_iterable(found), dtype=np.int64, count=int(cnt.sum()))
        k = np.repeat(np.arange(cells.shape[0]), cnt)
        P, fc = self.P[sp], self.poly.facet_centre[sp]
        ok = (np.linalg.norm(s[k] - fc, axis=1) <= reach[k] + self.poly.facet_radius[sp]) & (
            -(np.einsum("ij,ij->i", P[:, :3], s[k]) + P[:, 3]) <= reach[k])
        sc, sp = cells[k[ok]], sp[ok]
        order = np.lexsort((sp, sc))
        return sc[order], sp[order]

    def _halfspaces(self, todo, sc, sp):
        """Stacked local half-spaces of the cells ``todo`` (sorted): bisectors, planes, box."""
        P, seeds = self.P, self.seeds
        nb = self.nb[todo]
        first, last = np.searchsorted(sc, todo, "left"), np.searchsorted(sc, todo, "right")
        ns = last - first
        off = np.concatenate([[0], np.cumsum(nb + ns + 6)])
        HS = np.empty((int(off[-1]), 4))
        label = np.full(HS.shape[0], -1, dtype=np.int64)
        src = _ranges(self.indptr[todo], nb)
        row = _ranges(off[:-1], nb)
        HS[row], label[row] = self.bis[src], self.indices[src]
        pair = _ranges(first, ns)
        cell, plane = sc[pair], sp[pair]
        row = _ranges(off[:-1] + nb, ns)
        HS[row, :3] = P[plane, :3]
        HS[row, 3] = P[plane, 3] + np.einsum("ij,ij->i", P[plane, :3], seeds[cell])
        closest = np.full(todo.shape[0], np.inf)
        np.minimum.at(closest, np.searchsorted(todo, cell), -HS[row, 3])
        hard = closest < INTERIOR_RATIO * 0.5 * self.near[todo]
        row = (off[1:] - 6)[:, None] + np.arange(6)
        HS[row, :3] = self.box[:, :3]
        HS[row, 3] = self.box[:, 3] + seeds[todo] @ self.box[:, :3].T
        return off, HS, label, hard

    def _dual_hull(self, hs: np.ndarray, seed: np.ndarray, hard: bool):
        """(vertices (local frame), simplices, neighbours) of one cell's dual hull."""
        if not hard:
            try:
                hull = ConvexHull(hs[:, :3] / -hs[:, 3:4])
                eq = hull.equations
                if np.all(eq[:, 3] < 0.0):  # origin strictly inside the dual hull: a bounded cell
                    return -eq[:, :3] / eq[:, 3:4], hull.simplices, hull.neighbors
            except QhullError:
                pass
        # a seed hugging a plane, or qhull trouble: from the Chebyshev centre, then joggled
        slack = -hs[:, 3]
        for attempt in range(3):
            centre = np.zeros(3)
            cheb = _chebyshev(hs)
            if cheb is not None and cheb[1] > 0.0:
                centre = cheb[0]
            sl = slack - hs[:, :3] @ centre
            if not np.all(sl > 0.0):
                continue
            try:
                hull = ConvexHull(hs[:, :3] / sl[:, None], qhull_options="QJ" if attempt == 2 else None)
            except QhullError:
                continue
            eq = hull.equations
            if np.all(eq[:, 3] < 0.0):
                return centre - eq[:, :3] / eq[:, 3:4], hull.simplices, hull.neighbors
        raise InputError(f"{self.what}: qhull failed to clip a Voronoi cell (seed at "
                         f"{np.array2string(seed, precision=6)} m); try another random seed or spacing")

    def _clip(self, todo, sc, sp, results: list) -> None:
        """Compute the cells ``todo`` with their selected planes into ``results``."""
        off, HS, label, hard = self._halfspaces(todo, sc, sp)
        seeds = self.seeds
        cell, off, hard = todo.tolist(), off.tolist(), hard.tolist()  # cheap scalar access in the loop

        def run(block):
            for k in block.tolist():
                i, a, b = cell[k], off[k], off[k + 1]
                x, simp, neigh = self._dual_hull(HS[a:b], seeds[i], hard[k])
                results[i] = (x + seeds[i], simp, neigh, label[a:b], HS[a:b, :3])

        if self.workers > 1 and todo.shape[0] >= 64:
            blocks = np.array_split(np.arange(todo.shape[0]), min(todo.shape[0], self.workers * 8))
            with ThreadPoolExecutor(self.workers) as ex:
                list(ex.map(run, blocks))
        else:
            run(np.arange(todo.shape[0]))

    def _violations(self, todo, sc, sp, results: list) -> tuple[np.ndarray, np.ndarray]:
        """(cell, plane) pairs, not yet used, whose facet the cell reaches and that a vertex violates."""
        reach = np.empty(todo.shape[0])
        for k, i in enumerate(todo):
            d = results[i][0] - self.seeds[i]
            reach[k] = math.sqrt(float(np.max(np.einsum("ij,ij->i", d, d))))
        cc, cp = self._near_planes(todo, reach)
        k = self.P.shape[0]
        new = ~np.isin(cc * k + cp, sc * k + sp)
        cc, cp = cc[new], cp[new]
        if cc.shape[0] == 0:
            return cc, cp
        nv = np.array([results[i][0].shape[0] for i in cc], dtype=np.int64)
        X = np.concatenate([results[i][0] for i in cc])
        pl = self.P[np.repeat(cp, nv)]
        val = np.einsum("ij,ij->i", X, pl[:, :3]) + pl[:, 3]
        bad = np.maximum.reduceat(val, np.cumsum(nv) - nv) > self.tol
        return cc[bad], cp[bad]

    def run(self) -> list:
        """Per cell: (vertices, dual simplices, dual neighbours, face labels, face normals)."""
        n = self.seeds.shape[0]
        results: list = [None] * n
        todo = np.arange(n)
        sc, sp = self._near_planes(todo, 1.5 * self.far)
        for _ in range(self.P.shape[0] + 1):
            self._clip(todo, sc, sp, results)
            vc, vp = self._violations(todo, sc, sp, results)
            if vc.shape[0] == 0:
                break
            sc, sp = np.concatenate([sc, vc]), np.concatenate([sp, vp])
            order = np.lexsort((sp, sc))
            sc, sp = sc[order], sp[order]
            todo = np.unique(vc)
        return results


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
                     a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _assemble(seeds: np.ndarray, results: list, size: float) -> VoronoiCells:
    """Polyhedra, volumes, centroids and shared faces of all cells, vectorised over the cells."""
    n = seeds.shape[0]
    nf = np.array([r[0].shape[0] for r in results], dtype=np.int64)  # vertices (dual facets)
    nh = np.array([r[3].shape[0] for r in results], dtype=np.int64)  # half-spaces (candidate faces)
    cells = np.arange(n, dtype=np.int64)
    F, H = int(nf.sum()), int(nh.sum())
    X = np.concatenate([r[0] for r in results])
    cell_f = np.repeat(cells, nf)
    S = np.concatenate([r[1] for r in results]).astype(np.int64) + np.repeat(np.cumsum(nh) - nh, nf)[:, None]
    N = np.concatenate([r[2] for r in results]).astype(np.int64) + np.repeat(np.cumsum(nf) - nf, nf)[:, None]
    label = np.concatenate([r[3] for r in results])
    normal = np.concatenate([r[4] for r in results])
    cell_h = np.repeat(cells, nh)

    # dual edges are polyhedron edges: facet f and its neighbour g across the dual edge (h1, h2);
    # the edge x_f - x_g lies on faces h1 and h2
    f = np.arange(F, dtype=np.int64)
    parts = []
    for k in range(3):
        m = f < N[:, k]
        parts.append((f[m], N[m, k], S[m, (k + 1) % 3], S[m, (k + 2) % 3]))
    ef, eg, eh1, eh2 = (np.concatenate(x) for x in zip(*parts))

    # qhull splits a vertex where more than 3 faces meet into coincident dual facets: merge them
    # through their zero-length edges
    d = X[ef] - X[eg]
    tiny = np.einsum("ij,ij->i", d, d) <= (MERGE_TOL * size) ** 2
    if tiny.any():
        graph = coo_matrix((np.ones(int(tiny.sum())), (ef[tiny], eg[tiny])), shape=(F, F))
        comp = connected_components(graph, directed=False)[1].astype(np.int64)
    else:
        comp = f
    first = np.full(int(comp.max()) + 1, F, dtype=np.int64)
    np.minimum.at(first, comp, f)  # representative facet of each vertex; in cell order
    used = np.flatnonzero(first < F)
    order = np.argsort(first[used], kind="stable")
    vid_of = np.empty(first.shape[0], dtype=np.int64)
    vid_of[used[order]] = np.arange(used.shape[0])
    vid = vid_of[comp]
    rep = first[used[order]]
    V = X[rep]
    vertex_cell = cell_f[rep]

    # each face is a convex polygon given by its edges: fan it from its smallest vertex
    face = np.concatenate([eh1, eh2])
    u = np.concatenate([vid[ef], vid[ef]])
    w = np.concatenate([vid[eg], vid[eg]])
    m = u != w
    face, u, w = face[m], u[m], w[m]
    anchor = np.full(H, V.shape[0], dtype=np.int64)
    np.minimum.at(anchor, face, u)
    np.minimum.at(anchor, face, w)
    m = (u != anchor[face]) & (w != anchor[face])
    face, u, w = face[m], u[m], w[m]
    order = np.argsort(face, kind="stable")  # group triangles by face, hence by cell
    face = face[order]
    T = np.stack([anchor[face], u[order], w[order]], axis=1)
    poly_cell = cell_h[face]

    # orient like the face's outward normal
    a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    cr = _cross(b - a, c - a)
    flip = np.einsum("ij,ij->i", cr, normal[face]) < 0.0
    T[flip] = T[flip][:, [0, 2, 1]]
    b, c = V[T[:, 1]], V[T[:, 2]]
    area = 0.5 * np.sqrt(np.einsum("ij,ij->i", cr, cr))

    # volume and centroid: tetrahedra from each cell's seed (inside the cell) to its triangles
    p = seeds[poly_cell]
    a, b, c = a - p, b - p, c - p
    tv = np.einsum("ij,ij->i", a, _cross(b, c)) / 6.0
    volumes = np.bincount(poly_cell, tv, minlength=n)
    tc = (a + b + c) / 4.0  # tetrahedron centroid relative to the seed
    centroids = seeds + np.stack([np.bincount(poly_cell, tv * tc[:, k], minlength=n) for k in range(3)],
                                 axis=1) / volumes[:, None]

    # shared faces: area of face (i -> j) and of (j -> i); a bond needs both above the threshold
    side_all = np.bincount(face, area, minlength=H)
    inner = np.flatnonzero(label >= 0)
    key = cell_h[inner] * n + label[inner]  # unique per (cell i, neighbour j)
    srt = np.argsort(key, kind="stable")
    inner, key = inner[srt], key[srt]  # sorted like (i, j)
    side, ci, cj = side_all[inner], cell_h[inner], label[inner]
    if key.shape[0]:
        rev = np.minimum(np.searchsorted(key, cj * n + ci), key.shape[0] - 1)
        both = key[rev] == cj * n + ci
    else:
        rev, both = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool)
    thr = FACE_TOL * size**2
    ok = (ci < cj) & both
    ok[ok] &= (side[ok] > thr) & (side[rev[ok]] > thr)
    pairs = np.stack([ci[ok], cj[ok]], axis=1).astype(np.int64).reshape(-1, 2)
    face_area = 0.5 * (side[ok] + side[rev[ok]])

    return VoronoiCells(
        seeds=seeds,
        centroids=centroids,
        volumes=volumes,
        pairs=pairs,
        face_area=face_area,
        poly_vertices=V,
        poly_triangles=T.astype(np.int64),
        poly_cell=poly_cell,
        vertex_cell=vertex_cell,
    )


def _seed_count_error(what, n, spacing, poly: _Polytope) -> InputError:
    ext = poly.hi - poly.lo
    return InputError(f"{what}: only {n} Voronoi seed(s) fall inside it with spacing {spacing:g} m (its bounding "
                      f"box is {' x '.join(f'{e:.3g}' for e in ext)} m); a body needs at least 2 cells: use a "
                      f"spacing of at most {float(ext.min()) / 2:.3g} m or make the shape larger")


def voronoi_cells(planes: np.ndarray, spacing: float | None, count: int | None, rng: np.random.Generator,
                  what: str = "voronoi body") -> VoronoiCells:
    """Seeds inside the polytope (jittered lattice of ``spacing`` or ``count`` uniform points), their
    Voronoi cells clipped to it: the volumes tile the polytope, the centroids are the material points.

    Exactly one of ``spacing`` [m] and ``count`` is given (else ValueError: a programming error).
    """
    if (spacing is None) == (count is None):
        raise ValueError("voronoi_cells: give exactly one of spacing and count")
    poly = _polytope(_as_planes(planes, what), what)
    if spacing is not None:
        h = _positive(spacing, f"{what}: Voronoi spacing")
        seeds = _jittered_seeds(poly, h, rng, what)
        if seeds.shape[0] < 2:
            raise _seed_count_error(what, seeds.shape[0], h, poly)
    else:
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 2:
            raise InputError(f"{what}: Voronoi seed count must be an integer >= 2, got {count!r}")
        if count > MAX_SEEDS:
            raise InputError(f"{what}: {count:,} Voronoi seeds requested (limit {MAX_SEEDS:,}); use fewer")
        seeds = _random_seeds(poly, int(count), rng)
    size = (poly.volume / seeds.shape[0]) ** (1.0 / 3.0)
    indptr, indices = _neighbours(seeds, what)
    results = _Clipper(seeds, poly, size, indptr, indices, what).run()
    return _assemble(seeds, results, size)
