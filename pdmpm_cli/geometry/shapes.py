"""Analytic primitive shapes: vectorised inside tests, volumes and axis-aligned bounds.

Conventions (SI units, metres):

* every primitive has a ``center`` (3,) and, except the sphere, an optional rotation matrix
  ``R`` (3, 3), default identity. The shape is defined in its local frame (centred at the
  origin) and placed in the world by ``x_world = center + R @ x_local``; i.e. the local frame
  is rotated by ``R`` about the centre.
* ``box``: ``size`` = full edge lengths (3,) along the local x, y, z axes.
* ``cylinder``: local axis = z, ``height`` = full length, ``radius``.
* ``capsule``: local axis = z, ``length`` = distance between the two hemisphere centres
  (``length = 0`` is a sphere), ``radius``.
* inside tests are inclusive (points exactly on the surface count as inside).

``rotation_matrix((ax, ay, az))`` builds ``R`` from rotations in degrees about the world
x, then y, then z axes (extrinsic), i.e. ``R = Rz(az) @ Ry(ay) @ Rx(ax)``.

Bad parameters raise :class:`pdmpm_cli.errors.InputError`.
"""

from __future__ import annotations

import math

import numpy as np

from pdmpm_cli.errors import InputError

__all__ = [
    "rotation_matrix",
    "box_inside",
    "sphere_inside",
    "cylinder_inside",
    "capsule_inside",
    "box_volume",
    "sphere_volume",
    "cylinder_volume",
    "capsule_volume",
    "box_bounds",
    "sphere_bounds",
    "cylinder_bounds",
    "capsule_bounds",
]


# ----------------------------------------------------------------------------------------
# argument helpers
# ----------------------------------------------------------------------------------------
def _vec3(x, name: str) -> np.ndarray:
    try:
        v = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be 3 numbers, got {x!r}") from None
    if v.shape != (3,):
        raise InputError(f"{name} must be 3 numbers [x, y, z], got {x!r}")
    if not np.all(np.isfinite(v)):
        raise InputError(f"{name} must be finite, got {x!r}")
    return v


def _positive(x, name: str, *, allow_zero: bool = False) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {x!r}") from None
    ok = (v >= 0.0) if allow_zero else (v > 0.0)
    if not (math.isfinite(v) and ok):
        need = "non-negative" if allow_zero else "positive"
        raise InputError(f"{name} must be a {need} length in metres (finite), got {x!r}")
    return v


def _size3(x, name: str = "size") -> np.ndarray:
    v = _vec3(x, name)
    if np.any(v <= 0.0):
        raise InputError(f"{name} must be positive edge lengths in metres, got {x!r}")
    return v


def _rotation(R) -> np.ndarray:
    """Validate an optional rotation matrix (None -> identity)."""
    if R is None:
        return np.eye(3)
    try:
        M = np.asarray(R, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"rotation must be a 3x3 matrix, got {R!r}") from None
    if M.shape != (3, 3) or not np.all(np.isfinite(M)):
        raise InputError(f"rotation must be a finite 3x3 matrix, got shape {M.shape}")
    if not np.allclose(M.T @ M, np.eye(3), atol=1e-6) or np.linalg.det(M) <= 0.0:
        raise InputError(
            "rotation matrix must be orthonormal with determinant +1 (a proper rotation, "
            "no scaling or mirroring); build it with rotation_matrix((ax, ay, az))"
        )
    return M


def _points(p) -> np.ndarray:
    P = np.asarray(p, dtype=np.float64)
    if P.ndim == 1 and P.shape[0] == 3:
        P = P[None, :]
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {P.shape}")
    return P


def _local(p, center, R) -> np.ndarray:
    """World points -> local frame coordinates: R^T (p - center) for each row."""
    return (_points(p) - center) @ R


# ----------------------------------------------------------------------------------------
# rotation
# ----------------------------------------------------------------------------------------
def rotation_matrix(axis_angle_deg) -> np.ndarray:
    """Rotation matrix from angles in degrees about x, y, z, applied in that order.

    ``R = Rz(az) @ Ry(ay) @ Rx(ax)`` (rotations about the fixed world axes: first x, then y,
    then z). ``rotation_matrix((0, 0, 90)) @ [1, 0, 0] == [0, 1, 0]``.
    """
    ax, ay, az = np.deg2rad(_vec3(axis_angle_deg, "rotation (degrees about x, y, z)"))
    cx, sx = math.cos(ax), math.sin(ax)
    cy, sy = math.cos(ay), math.sin(ay)
    cz, sz = math.cos(az), math.sin(az)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    Ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    Rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


