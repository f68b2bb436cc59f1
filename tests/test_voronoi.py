"""Voronoi geometry: clipped cells tile the convex shape, bonds are shared faces, polyhedra are outward."""

import math

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, Delaunay, HalfspaceIntersection, cKDTree

from pdmpm_cli.errors import InputError
from pdmpm_cli.geometry import voronoi as VO


# ---------------------------------------------------------------------------- helpers
def rotation(ax, ay, az):
    """R = Rz @ Ry @ Rx, angles in degrees."""
    a, b, c = np.radians([ax, ay, az])
    Rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    Ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    Rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def fibonacci_sphere(n, radius, center=(0.0, 0.0, 0.0)):
    i = np.arange(n) + 0.5
    phi = np.arccos(1.0 - 2.0 * i / n)
    theta = np.pi * (1.0 + 5.0**0.5) * i
    pts = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)
    return radius * pts + np.asarray(center)


def polytope_hull(planes):
    """Independent check: scipy's own half-space intersection from a strictly interior point."""
    planes = np.asarray(planes, float)
    return ConvexHull(HalfspaceIntersection(planes, _interior(planes)).intersections)


def _interior(planes):
    """Chebyshev centre by LP."""
    k = planes.shape[0]
    res = linprog([0, 0, 0, -1], A_ub=np.hstack([planes[:, :3], np.ones((k, 1))]), b_ub=-planes[:, 3],
                  bounds=[(None, None)] * 3 + [(0, None)])
    return res.x[:3]


def max_violation(points, planes):
    """max over points and planes of n.x + d (> 0: outside), in chunks to bound memory."""
    return max(float(np.max(points[a:a + 1000] @ planes[:, :3].T + planes[:, 3]))
               for a in range(0, points.shape[0], 1000))


def triangle_geometry(cells):
    V, T = cells.poly_vertices, cells.poly_triangles
    a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    cr = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cr, axis=1)
    return a, b, c, cr, area


BOX = dict(center=[0.05, -0.02, 0.3], size=[0.3, 0.2, 0.1], R=rotation(20, -35, 50))


@pytest.fixture(scope="module")
def box_cells():
    planes = VO.box_planes(BOX["center"], BOX["size"], BOX["R"])
    return planes, VO.voronoi_cells(planes, 0.02, None, np.random.default_rng(7), what="test box")


@pytest.fixture(scope="module")
def sphere_cells():
    planes = VO.polytope_from_points(fibonacci_sphere(2000, 0.1, center=(0.2, 0.1, -0.1)))
    return planes, VO.voronoi_cells(planes, 0.02, None, np.random.default_rng(3), what="test sphere")


ALL = ["box_cells", "sphere_cells"]


# ---------------------------------------------------------------------------- polytopes
def test_box_planes_volume_and_orientation():
    c, s, R = BOX["center"], BOX["size"], BOX["R"]
    planes = VO.box_planes(c, s, R)
    assert planes.shape == (6, 4)
    np.testing.assert_allclose(np.linalg.norm(planes[:, :3], axis=1), 1.0, rtol=1e-14)
    assert VO.polytope_volume(planes) == pytest.approx(0.3 * 0.2 * 0.1, rel=1e-12)
    # box corners are on the boundary, the centre is inside by half the smallest edge
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * 0.5 * np.array(s)
    world = np.asarray(c) + corners @ np.asarray(R).T
    assert np.max(world @ planes[:, :3].T + planes[:, 3]) == pytest.approx(0.0, abs=1e-15)
    assert np.max(planes[:, :3] @ np.asarray(c) + planes[:, 3]) == pytest.approx(-0.05, rel=1e-12)


def test_polytope_from_points_merges_coplanar_facets():
    # a cube sampled with many points per face: qhull triangulates each face into many facets
    g = np.linspace(-0.5, 0.5, 5)
    pts = np.array([[x, y, z] for x in g for y in g for z in g])
    planes = VO.polytope_from_points(pts * 0.2 + [1.0, 2.0, 3.0])
    assert planes.shape == (6, 4)
    np.testing.assert_allclose(np.sort(np.abs(planes[:, :3]).sum(axis=1)), 1.0, rtol=1e-12)
    assert VO.polytope_volume(planes) == pytest.approx(0.2**3, rel=1e-12)


def test_polytope_volume_matches_scipy_and_sphere():
    planes = VO.polytope_from_points(fibonacci_sphere(2000, 0.1))
    hull = polytope_hull(planes)
    vol = VO.polytope_volume(planes)
    assert vol == pytest.approx(hull.volume, rel=1e-12)
    assert vol == pytest.approx(4.0 / 3.0 * math.pi * 0.1**3, rel=0.01)


