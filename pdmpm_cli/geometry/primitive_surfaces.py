"""Triangulated surfaces of the built-in primitives (sheet, box, sphere, cylinder, capsule).

Each shape is triangulated with edges about ``edge`` long, outward-oriented and validated like a
mesh file: the sheet is a regular grid (open), the box a regular grid on each face, the sphere,
cylinder and capsule are surfaces of revolution: rings of about ``2 pi rho / edge`` vertices
spaced ``edge`` along the profile, adjacent rings zipped together by angle (a single vertex at
the poles / cap centres). Shell bodies sample these surfaces; Voronoi bodies take the vertices
as the corners of an inscribed polytope.
"""

from __future__ import annotations

import math

import numpy as np

from pdmpm_cli.errors import InputError
from pdmpm_cli.geometry.mesh import SurfaceMesh, _weld, is_closed, validate_surface
from pdmpm_cli.geometry.shapes import _positive, _rotation, _size3, _vec3

__all__ = ["PRIMITIVES", "bowl_surface", "primitive_surface"]

PRIMITIVES = ("sheet", "box", "sphere", "cylinder", "capsule")
#: refuse primitive surfaces with more triangles than this
MAX_TRIANGLES = 20_000_000


def _grid_face(o, U, W, nu: int, nw: int) -> tuple[np.ndarray, np.ndarray]:
    """Regular grid o + i/nu U + j/nw W, triangulated counter-clockwise about U x W."""
    i, j = np.meshgrid(np.arange(nu + 1), np.arange(nw + 1), indexing="ij")
    V = o + (i.reshape(-1, 1) / nu) * U + (j.reshape(-1, 1) / nw) * W
    idx = lambda a, b: a * (nw + 1) + b  # noqa: E731
    a, b = np.meshgrid(np.arange(nu), np.arange(nw), indexing="ij")
    a, b = a.ravel(), b.ravel()
    p00, p10, p11, p01 = idx(a, b), idx(a + 1, b), idx(a + 1, b + 1), idx(a, b + 1)
    T = np.concatenate([np.stack([p00, p10, p11], 1), np.stack([p00, p11, p01], 1)])
    return V, T.astype(np.int64)


def _nseg(length: float, edge: float) -> int:
    return max(1, int(round(length / edge)))


def _box_local(size, edge) -> tuple[np.ndarray, np.ndarray]:
    """Box centred at the origin: a grid on each face, shared edge vertices welded."""
    a, b, c = size
    na, nb, nc = _nseg(a, edge), _nseg(b, edge), _nseg(c, edge)
    X, Y, Z = np.array([a, 0.0, 0.0]), np.array([0.0, b, 0.0]), np.array([0.0, 0.0, c])
    lo = -0.5 * np.asarray(size)
    faces = [  # (origin, U, W, nu, nw) with U x W = outward normal
        (lo + X, Y, Z, nb, nc), (lo, Z, Y, nc, nb),
        (lo + Y, Z, X, nc, na), (lo, X, Z, na, nc),
        (lo + Z, X, Y, na, nb), (lo, Y, X, nb, na),
    ]
    Vs, Ts, off = [], [], 0
    for o, U, W, nu, nw in faces:
        V, T = _grid_face(o, U, W, nu, nw)
        Vs.append(V)
        Ts.append(T + off)
        off += V.shape[0]
    V, T = np.concatenate(Vs), np.concatenate(Ts)
    V, T, _ = _weld(V, T, 1e-9 * float(np.linalg.norm(size)))
    used, inv = np.unique(T, return_inverse=True)
    return V[used], inv.reshape(T.shape).astype(np.int64)


