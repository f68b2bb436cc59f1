"""A procedural sitting rabbit ("bunny") built from implicit primitives.

Why: the paper's scenes collide two bunnies, and the scenes must run offline without the
Stanford bunny. This module builds a recognisable stand-in from a smooth union (Inigo
Quilez's polynomial smooth-min) of ellipsoids and round cones: a pear-shaped body (haunch +
chest), hind thighs and long flat hind feet, front paws, a head with a muzzle, two long ears
tilted apart and backwards, and a round tail. The solid is cut flat at the bottom so that
it sits stably on the ground.

Canonical frame: +y up, facing +x, bounding-box height 1, sitting on y = 0, bounding box
centred on the origin in x and z (its centre is ``(0, 0.5, 0)``).

Placement (as for the primitive shapes, rotation about the centre):
``x = R @ (height * (x_canon - c_canon)) + center`` with ``c_canon = (0, 0.5, 0)``.

The shape is designed so that every feature is at least ~0.11 (of the height) thick, so
marching cubes with a spacing up to height / 20 yields one connected closed surface.

Normalisation (bounding box), canonical volume and the convex hull used for tight rotated
bounds are computed once per process (about a second, after Numba has loaded its cached
kernels) and cached.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import njit, prange

from pdmpm_cli.errors import InputError
from pdmpm_cli.geometry.mesh import SurfaceMesh, validate_surface
from pdmpm_cli.geometry.shapes import _points, _positive, _rotation, _vec3

__all__ = ["bunny_sdf", "bunny_inside", "bunny_bounds", "bunny_volume", "bunny_surface"]

#: largest marching-cubes grid bunny_surface builds (about 2.4 GB of float64 samples)
_MAX_GRID_POINTS = 3e8
#: centre of the canonical bunny's bounding box
CANONICAL_CENTER = np.array([0.0, 0.5, 0.0])

# ----------------------------------------------------------------------------------------
# the raw model (units: roughly the height; normalised numerically below)
# ----------------------------------------------------------------------------------------
_ELLIPSOID, _ROUNDCONE = 0, 1
_NPAR = 17  # row layout: type, blend k, then 15 shape parameters

#: the bottom cut: the raw solid is intersected with y >= _CUT_Y (a flat base to sit on)
_CUT_Y = 0.03


def _axes(yaw_deg=0.0, roll_deg=0.0, pitch_deg=0.0) -> np.ndarray:
    """World->local rotation for a tilted primitive (rows = local axes in raw coordinates)."""
    a, b, c = (math.radians(v) for v in (yaw_deg, roll_deg, pitch_deg))
    Ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    Rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return (Ry @ Rx @ Rz).T


def _ellipsoid_row(center, radii, k, M=None) -> np.ndarray:
    M = np.eye(3) if M is None else M
    return np.array([_ELLIPSOID, k, *center, *M.reshape(-1), *radii], dtype=np.float64)


def _roundcone_row(a, b, r1, r2, k) -> np.ndarray:
    row = np.zeros(_NPAR)
    row[:10] = [_ROUNDCONE, k, *a, *b, r1, r2]
    return row


def _ear_axes(a, b, side) -> np.ndarray:
    """World->local rows (broad, along the ear, thin): thin across the head, broad front-back."""
    e = np.subtract(b, a) / np.linalg.norm(np.subtract(b, a))
    w = np.array([0.0, 0.0, side]) - side * e[2] * e
    w /= np.linalg.norm(w)
    return np.stack([np.cross(e, w), e, w])


def _model() -> np.ndarray:
    """Primitive table, unioned in order with each row's smooth-min radius k."""
    rows = [
        # body: big rear haunch and a narrower, higher chest -> pear shape
        _ellipsoid_row((-0.07, 0.27, 0.0), (0.30, 0.26, 0.25), 0.0),
        _ellipsoid_row((0.09, 0.38, 0.0), (0.18, 0.23, 0.175), 0.10, _axes(pitch_deg=-20)),
        # head and muzzle
        _ellipsoid_row((0.22, 0.62, 0.0), (0.185, 0.155, 0.15), 0.10, _axes(pitch_deg=-15)),
        _ellipsoid_row((0.34, 0.575, 0.0), (0.095, 0.085, 0.105), 0.05),
        # tail
        _ellipsoid_row((-0.375, 0.22, 0.0), (0.08, 0.08, 0.08), 0.04),
    ]
    for s in (-1.0, 1.0):
        # ears: a round-cone core (guarantees >= 0.11 thickness and a rounded tip) inside a
        # leaf-shaped ellipsoid (broad front-back, thin across), tilted apart and backwards
        a, b = (0.18, 0.70, s * 0.055), (0.06, 0.99, s * 0.17)
        mid = 0.45 * np.add(a, b) + 0.1 * np.asarray(b)
        rows += [
            # hind thighs (haunches bulging at the sides)
            _ellipsoid_row((-0.10, 0.18, s * 0.155), (0.21, 0.15, 0.10), 0.08, _axes(pitch_deg=10)),
            # long flat hind feet pointing forward
            _ellipsoid_row((0.04, 0.06, s * 0.185), (0.20, 0.06, 0.07), 0.06),
            # front paws under the chest
            _ellipsoid_row((0.20, 0.12, s * 0.075), (0.065, 0.12, 0.06), 0.06),
            _roundcone_row(a, b, 0.062, 0.056, 0.05),
            _ellipsoid_row(mid, (0.085, 0.19, 0.058), 0.03, _ear_axes(a, b, s)),
        ]
    return np.ascontiguousarray(np.stack(rows))