@pytest.mark.parametrize("planes, msg", [
    (np.array([[1, 0, 0, -1], [-1, 0, 0, 0], [0, 1, 0, -1], [0, -1, 0, 0.0]]), "bounded"),  # open along z
    (np.array([[1, 0, 0, 1], [-1, 0, 0, 1], [0, 1, 0, -1], [0, -1, 0, 0], [0, 0, 1, -1], [0, 0, -1, 0.0]]),
     "no common interior"),  # x <= -1 and x >= 1
    (np.zeros((6, 4)), "zero normal"),
    (np.ones((3, 4)), "at least 4"),
])
def test_bad_polytopes_raise_input_error(planes, msg):
    with pytest.raises(InputError, match=msg):
        VO.polytope_volume(planes)


def test_flat_points_raise_input_error():
    pts = np.random.default_rng(0).random((50, 3))
    pts[:, 2] = 0.0
    with pytest.raises(InputError, match="flat"):
        VO.polytope_from_points(pts)


# ---------------------------------------------------------------------------- cells
def test_box_cells_tile_the_box(box_cells):
    planes, cells = box_cells
    V = 0.3 * 0.2 * 0.1
    n = cells.seeds.shape[0]
    assert abs(n - V / 0.02**3) < 0.15 * V / 0.02**3
    assert cells.volumes.sum() == pytest.approx(V, rel=1e-9)
    assert np.all(cells.volumes > 0.0)
    # cells are about h^3
    assert np.mean(cells.volumes) == pytest.approx(V / n, rel=1e-12)
    assert np.median(cells.volumes) == pytest.approx(0.02**3, rel=0.3)
    # centroids inside the box, seeds strictly inside
    assert max_violation(cells.centroids, planes) < 0.0
    assert max_violation(cells.seeds, planes) < 0.0
    # every polyhedron vertex is inside (or on) the box
    assert max_violation(cells.poly_vertices, planes) < 1e-12


def test_sphere_cells_tile_the_polytope(sphere_cells):
    planes, cells = sphere_cells
    vol = VO.polytope_volume(planes)
    assert cells.volumes.sum() == pytest.approx(vol, rel=1e-9)
    assert cells.volumes.sum() == pytest.approx(4.0 / 3.0 * math.pi * 0.1**3, rel=0.01)
    assert np.all(cells.volumes > 0.0)
    assert max_violation(cells.poly_vertices, planes) < 1e-12
    assert max_violation(cells.centroids, planes) < 0.0


@pytest.mark.parametrize("fixture", ALL)
def test_centroid_and_volume_match_independent_hulls(fixture, request):
    _, cells = request.getfixturevalue(fixture)
    for i in np.linspace(0, cells.seeds.shape[0] - 1, 25).astype(int):
        hull = ConvexHull(cells.poly_vertices[cells.vertex_cell == i])
        assert cells.volumes[i] == pytest.approx(hull.volume, rel=1e-9)
        # centroid of a solid polyhedron, by tetrahedra from an inside point
        p = hull.points[hull.vertices].mean(axis=0)
        t = hull.points[hull.simplices]
        v = np.abs(np.einsum("ij,ij->i", t[:, 0] - p, np.cross(t[:, 1] - p, t[:, 2] - p))) / 6.0
        c = (v[:, None] * (t.sum(axis=1) + p) / 4.0).sum(axis=0) / v.sum()
        np.testing.assert_allclose(cells.centroids[i], c, atol=1e-12)


@pytest.mark.parametrize("fixture", ALL)
def test_triangles_are_outward(fixture, request):
    _, cells = request.getfixturevalue(fixture)
    a, b, c, _, _ = triangle_geometry(cells)
    p = cells.centroids[cells.poly_cell]
    signed = np.einsum("ij,ij->i", a - p, np.cross(b - p, c - p)) / 6.0
    vol = np.bincount(cells.poly_cell, signed, minlength=cells.seeds.shape[0])
    np.testing.assert_allclose(vol, cells.volumes, rtol=1e-9)
    # and each triangle faces away from its cell's centroid (convex cells)
    n = np.cross(b - a, c - a)
    assert np.all(np.einsum("ij,ij->i", n, (a + b + c) / 3.0 - p) >= -1e-18)