def _profile(kind: str, edge: float, radius: float, height: float, length: float) -> np.ndarray:
    """(rho, z) points from the bottom pole to the top pole of a surface of revolution about z."""
    pts: list[np.ndarray] = []

    def arc(zc, phi0, phi1):
        n = _nseg(abs(phi1 - phi0) * radius, edge)
        phi = np.linspace(phi0, phi1, n + 1)
        pts.append(np.stack([radius * np.cos(phi), zc + radius * np.sin(phi)], 1))

    def line(p0, p1):
        n = _nseg(float(np.hypot(p1[0] - p0[0], p1[1] - p0[1])), edge)
        s = np.linspace(0.0, 1.0, n + 1)[:, None]
        pts.append((1.0 - s) * np.asarray(p0) + s * np.asarray(p1))

    if kind == "sphere":
        arc(0.0, -0.5 * math.pi, 0.5 * math.pi)
    elif kind == "cylinder":
        z = 0.5 * height
        line((0.0, -z), (radius, -z))
        line((radius, -z), (radius, z))
        line((radius, z), (0.0, z))
    else:  # capsule
        z = 0.5 * length
        arc(-z, -0.5 * math.pi, 0.0)
        if length > 0.0:
            line((radius, -z), (radius, z))
        arc(z, 0.0, 0.5 * math.pi)
    P = np.concatenate(pts)
    keep = np.ones(P.shape[0], bool)  # drop the repeated joints between pieces
    keep[1:] = np.any(np.abs(np.diff(P, axis=0)) > 1e-12 * radius, axis=1)
    P = P[keep]
    P[0, 0] = P[-1, 0] = 0.0  # exact poles
    return P


