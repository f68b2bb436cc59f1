"""Procedural bunny: inside test vs SDF, bounds, volume, surface, shape sanity, rotation."""


import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from pdmpm_cli.errors import InputError
from pdmpm_cli.geometry import bvh as B
from pdmpm_cli.geometry import mesh as M
from pdmpm_cli.geometry.bunny import (
    CANONICAL_CENTER,
    bunny_bounds,
    bunny_inside,
    bunny_sdf,
    bunny_surface,
    bunny_volume,
)
from pdmpm_cli.geometry.shapes import rotation_matrix

RNG = np.random.default_rng(7)
I3 = np.eye(3)
CENTER = np.array([0.3, -0.2, 1.1])
HEIGHT = 0.4
R_TILT = rotation_matrix((20.0, 35.0, -50.0))


def components(mesh) -> int:
    """Connected components of the triangle graph (vertices linked by triangle edges)."""
    T, nv = mesh.triangles, mesh.n_vertices
    r = np.concatenate([T[:, 0], T[:, 1]])
    c = np.concatenate([T[:, 1], T[:, 2]])
    return connected_components(coo_matrix((np.ones(r.size), (r, c)), shape=(nv, nv)), directed=False)[0]


def to_canonical(x, center, height, R):
    """Inverse placement: x = R @ (height * (xc - c_canon)) + center."""
    return (np.asarray(x) - center) @ R / height + CANONICAL_CENTER


def sample_box(lo, hi, n):
    return RNG.uniform(lo, hi, (n, 3))


def grid_points(lo, hi, h):
    axes = [np.arange(a + 0.5 * h, b, h) for a, b in zip(lo, hi)]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)


# ---------------------------------------------------------------------------- inside / sdf
@pytest.mark.parametrize("center,height,R", [((0.0, 0.5, 0.0), 1.0, I3), (CENTER, HEIGHT, R_TILT)])
def test_inside_agrees_with_sdf(center, height, R):
    center = np.asarray(center, float)
    lo, hi = bunny_bounds(center, height, R)
    pad = 0.05 * height
    P = sample_box(lo - pad, hi + pad, 50_000)
    d = bunny_sdf(to_canonical(P, center, height, R))
    inside = bunny_inside(P, center, height, R)
    assert 0.05 < inside.mean() < 0.6
    clear = np.abs(d) > 1e-9  # exactly-on-surface points may round either way
    assert np.array_equal(inside[clear], d[clear] < 0.0)


def test_sdf_is_distance_like():
    """Near the surface |sdf| bounds the distance to the other side (sign flips within |d|)."""
    P = grid_points([-0.5, 0.0, -0.35], [0.5, 1.0, 0.35], 0.02)
    d = bunny_sdf(P)
    near = np.abs(d) < 0.02
    assert near.sum() > 1000
    # step along the finite-difference gradient by -d: the sign must change or vanish
    Q = P[near]
    e = 1e-5
    grad = np.stack([(bunny_sdf(Q + e * u) - bunny_sdf(Q - e * u)) / (2 * e) for u in I3], axis=1)
    n = grad / np.linalg.norm(grad, axis=1)[:, None]
    dq = d[near]
    moved = bunny_sdf(Q - 1.6 * dq[:, None] * n)
    assert np.mean(np.sign(moved) != np.sign(dq)) > 0.95
    gn = np.linalg.norm(grad, axis=1)
    assert np.mean(gn > 0.3) > 0.99 and gn.max() < 1.5  # low only in the blended creases


def test_bad_arguments():
    with pytest.raises(InputError):
        bunny_inside(np.zeros((1, 3)), (0, 0, 0), -1.0, I3)
    with pytest.raises(InputError):
        bunny_bounds((0, 0, 0), 1.0, 2.0 * I3)
    with pytest.raises(InputError):
        bunny_volume(0.0)
    with pytest.raises(InputError):
        bunny_surface((0, 0, 0), 1.0, I3, edge=-0.1)