# ----------------------------------------------------------------------------------------
# box
# ----------------------------------------------------------------------------------------
def box_inside(p, center, size, R=None) -> np.ndarray:
    """Bool mask (n,): points inside the box of full edge lengths ``size`` (inclusive)."""
    c, s, M = _vec3(center, "center"), _size3(size), _rotation(R)
    q = _local(p, c, M)
    return np.all(np.abs(q) <= 0.5 * s, axis=1)


def box_volume(size) -> float:
    return float(np.prod(_size3(size)))


def box_bounds(center, size, R=None) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds (lo, hi) of the (rotated) box."""
    c, s, M = _vec3(center, "center"), _size3(size), _rotation(R)
    half = np.abs(M) @ (0.5 * s)
    return c - half, c + half


# ----------------------------------------------------------------------------------------
# sphere
# ----------------------------------------------------------------------------------------
def sphere_inside(p, center, radius, R=None) -> np.ndarray:
    """Bool mask (n,): points inside the sphere (inclusive). ``R`` is accepted and ignored."""
    c, r = _vec3(center, "center"), _positive(radius, "radius")
    if R is not None:
        _rotation(R)
    d = _points(p) - c
    return np.einsum("ij,ij->i", d, d) <= r * r


def sphere_volume(radius) -> float:
    r = _positive(radius, "radius")
    return 4.0 / 3.0 * math.pi * r**3


def sphere_bounds(center, radius, R=None) -> tuple[np.ndarray, np.ndarray]:
    c, r = _vec3(center, "center"), _positive(radius, "radius")
    return c - r, c + r


# ----------------------------------------------------------------------------------------
# cylinder (local axis z, full height)
# ----------------------------------------------------------------------------------------
def cylinder_inside(p, center, radius, height, R=None) -> np.ndarray:
    """Bool mask (n,): points inside the closed cylinder (local axis z, full ``height``)."""
    c, M = _vec3(center, "center"), _rotation(R)
    r, h = _positive(radius, "radius"), _positive(height, "height")
    q = _local(p, c, M)
    return (q[:, 0] ** 2 + q[:, 1] ** 2 <= r * r) & (np.abs(q[:, 2]) <= 0.5 * h)


def cylinder_volume(radius, height) -> float:
    r, h = _positive(radius, "radius"), _positive(height, "height")
    return math.pi * r * r * h


def cylinder_bounds(center, radius, height, R=None) -> tuple[np.ndarray, np.ndarray]:
    """Exact axis-aligned bounds of the rotated cylinder (two discs + side)."""
    c, M = _vec3(center, "center"), _rotation(R)
    r, h = _positive(radius, "radius"), _positive(height, "height")
    a = M[:, 2]  # world direction of the local z axis
    half = np.abs(a) * 0.5 * h + r * np.sqrt(np.clip(1.0 - a * a, 0.0, None))
    return c - half, c + half


# ----------------------------------------------------------------------------------------
# capsule (local axis z, length between the hemisphere centres)
# ----------------------------------------------------------------------------------------
def capsule_inside(p, center, radius, length, R=None) -> np.ndarray:
    """Bool mask (n,): points within ``radius`` of the axis segment of length ``length``."""
    c, M = _vec3(center, "center"), _rotation(R)
    r, L = _positive(radius, "radius"), _positive(length, "length", allow_zero=True)
    q = _local(p, c, M)
    z = np.clip(q[:, 2], -0.5 * L, 0.5 * L)
    return q[:, 0] ** 2 + q[:, 1] ** 2 + (q[:, 2] - z) ** 2 <= r * r


def capsule_volume(radius, length) -> float:
    r, L = _positive(radius, "radius"), _positive(length, "length", allow_zero=True)
    return math.pi * r * r * L + 4.0 / 3.0 * math.pi * r**3


def capsule_bounds(center, radius, length, R=None) -> tuple[np.ndarray, np.ndarray]:
    c, M = _vec3(center, "center"), _rotation(R)
    r, L = _positive(radius, "radius"), _positive(length, "length", allow_zero=True)
    half = np.abs(M[:, 2]) * 0.5 * L + r
    return c - half, c + half