def _revolve(profile: np.ndarray, edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Rings of vertices about z (outward for a profile going up), adjacent rings zipped by angle."""
    V: list[np.ndarray] = []
    rings: list[tuple[int, int, float]] = []  # (first vertex, count (1 = pole), angular offset)
    off = 0
    for j, (rho, z) in enumerate(profile):
        if rho <= 0.0:
            m, phase = 1, 0.0
            V.append(np.array([[0.0, 0.0, z]]))
        else:
            m = max(3, int(round(2.0 * math.pi * rho / edge)))
            phase = (j % 2) * math.pi / m  # stagger neighbouring rings
            th = phase + 2.0 * math.pi * np.arange(m) / m
            V.append(np.stack([rho * np.cos(th), rho * np.sin(th), np.full(m, z)], 1))
        rings.append((off, m, phase))
        off += m
    T: list[tuple[int, int, int]] = []
    for (a0, ma, pa), (b0, mb, pb) in zip(rings[:-1], rings[1:]):
        na = 0 if ma == 1 else ma  # steps along each ring (none around a pole)
        nb = 0 if mb == 1 else mb
        i = j = 0
        while i < na or j < nb:
            next_a = pa + 2.0 * math.pi * (i + 1) / ma
            next_b = pb + 2.0 * math.pi * (j + 1) / mb
            A, B = a0 + i % ma, b0 + j % mb
            if j >= nb or (i < na and next_a < next_b):
                T.append((A, a0 + (i + 1) % ma, B))
                i += 1
            else:
                T.append((A, b0 + (j + 1) % mb, B))
                j += 1
    return np.concatenate(V), np.asarray(T, dtype=np.int64)


def primitive_surface(kind: str, *, center, R, edge: float, size=None, radius=None, height=None,
                      length=None) -> SurfaceMesh:
    """Triangulated surface of a built-in primitive with edges about `edge` long, outward-oriented.

    kind: 'sheet' (OPEN flat rectangle, size=(a, b) full lengths along local x and y, normal =
    local +z, centred at center), 'box' (size=(a, b, c)), 'sphere' (radius), 'cylinder'
    (radius, height along local z, capped), 'capsule' (radius, length = distance between cap
    centres along local z). R is a 3x3 rotation matrix (local axes = columns), applied about
    the centre. Closed ones are validated like a mesh file; the sheet has ``closed=False``.
    """
    if kind not in PRIMITIVES:
        raise InputError(f"unknown surface primitive {kind!r}; choose one of {', '.join(PRIMITIVES)}")
    c = _vec3(center, "center")
    M = _rotation(R)
    e = _positive(edge, "edge")
    what = f"{kind} surface"

    def need(value, name):
        if value is None:
            raise InputError(f"{what}: {name} is required for a {kind}")
        return value

    if kind == "sheet":
        s = need(size, "size=(a, b)")
        try:
            ab = np.asarray(s, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            ab = np.zeros(0)
        if ab.shape != (2,) or not np.all(np.isfinite(ab)) or np.any(ab <= 0.0):
            raise InputError(f"{what}: size must be 2 positive lengths (a, b) in metres, got {s!r}")
        area = float(ab[0] * ab[1])
    elif kind == "box":
        abc = _size3(need(size, "size=(a, b, c)"))
        area = 2.0 * float(abc[0] * abc[1] + abc[1] * abc[2] + abc[0] * abc[2])
    else:
        r = _positive(need(radius, "radius"), "radius")
        hgt = _positive(need(height, "height"), "height") if kind == "cylinder" else 0.0
        lng = _positive(need(length, "length"), "length", allow_zero=True) if kind == "capsule" else 0.0
        area = 4.0 * math.pi * r * r + 2.0 * math.pi * r * (hgt + lng) + (2.0 * math.pi * r * r if hgt else 0.0)
    n_tri = 2.3 * area / (e * e)  # ~ 2 triangles per edge^2 (rounded up for the ring zippers)
    if n_tri > MAX_TRIANGLES:
        raise InputError(
            f"{what}: edge {e:g} m would give about {n_tri:,.0f} triangles (limit {MAX_TRIANGLES:,}); use an "
            f"edge of at least {math.sqrt(2.3 * area / MAX_TRIANGLES):.3g} m"
        )

    if kind == "sheet":
        V, T = _grid_face(np.array([-0.5 * ab[0], -0.5 * ab[1], 0.0]), np.array([ab[0], 0.0, 0.0]),
                          np.array([0.0, ab[1], 0.0]), _nseg(ab[0], e), _nseg(ab[1], e))
    elif kind == "box":
        V, T = _box_local(abc, e)
    else:
        V, T = _revolve(_profile(kind, e, r, hgt, lng), e)
    V = c + V @ M.T
    V, T, repairs = validate_surface(V, T, what, allow_open=(kind == "sheet"))
    return SurfaceMesh(V, T, "", repairs, closed=is_closed(T))


def bowl_surface(outer: float, inner: float, edge: float) -> SurfaceMesh:
    """A hemispherical bowl as a closed solid: outer and inner hemispheres (radii [m]) joined by a flat rim at
    y = 0, opening towards +y, about the origin. For mesh-collider checks (the stability sweep, the tests):
    a container whose hollow is outside the solid. Volume 2 pi (outer^3 - inner^3) / 3."""
    if not 0.0 < inner < outer:
        raise InputError(f"bowl: need 0 < inner < outer radius, got inner {inner!r}, outer {outer!r}")
    profile = [(outer * math.cos(a), outer * math.sin(a)) for a in
               np.linspace(-0.5 * math.pi, 0.0, _nseg(0.5 * math.pi * outer, edge) + 1)]
    n_rim = _nseg(outer - inner, edge)
    profile += [(outer - (outer - inner) * k / n_rim, 0.0) for k in range(1, n_rim)]
    profile += [(inner * math.cos(a), inner * math.sin(a)) for a in
                np.linspace(0.0, -0.5 * math.pi, _nseg(0.5 * math.pi * inner, edge) + 1)]
    P = np.array(profile)
    P[0, 0] = P[-1, 0] = 0.0
    V, T = _revolve(P, edge)
    V, T, repairs = validate_surface(V[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0]), T, "bowl")  # z up -> y up
    return SurfaceMesh(V, T, "", repairs, closed=is_closed(T))