# ---------------------------------------------------------------------------- bounds
def test_bounds_identity():
    c = np.array([1.0, 2.0, -0.5])
    h = 0.8
    lo, hi = bunny_bounds(c, h, I3)
    assert hi[1] - lo[1] == pytest.approx(h, abs=0.02 * h)
    assert lo[1] == pytest.approx(c[1] - h / 2, abs=0.02 * h)
    assert hi[1] == pytest.approx(c[1] + h / 2, abs=0.02 * h)
    assert 0.5 * (lo + hi) == pytest.approx(c, abs=0.02 * h)


@pytest.mark.parametrize("R", [I3, R_TILT, rotation_matrix((0.0, 45.0, 0.0))])
def test_bounds_contain_and_are_tight(R):
    lo, hi = bunny_bounds(CENTER, HEIGHT, R)
    pad = 0.1 * HEIGHT
    P = grid_points(lo - pad, hi + pad, 0.008 * HEIGHT)
    X = P[bunny_inside(P, CENTER, HEIGHT, R)]
    assert np.all(X >= lo) and np.all(X <= hi)
    assert np.all(X.min(axis=0) - lo < 0.02 * HEIGHT)
    assert np.all(hi - X.max(axis=0) < 0.02 * HEIGHT)


def test_canonical_frame():
    """Height 1, sitting on y = 0, centred in x and z; bunny_sdf sees the same body."""
    lo, hi = bunny_bounds(CANONICAL_CENTER, 1.0, I3)
    assert lo == pytest.approx([lo[0], 0.0, lo[2]], abs=2e-3)
    assert hi[1] == pytest.approx(1.0, abs=2e-3)
    assert lo[0] == pytest.approx(-hi[0], abs=2e-3) and lo[2] == pytest.approx(-hi[2], abs=2e-3)
    P = grid_points([-0.5, -0.05, -0.4], [0.5, 1.05, 0.4], 0.01)
    X = P[bunny_sdf(P) < 0.0]
    assert X.min(axis=0) == pytest.approx(lo, abs=0.011)
    assert X.max(axis=0) == pytest.approx(hi, abs=0.011)


# ---------------------------------------------------------------------------- volume
def test_volume_matches_mesh_and_monte_carlo():
    h = HEIGHT
    v = bunny_volume(h)
    assert v == pytest.approx(bunny_volume(1.0) * h**3, rel=1e-12)
    surf = bunny_surface(CENTER, h, R_TILT, edge=h / 60)
    assert M.mesh_volume(surf) == pytest.approx(v, rel=0.02)
    lo, hi = bunny_bounds(CENTER, h, R_TILT)
    n = 400_000
    frac = bunny_inside(sample_box(lo, hi, n), CENTER, h, R_TILT).mean()
    mc = frac * np.prod(hi - lo)
    assert mc == pytest.approx(v, rel=0.03)


# ---------------------------------------------------------------------------- surface
@pytest.mark.parametrize("R", [I3, R_TILT, rotation_matrix((90.0, 0.0, 0.0)), rotation_matrix((13.0, 71.0, 29.0))])
def test_surface_single_closed_at_coarse_edge(R):
    h = 0.5
    surf = bunny_surface((0.1, 0.2, 0.3), h, R, edge=h / 20)
    V, T, _ = M.validate_surface(surf.vertices, surf.triangles, "bunny")  # raises if broken
    assert T.shape == surf.triangles.shape
    assert components(surf) == 1
    assert M.mesh_volume(surf) > 0.0
    assert M.mesh_volume(surf) == pytest.approx(bunny_volume(h), rel=0.06)


def test_surface_edges_and_inside_agree():
    h, edge = HEIGHT, HEIGHT / 40
    surf = bunny_surface(CENTER, h, R_TILT, edge=edge)
    assert components(surf) == 1
    assert all("zero-area" in r for r in surf.repairs)  # nothing flipped, welded or dropped
    T = surf.triangles
    L = np.linalg.norm(surf.vertices[T] - surf.vertices[np.roll(T, 1, axis=1)], axis=2)
    assert 0.3 * edge < np.median(L) < 1.2 * edge and L.max() < 1.8 * edge
    lo, hi = bunny_bounds(CENTER, h, R_TILT)
    P = sample_box(lo, hi, 20_000)
    agree = B.inside_mesh(surf, P) == bunny_inside(P, CENTER, h, R_TILT)
    assert agree.mean() > 0.98
    # outward orientation: vertices moved along their face normals leave the body
    a, b, c = (surf.vertices[T[:, k]] for k in range(3))
    nrm = np.cross(b - a, c - a)
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    cen = (a + b + c) / 3.0
    assert bunny_inside(cen - 0.01 * h * nrm, CENTER, h, R_TILT).mean() > 0.97
    assert bunny_inside(cen + 0.01 * h * nrm, CENTER, h, R_TILT).mean() < 0.03