@pytest.mark.parametrize("fixture", ALL)
def test_vertices_belong_to_one_cell(fixture, request):
    _, cells = request.getfixturevalue(fixture)
    T = cells.poly_triangles
    nv = cells.poly_vertices.shape[0]
    assert T.dtype == np.int64 and cells.poly_cell.dtype == np.int64 and cells.vertex_cell.dtype == np.int64
    assert T.min() >= 0 and T.max() < nv
    np.testing.assert_array_equal(cells.vertex_cell[T], np.repeat(cells.poly_cell[:, None], 3, axis=1))
    assert np.unique(T).shape[0] == nv  # no unused vertices
    assert np.all((T[:, 0] != T[:, 1]) & (T[:, 1] != T[:, 2]) & (T[:, 2] != T[:, 0]))
    # closed, consistently oriented surfaces: each directed edge is matched by its reverse
    e = np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])
    fwd = np.unique(e[:, 0] * nv + e[:, 1], return_counts=True)
    rev = np.unique(e[:, 1] * nv + e[:, 0], return_counts=True)
    np.testing.assert_array_equal(fwd[0], rev[0])
    np.testing.assert_array_equal(fwd[1], rev[1])


def _per_side_face_areas(cells):
    """Area of each cell's faces towards each neighbour, found independently: a triangle on the bisector
    of seeds i and j mirrors s_i onto s_j across its plane."""
    a, b, c, cr, area = triangle_geometry(cells)
    nrm = cr / np.maximum(np.linalg.norm(cr, axis=1), 1e-300)[:, None]
    s = cells.seeds[cells.poly_cell]
    mirror = s + 2.0 * np.einsum("ij,ij->i", (a + b + c) / 3.0 - s, nrm)[:, None] * nrm
    dist, j = cKDTree(cells.seeds).query(mirror)
    size = np.mean(cells.volumes) ** (1 / 3)
    inner = (dist < 1e-6 * size) & (area > 0.0)
    out = {}
    for i, jj, ar in zip(cells.poly_cell[inner], j[inner], area[inner]):
        out[(int(i), int(jj))] = out.get((int(i), int(jj)), 0.0) + ar
    return out, area[~inner].sum()


@pytest.mark.parametrize("fixture", ALL)
def test_pairs_are_delaunay_neighbours_with_equal_face_areas(fixture, request):
    _, cells = request.getfixturevalue(fixture)
    P = cells.pairs
    assert P.dtype == np.int64 and P.shape[1] == 2 and P.shape[0] == cells.face_area.shape[0]
    assert np.all(P[:, 0] < P[:, 1])
    assert np.all(np.diff(P[:, 0] * cells.seeds.shape[0] + P[:, 1]) > 0)  # sorted, unique
    indptr, indices = Delaunay(cells.seeds).vertex_neighbor_vertices
    for i, j in P:
        assert j in indices[indptr[i]:indptr[i + 1]]
    # about 7 face neighbours per cell inside, fewer at the boundary
    assert 4.0 < 2 * P.shape[0] / cells.seeds.shape[0] < 16.0
    sides, _ = _per_side_face_areas(cells)
    size = np.mean(cells.volumes) ** (1 / 3)
    for (i, j), fa in zip(P, cells.face_area):
        np.testing.assert_allclose(sides[(i, j)], sides[(j, i)], rtol=1e-9)
        np.testing.assert_allclose(fa, sides[(i, j)], rtol=1e-9)
    # faces left out are the ones below the threshold
    paired = set(map(tuple, P.tolist()))
    for (i, j), ar in sides.items():
        if (min(i, j), max(i, j)) not in paired:
            assert ar <= 1e-6 * size**2 * (1 + 1e-9)


@pytest.mark.parametrize("fixture", ALL)
def test_surface_area_is_twice_shared_faces_plus_boundary(fixture, request):
    planes, cells = request.getfixturevalue(fixture)
    _, _, _, _, area = triangle_geometry(cells)
    boundary = polytope_hull(planes).area
    assert area.sum() == pytest.approx(2.0 * cells.face_area.sum() + boundary, rel=1e-6)
    _, outer = _per_side_face_areas(cells)
    assert outer == pytest.approx(boundary, rel=1e-6)