_TABLE = _model()


# ----------------------------------------------------------------------------------------
# Numba kernels
# ----------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _smin(a, b, k):
    """Polynomial smooth minimum (Quilez); k = 0 is the plain min."""
    if k <= 0.0:
        return min(a, b)
    h = max(k - abs(a - b), 0.0) / k
    return min(a, b) - 0.25 * h * h * k


@njit(cache=True, inline="always")
def _sd_ellipsoid(row, x, y, z):
    """Quilez's ellipsoid bound: exact zero set, distance-like near it."""
    dx, dy, dz = x - row[2], y - row[3], z - row[4]
    lx = row[5] * dx + row[6] * dy + row[7] * dz
    ly = row[8] * dx + row[9] * dy + row[10] * dz
    lz = row[11] * dx + row[12] * dy + row[13] * dz
    ax, ay, az = lx / row[14], ly / row[15], lz / row[16]
    k0 = math.sqrt(ax * ax + ay * ay + az * az)
    bx, by, bz = ax / row[14], ay / row[15], az / row[16]
    k1 = math.sqrt(bx * bx + by * by + bz * bz)
    if k1 < 1e-300:
        return -min(row[14], min(row[15], row[16]))
    return k0 * (k0 - 1.0) / k1


@njit(cache=True, inline="always")
def _sd_roundcone(row, x, y, z):
    """Quilez's exact round cone between spheres (a, r1) and (b, r2)."""
    ax, ay, az, bx, by, bz, r1, r2 = row[2], row[3], row[4], row[5], row[6], row[7], row[8], row[9]
    bax, bay, baz = bx - ax, by - ay, bz - az
    l2 = bax * bax + bay * bay + baz * baz
    rr = r1 - r2
    a2 = l2 - rr * rr
    il2 = 1.0 / l2
    pax, pay, paz = x - ax, y - ay, z - az
    yy = pax * bax + pay * bay + paz * baz
    zz = yy - l2
    cx, cy, cz = pax * l2 - bax * yy, pay * l2 - bay * yy, paz * l2 - baz * yy
    x2 = cx * cx + cy * cy + cz * cz
    y2 = yy * yy * l2
    z2 = zz * zz * l2
    k = math.copysign(1.0, rr) * rr * rr * x2
    if math.copysign(1.0, zz) * a2 * z2 > k:
        return math.sqrt(x2 + z2) * il2 - r2
    if math.copysign(1.0, yy) * a2 * y2 < k:
        return math.sqrt(x2 + y2) * il2 - r1
    return (math.sqrt(x2 * a2 * il2) + yy * rr) * il2 - r1


@njit(cache=True)
def _sdf_raw(table, x, y, z):
    d = 1e300
    for i in range(table.shape[0]):
        row = table[i]
        if row[0] == 0.0:
            di = _sd_ellipsoid(row, x, y, z)
        else:
            di = _sd_roundcone(row, x, y, z)
        d = _smin(d, di, row[1]) if i > 0 else di
    return max(d, _CUT_Y - y)


@njit(parallel=True, cache=True)
def _sdf_points(table, P, A, b, scale):
    """scale * sdf_raw(A @ p + b) for each row p of P."""
    n = P.shape[0]
    out = np.empty(n)
    for i in prange(n):
        x, y, z = P[i, 0], P[i, 1], P[i, 2]
        qx = A[0, 0] * x + A[0, 1] * y + A[0, 2] * z + b[0]
        qy = A[1, 0] * x + A[1, 1] * y + A[1, 2] * z + b[1]
        qz = A[2, 0] * x + A[2, 1] * y + A[2, 2] * z + b[2]
        out[i] = scale * _sdf_raw(table, qx, qy, qz)
    return out