# ---------------------------------------------------------------------------- shape
def clusters(values, spacing):
    """Number of separate clusters of grid coordinates (gaps wider than 1.5 grid steps)."""
    v = np.unique(values)
    return int(np.sum(np.diff(v) > 1.5 * spacing) + 1) if v.size else 0


def test_ears_are_the_top_and_body_is_bottom_heavy():
    h = 0.008
    P = grid_points([-0.5, 0.0, -0.4], [0.5, 1.0, 0.4], h)
    X = P[bunny_sdf(P) < 0.0]
    top = X[X[:, 1] > 0.9]
    assert top.shape[0] > 100
    # two separate clusters in z: the ears, one on each side, a gap between them
    assert clusters(top[:, 2], h) == 2
    assert (top[:, 2] > 0).any() and (top[:, 2] < 0).any() and np.abs(top[:, 2]).min() > 0.03
    # the ears lean backwards: their tips are behind the head
    head = X[(X[:, 1] > 0.5) & (X[:, 1] < 0.7)]
    assert top[:, 0].mean() < head[:, 0].max()
    # widest horizontal section (area and z width) lies in the lower half
    ys = np.unique(X[:, 1])
    area = np.array([np.sum(X[:, 1] == y) for y in ys])
    width = np.array([np.ptp(X[X[:, 1] == y, 2]) for y in ys])
    assert ys[np.argmax(area)] < 0.5 and ys[np.argmax(width)] < 0.5
    # faces +x: the head (upper body) sits in front of the tail (lower rear)
    assert head[:, 0].mean() > 0.05 and X[X[:, 1] < 0.4, 0].min() < -0.3


def test_rotation_about_y_turns_facing_to_minus_z():
    c, h = np.array([0.5, 0.5, 0.5]), 1.0
    R = rotation_matrix((0.0, 90.0, 0.0))
    assert R @ np.array([1.0, 0.0, 0.0]) == pytest.approx([0.0, 0.0, -1.0], abs=1e-12)

    def upper_offsets(R):
        lo, hi = bunny_bounds(c, h, R)
        P = grid_points(lo, hi, 0.01)
        X = P[bunny_inside(P, c, h, R)]
        up = X[X[:, 1] > c[1] + 0.1 * h]  # head and ears
        top = X[X[:, 1] > c[1] + 0.4 * h]  # ears only
        return up.mean(axis=0) - c, top, lo, hi

    d0, top0, lo0, hi0 = upper_offsets(I3)
    d1, top1, lo1, hi1 = upper_offsets(R)
    assert d0[0] > 0.05 and abs(d0[2]) < 0.01  # head forward along +x
    assert d1[2] < -0.05 and abs(d1[0]) < 0.01  # ... now along -z
    assert d1[2] == pytest.approx(-d0[0], abs=0.01)
    # the ears now stand side by side along x instead of z
    assert clusters(top0[:, 2], 0.01) == 2 and clusters(top0[:, 0], 0.01) == 1
    assert clusters(top1[:, 0], 0.01) == 2 and clusters(top1[:, 2], 0.01) == 1
    # the extents swap: x extent <-> z extent
    assert (hi1 - lo1)[[2, 1, 0]] == pytest.approx(hi0 - lo0, abs=0.01)
    # the surface follows the same placement
    surf = bunny_surface(c, h, R, edge=h / 30)
    V = surf.vertices
    up = V[V[:, 1] > c[1] + 0.1 * h]
    assert up[:, 2].mean() - c[2] < -0.03 and abs(up[:, 0].mean() - c[0]) < 0.02