def test_count_mode_is_reproducible_and_uniform():
    planes = VO.box_planes([0, 0, 0], [0.1, 0.1, 0.1], np.eye(3))
    c1 = VO.voronoi_cells(planes, None, 300, np.random.default_rng(11))
    c2 = VO.voronoi_cells(planes, None, 300, np.random.default_rng(11))
    c3 = VO.voronoi_cells(planes, None, 300, np.random.default_rng(12))
    assert c1.seeds.shape == (300, 3)
    for f in ("seeds", "centroids", "volumes", "pairs", "face_area", "poly_vertices", "poly_triangles",
              "poly_cell", "vertex_cell"):
        np.testing.assert_array_equal(getattr(c1, f), getattr(c2, f))
    assert not np.allclose(c1.seeds, c3.seeds)
    assert c1.volumes.sum() == pytest.approx(1e-3, rel=1e-9)
    assert c3.volumes.sum() == pytest.approx(1e-3, rel=1e-9)
    # random (Poisson) seeds: cell volumes vary far more than on the jittered lattice
    cv = np.std(c1.volumes) / np.mean(c1.volumes)
    assert 0.25 < cv < 0.8


def test_spacing_mode_is_reproducible():
    planes = VO.box_planes([0, 0, 0], [0.1, 0.06, 0.04], rotation(10, 20, 30))
    c1 = VO.voronoi_cells(planes, 0.01, None, np.random.default_rng(5))
    c2 = VO.voronoi_cells(planes, 0.01, None, np.random.default_rng(5))
    np.testing.assert_array_equal(c1.seeds, c2.seeds)
    np.testing.assert_array_equal(c1.poly_vertices, c2.poly_vertices)
    np.testing.assert_array_equal(c1.pairs, c2.pairs)


def test_seeds_hugging_the_boundary_use_the_fallback(monkeypatch):
    """Every boundary cell through the Chebyshev-centre path: the same cells, the same tiling."""
    planes = VO.polytope_from_points(fibonacci_sphere(400, 0.05))
    ref = VO.voronoi_cells(planes, None, 150, np.random.default_rng(2))
    monkeypatch.setattr(VO, "INTERIOR_RATIO", 1e9)
    alt = VO.voronoi_cells(planes, None, 150, np.random.default_rng(2))
    np.testing.assert_array_equal(ref.seeds, alt.seeds)
    np.testing.assert_allclose(alt.volumes, ref.volumes, rtol=1e-9)
    np.testing.assert_allclose(alt.centroids, ref.centroids, atol=1e-12)
    np.testing.assert_array_equal(alt.pairs, ref.pairs)
    assert alt.volumes.sum() == pytest.approx(VO.polytope_volume(planes), rel=1e-9)


def test_few_cells_and_a_thin_slab():
    # 2 cells: the box split by one bisector
    planes = VO.box_planes([0, 0, 0], [0.2, 0.1, 0.1], np.eye(3))
    cells = VO.voronoi_cells(planes, None, 2, np.random.default_rng(0))
    assert cells.volumes.sum() == pytest.approx(0.002, rel=1e-12)
    np.testing.assert_array_equal(cells.pairs, [[0, 1]])
    # a slab one spacing thick: a single layer of cells, each spanning it
    planes = VO.box_planes([0, 0, 0], [0.2, 0.2, 0.01], rotation(0, 30, 0))
    cells = VO.voronoi_cells(planes, 0.01, None, np.random.default_rng(1))
    assert cells.volumes.sum() == pytest.approx(0.2 * 0.2 * 0.01, rel=1e-9)


def test_errors():
    planes = VO.box_planes([0, 0, 0], [0.01, 0.01, 0.01], np.eye(3))
    rng = np.random.default_rng(0)
    with pytest.raises(InputError, match="tiny cube.*spacing"):
        VO.voronoi_cells(planes, 0.1, None, rng, what="tiny cube")
    with pytest.raises(ValueError):
        VO.voronoi_cells(planes, 0.001, 10, rng)
    with pytest.raises(ValueError):
        VO.voronoi_cells(planes, None, None, rng)
    with pytest.raises(InputError, match="limit"):
        VO.voronoi_cells(planes, 1e-5, None, rng)
    with pytest.raises(InputError, match="limit"):
        VO.voronoi_cells(planes, None, VO.MAX_SEEDS + 1, rng)
    for bad in (0.0, -0.01, float("nan"), "x"):
        with pytest.raises(InputError, match="spacing"):
            VO.voronoi_cells(planes, bad, None, rng)
    for bad in (1, 2.5, True):
        with pytest.raises(InputError, match="count"):
            VO.voronoi_cells(planes, None, bad, rng)
    with pytest.raises(InputError, match="size"):
        VO.box_planes([0, 0, 0], [0.1, 0.0, 0.1], np.eye(3))
    with pytest.raises(InputError, match="rotation"):
        VO.box_planes([0, 0, 0], [0.1, 0.1, 0.1], 2 * np.eye(3))