@njit(parallel=True, cache=True)
def _sdf_grid(table, origin, h, nx, ny, nz, A, b, scale):
    """The same on the grid origin + h * (i, j, k); returned as (nx, ny, nz)."""
    out = np.empty((nx, ny, nz))
    for i in prange(nx):
        x = origin[0] + h * i
        for j in range(ny):
            y = origin[1] + h * j
            for k in range(nz):
                z = origin[2] + h * k
                qx = A[0, 0] * x + A[0, 1] * y + A[0, 2] * z + b[0]
                qy = A[1, 0] * x + A[1, 1] * y + A[1, 2] * z + b[1]
                qz = A[2, 0] * x + A[2, 1] * y + A[2, 2] * z + b[2]
                out[i, j, k] = scale * _sdf_raw(table, qx, qy, qz)
    return out


@njit(parallel=True, cache=True)
def _bisect(table, P0, P1, iters):
    """Surface points on the segments P0 (inside) -> P1 (outside) of the raw model."""
    n = P0.shape[0]
    out = np.empty((n, 3))
    for i in prange(n):
        lo, hi = 0.0, 1.0
        for _ in range(iters):
            t = 0.5 * (lo + hi)
            x = P0[i, 0] + t * (P1[i, 0] - P0[i, 0])
            y = P0[i, 1] + t * (P1[i, 1] - P0[i, 1])
            z = P0[i, 2] + t * (P1[i, 2] - P0[i, 2])
            if _sdf_raw(table, x, y, z) <= 0.0:
                lo = t
            else:
                hi = t
        t = 0.5 * (lo + hi)
        for c in range(3):
            out[i, c] = P0[i, c] + t * (P1[i, c] - P0[i, c])
    return out


# ----------------------------------------------------------------------------------------
# normalisation, volume, hull (computed once)
# ----------------------------------------------------------------------------------------
#: raw search box (must enclose the raw model with a margin) and the sampling spacing
_RAW_LO = np.array([-0.55, _CUT_Y - 0.02, -0.45])
_RAW_HI = np.array([0.55, 1.15, 0.45])
_RAW_H = 1.0 / 128.0


@lru_cache(maxsize=1)
def _canonical():
    """(s, o, volume, hull points): canonical = s * (raw - o); volume and hull canonical.

    Surface points are the bisected sign changes along the grid lines of a fine raw grid:
    their extent gives the bounding box (error ~h^2 / radius), the signed heights of the
    crossings on vertical lines integrate the volume column by column.
    """
    from scipy.spatial import ConvexHull

    n = np.ceil((_RAW_HI - _RAW_LO) / _RAW_H).astype(np.int64) + 1
    I3 = np.eye(3)
    F = _sdf_grid(_TABLE, _RAW_LO, _RAW_H, n[0], n[1], n[2], I3, np.zeros(3), 1.0)
    inside = F <= 0.0
    if inside[[0, -1]].any() or inside[:, [0, -1]].any() or inside[:, :, [0, -1]].any():
        raise RuntimeError("procedural bunny: the raw model leaves its search box")  # pragma: no cover
    pts, vol = [], 0.0
    for axis in range(3):
        a = np.moveaxis(inside, axis, 0)
        flip = a[:-1] != a[1:]
        idx = np.argwhere(flip)  # columns: (axis, the other two in order)
        order = [1, 2]
        order.insert(axis, 0)
        ijk = idx[:, order]
        lower_in = a[:-1][flip]
        step = np.zeros(3, dtype=np.int64)
        step[axis] = 1
        Pa = _RAW_LO + _RAW_H * ijk
        Pb = _RAW_LO + _RAW_H * (ijk + step)
        P0 = np.where(lower_in[:, None], Pa, Pb)
        P1 = np.where(lower_in[:, None], Pb, Pa)
        X = _bisect(_TABLE, np.ascontiguousarray(P0), np.ascontiguousarray(P1), 40)
        pts.append(X)
        if axis == 1:  # column integral: exits (lower inside) add y, entries subtract it
            vol = float(np.sum(np.where(lower_in, X[:, 1], -X[:, 1]))) * _RAW_H * _RAW_H
    X = np.concatenate(pts)
    lo, hi = X.min(axis=0), X.max(axis=0)
    s = 1.0 / (hi[1] - lo[1])
    o = np.array([0.5 * (lo[0] + hi[0]), lo[1], 0.5 * (lo[2] + hi[2])])
    Xc = s * (X - o)
    hull = np.ascontiguousarray(Xc[ConvexHull(Xc).vertices])
    return s, o, vol * s**3, hull


def _raw_map(center, height, R):
    """Affine world->raw map (A, b) and the world/raw distance factor of a placed bunny."""
    s, o, _, _ = _canonical()
    A = R.T / (height * s)
    b = o + (CANONICAL_CENTER - (R.T @ center) / height) / s
    return np.ascontiguousarray(A), b, height * s


# ----------------------------------------------------------------------------------------
# public API
# ----------------------------------------------------------------------------------------
def bunny_sdf(p: np.ndarray) -> np.ndarray:
    """Approximate signed distance (negative inside) of the canonical bunny (height 1) at points p (m, 3).

    Exact zero set; away from it a distance-like bound (ellipsoids and smooth blends are
    not exact distances), good enough for marching cubes and inside tests.
    """
    s, o, _, _ = _canonical()
    P = np.ascontiguousarray(_points(p))
    return _sdf_points(_TABLE, P, np.eye(3) / s, o.copy(), s)


def bunny_inside(p, center, height, R=None) -> np.ndarray:
    """Bool (m,): inside the bunny of total height `height` [m], whose bounding-box centre is at `center` after rotation R (3x3, about the centre).

    Inclusive (sdf <= 0), like the primitive shapes.
    """
    c, hgt, M = _vec3(center, "center"), _positive(height, "height"), _rotation(R)
    P = np.ascontiguousarray(_points(p))
    A, b, _ = _raw_map(c, hgt, M)
    return _sdf_points(_TABLE, P, A, b, 1.0) <= 0.0


def bunny_bounds(center, height, R=None) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds (lo, hi) [m] of the placed bunny.

    From the cached convex hull of fine canonical surface points, so they stay tight for
    any rotation (a rotated bounding box would not); padded by 1e-3 * height to be safe.
    """
    c, hgt, M = _vec3(center, "center"), _positive(height, "height"), _rotation(R)
    hull = _canonical()[3]
    X = (hull - CANONICAL_CENTER) @ M.T * hgt + c
    pad = 1e-3 * hgt
    return X.min(axis=0) - pad, X.max(axis=0) + pad


def bunny_volume(height) -> float:
    """Volume [m^3] of the bunny of this height (cached canonical volume times height^3)."""
    hgt = _positive(height, "height")
    return _canonical()[2] * hgt**3


def bunny_surface(center, height, R=None, edge: float | None = None) -> SurfaceMesh:
    """A closed, outward-oriented triangle surface of the placed bunny with edges about `edge` long.

    Marching cubes (VTK via pyvista) on a world-axis grid of spacing ``edge`` (default
    height / 40) sampling the signed distance; validated (closed, manifold, oriented).
    """
    c, hgt, M = _vec3(center, "center"), _positive(height, "height"), _rotation(R)
    h = hgt / 40.0 if edge is None else _positive(edge, "edge")
    import pyvista as pv

    pv.OFF_SCREEN = True
    lo, hi = bunny_bounds(c, hgt, M)
    lo, hi = lo - 2.0 * h, hi + 2.0 * h
    n = np.ceil((hi - lo) / h).astype(np.int64) + 1
    if float(np.prod(n.astype(np.float64))) > _MAX_GRID_POINTS:
        raise InputError(
            f"procedural bunny: edge {h:g} m is too small for height {hgt:g} m (the sampling grid "
            f"would have {int(np.prod(n)):,} points); use an edge of at least height / 400"
        )
    A, b, scale = _raw_map(c, hgt, M)
    F = _sdf_grid(_TABLE, lo, h, n[0], n[1], n[2], A, b, scale)
    grid = pv.ImageData(dimensions=tuple(int(v) for v in n), spacing=(h, h, h), origin=tuple(lo))
    grid.point_data["depth"] = -F.ravel(order="F")  # VTK orients normals up the gradient
    surf = grid.contour([0.0], scalars="depth").triangulate().clean()
    T = np.asarray(surf.faces).reshape(-1, 4)[:, 1:]
    V, T, repairs = validate_surface(np.asarray(surf.points, dtype=np.float64), T, "procedural bunny")
    return SurfaceMesh(V, T, "", repairs)
