"""Geometry layer: primitive shapes, surface meshes (loading, validation, winding number), sampling."""

import math
import time
from pathlib import Path

import meshio
import numpy as np
import pytest
from scipy.spatial import cKDTree

from pdmpm_cli.errors import InputError
from pdmpm_cli.geometry import bvh as B
from pdmpm_cli.geometry import mesh as M
from pdmpm_cli.geometry import sampling as S
from pdmpm_cli.geometry import shapes as G
from tests.mesh_corpus import icosphere, torus

DATA = Path(__file__).parent / "data"
CUBE_OBJ = DATA / "unit_cube.obj"


# ---------------------------------------------------------------------------- helpers
def cube_tris(lo=0.0, hi=1.0):
    """Outward triangulated cube [lo, hi]^3: 8 vertices, 12 triangles."""
    V = np.array([[x, y, z] for z in (lo, hi) for y in (lo, hi) for x in (lo, hi)], float)
    # vertex index = x + 2y + 4z
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (3, 2, 6, 7), (0, 4, 6, 2), (1, 3, 7, 5)]
    T = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64)
    return V, T


def write(path, V, T):
    meshio.write(str(path), meshio.Mesh(np.asarray(V, float), [("triangle", np.asarray(T))]))
    return path


def polyhedron_volume(V, T):
    a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


RNG = np.random.default_rng(12345)
ROTS = [None, G.rotation_matrix((30.0, -50.0, 20.0)), G.rotation_matrix((90.0, 0.0, 45.0))]


# ---------------------------------------------------------------------------- rotations
def test_rotation_matrix_order_and_orthonormality():
    Rz = G.rotation_matrix((0, 0, 90))
    assert np.allclose(Rz @ [1, 0, 0], [0, 1, 0])
    # x first, then y: Rx(90) sends y -> z, then Ry(90) sends z -> x
    assert np.allclose(G.rotation_matrix((90, 90, 0)) @ [0, 1, 0], [1, 0, 0])
    R = G.rotation_matrix((12.0, 34.0, 56.0))
    assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    with pytest.raises(InputError, match="rotation"):
        G.box_inside(np.zeros((1, 3)), [0, 0, 0], [1, 1, 1], R=2 * np.eye(3))
    with pytest.raises(InputError, match="radius"):
        G.sphere_inside(np.zeros((1, 3)), [0, 0, 0], -1.0)
    with pytest.raises(InputError, match="size"):
        G.box_bounds([0, 0, 0], [1, 0, 1])


# ---------------------------------------------------------------------------- inside tests
@pytest.mark.parametrize("R", ROTS)
def test_box_inside_matches_projection(R):
    c, size = np.array([0.3, -0.2, 1.0]), np.array([1.0, 0.4, 0.7])
    p = c + RNG.uniform(-0.8, 0.8, (20000, 3))
    Rm = np.eye(3) if R is None else R
    expect = np.all(np.abs((p - c) @ Rm) <= size / 2, axis=1)
    # independent formulation: projections onto the rotated axes (columns of R)
    expect2 = np.all([np.abs((p - c) @ Rm[:, k]) <= size[k] / 2 for k in range(3)], axis=0)
    got = G.box_inside(p, c, size, R)
    assert got.dtype == bool and np.array_equal(got, expect) and np.array_equal(got, expect2)
    assert 0 < got.sum() < p.shape[0]


def test_box_rotated_specific_points():
    R = G.rotation_matrix((0, 0, 90))  # long local x axis now along world y
    assert G.box_inside([[0, 0.9, 0], [0.9, 0, 0]], [0, 0, 0], [2.0, 0.2, 0.2], R).tolist() == [True, False]


def test_sphere_inside():
    c = np.array([1.0, 2.0, 3.0])
    p = c + RNG.uniform(-1, 1, (10000, 3))
    assert np.array_equal(G.sphere_inside(p, c, 0.6), np.linalg.norm(p - c, axis=1) <= 0.6)


@pytest.mark.parametrize("R", ROTS)
def test_cylinder_inside(R):
    c, r, h = np.array([0.0, 1.0, -1.0]), 0.3, 1.2
    p = c + RNG.uniform(-0.8, 0.8, (20000, 3))
    a = np.array([0, 0, 1.0]) if R is None else R[:, 2]
    d = p - c
    along = d @ a
    radial = np.linalg.norm(d - along[:, None] * a, axis=1)
    assert np.array_equal(G.cylinder_inside(p, c, r, h, R), (np.abs(along) <= h / 2) & (radial <= r))


def test_cylinder_rotated_axis():
    R = G.rotation_matrix((0, 90, 0))  # local z -> world x
    assert G.cylinder_inside([[0.5, 0, 0], [0, 0, 0.5]], [0, 0, 0], 0.1, 1.2, R).tolist() == [True, False]


@pytest.mark.parametrize("R", ROTS)
def test_capsule_inside(R):
    c, r, L = np.array([0.5, 0.5, 0.5]), 0.25, 0.8
    p = c + RNG.uniform(-0.8, 0.8, (20000, 3))
    a = np.array([0, 0, 1.0]) if R is None else R[:, 2]
    e0, e1 = c - 0.5 * L * a, c + 0.5 * L * a
    s = np.clip((p - e0) @ (e1 - e0) / L**2, 0, 1)
    dist = np.linalg.norm(p - (e0 + s[:, None] * (e1 - e0)), axis=1)
    assert np.array_equal(G.capsule_inside(p, c, r, L, R), dist <= r)
    tip = c + (0.5 * L + 0.9 * r) * a
    assert G.capsule_inside(tip[None], c, r, L, R)[0]
    assert not G.capsule_inside((c + (0.5 * L + 1.1 * r) * a)[None], c, r, L, R)[0]


# ---------------------------------------------------------------------------- bounds & volumes
def _cases():
    c = np.array([0.1, -0.3, 0.2])
    out = []
    for R in ROTS:
        out.append(("box", lambda p, R=R: G.box_inside(p, c, [0.6, 0.3, 0.45], R),
                    G.box_bounds(c, [0.6, 0.3, 0.45], R), G.box_volume([0.6, 0.3, 0.45])))
        out.append(("cylinder", lambda p, R=R: G.cylinder_inside(p, c, 0.2, 0.7, R),
                    G.cylinder_bounds(c, 0.2, 0.7, R), G.cylinder_volume(0.2, 0.7)))
        out.append(("capsule", lambda p, R=R: G.capsule_inside(p, c, 0.15, 0.5, R),
                    G.capsule_bounds(c, 0.15, 0.5, R), G.capsule_volume(0.15, 0.5)))
    out.append(("sphere", lambda p: G.sphere_inside(p, c, 0.35), G.sphere_bounds(c, 0.35), G.sphere_volume(0.35)))
    return out


@pytest.mark.parametrize("case", _cases(), ids=lambda c: c[0])
@pytest.mark.parametrize("sampling", ["lattice", "jittered", "relaxed"])
def test_filled_volume_and_tight_bounds(case, sampling):
    name, inside, (lo, hi), vol = case
    h = 0.02 if sampling == "relaxed" else 0.012  # relaxation costs most: 10k points rather than 47k per shape
    pts = S.fill_shape(inside, lo, hi, h, sampling=sampling, rng=np.random.default_rng(7))
    assert inside(pts).all()
    assert abs(pts.shape[0] * h**3 / vol - 1.0) < 0.03
    # bounds contain the shape and are tight (the extreme points reach within ~h of them)
    assert np.all(pts.min(axis=0) >= lo) and np.all(pts.max(axis=0) <= hi)
    assert np.all(pts.min(axis=0) - lo < 3 * h) and np.all(hi - pts.max(axis=0) < 3 * h)
    # nothing outside the bounds is inside the shape
    probe = RNG.uniform(lo - 0.3, hi + 0.3, (50000, 3))
    outside = np.any((probe < lo) | (probe > hi), axis=1)
    assert not inside(probe[outside]).any()


@pytest.mark.parametrize("R", ROTS)
def test_bounds_exact(R):
    c = np.array([0.1, -0.3, 0.2])
    Rm = np.eye(3) if R is None else R
    corners = c + (np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * [0.3, 0.15, 0.2]) @ Rm.T
    lo, hi = G.box_bounds(c, [0.6, 0.3, 0.4], R)
    assert np.allclose(lo, corners.min(0)) and np.allclose(hi, corners.max(0))
    phi = np.linspace(0, 2 * np.pi, 20001)
    ring = np.stack([np.cos(phi), np.sin(phi), 0 * phi], 1) * 0.2
    rims = np.vstack([c + (ring + [0, 0, z]) @ Rm.T for z in (-0.35, 0.35)])
    lo, hi = G.cylinder_bounds(c, 0.2, 0.7, R)
    assert np.allclose(lo, rims.min(0), atol=1e-8) and np.allclose(hi, rims.max(0), atol=1e-8)
    ends = np.array([c + Rm @ [0, 0, z] for z in (-0.25, 0.25)])
    lo, hi = G.capsule_bounds(c, 0.15, 0.5, R)
    assert np.allclose(lo, ends.min(0) - 0.15) and np.allclose(hi, ends.max(0) + 0.15)


def test_volumes_analytic():
    assert math.isclose(G.box_volume([1, 2, 3]), 6.0)
    assert math.isclose(G.sphere_volume(1.0), 4 / 3 * math.pi)
    assert math.isclose(G.cylinder_volume(1.0, 2.0), 2 * math.pi)
    assert math.isclose(G.capsule_volume(1.0, 2.0), 2 * math.pi + 4 / 3 * math.pi)
    assert math.isclose(G.capsule_volume(1.0, 0.0), G.sphere_volume(1.0))


# ---------------------------------------------------------------------------- sampling
def test_lattice_mode_exact_centres():
    lo, hi, h = np.array([-0.5, 0.0, 1.0]), np.array([0.5, 0.3, 1.2]), 0.1
    p = S.lattice_points(lo, hi, h, sampling="lattice", rng=np.random.default_rng(0))
    assert p.shape == (10 * 3 * 2, 3)  # extents that are multiples of h are not padded
    idx = (p - lo) / h - 0.5
    assert np.allclose(idx, np.round(idx), atol=1e-9)
    assert len({tuple(x) for x in np.round(idx).astype(int)}) == p.shape[0]
    # extent not a multiple of h: cells cover the box
    q = S.lattice_points([0, 0, 0], [0.25, 0.1, 0.1], 0.1, sampling="lattice", rng=None)
    assert q.shape[0] == 3 and np.isclose(q[:, 0].max(), 0.25)


def test_jittered_one_per_cell_min_separation_reproducible():
    lo, hi, h = np.zeros(3), np.array([1.0, 0.8, 0.6]), 0.025
    a = S.lattice_points(lo, hi, h, sampling="jittered", rng=np.random.default_rng(42))
    n = np.ceil((hi - lo) / h - 1e-9).astype(int)
    assert a.shape == (int(np.prod(n)), 3)
    cells = np.floor((a - lo) / h).astype(int)
    assert np.all(cells >= 0) and np.all(cells < n)
    assert np.unique(np.ravel_multi_index(cells.T, n)).size == a.shape[0]  # one per cell
    d, _ = cKDTree(a).query(a, k=2)
    assert d[:, 1].min() >= S.MIN_SEPARATION * h
    # not a lattice: offsets spread over the cell
    off = (a - lo) / h - cells
    assert off.std() > 0.2
    b = S.lattice_points(lo, hi, h, sampling="jittered", rng=np.random.default_rng(42))
    c = S.lattice_points(lo, hi, h, sampling="jittered", rng=np.random.default_rng(43))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_relaxed_points_are_evenly_spaced_and_reproducible():
    """Lloyd relaxation (the default cloud sampling) evens out the jitter's clumps and gaps: the spread of the
    nearest-neighbour distance falls from 0.143 h to 0.083 h (closest pair 0.50 -> 0.63 h), with the same count,
    reproducible from the seed."""
    lo, hi, h = np.zeros(3), np.array([0.3, 0.2, 0.2]), 0.02
    inside = lambda p: G.box_inside(p, (lo + hi) / 2, hi - lo, None)  # noqa: E731
    jit = S.fill_shape(inside, lo, hi, h, sampling="jittered", rng=np.random.default_rng(3))
    rel = S.fill_shape(inside, lo, hi, h, sampling="relaxed", rng=np.random.default_rng(3))
    nn = lambda x: cKDTree(x).query(x, 2)[0][:, 1] / h  # noqa: E731
    print(f"nearest neighbour / h: jittered {nn(jit).min():.2f} min, {nn(jit).std():.3f} std; relaxed "
          f"{nn(rel).min():.2f} min, {nn(rel).std():.3f} std")
    assert len(rel) == len(jit)
    assert nn(rel).min() > 0.6 and nn(rel).std() < 0.7 * nn(jit).std()
    again = S.fill_shape(inside, lo, hi, h, sampling="relaxed", rng=np.random.default_rng(3))
    assert np.array_equal(rel, again)


def test_sampling_errors():
    with pytest.raises(InputError, match="no particle falls inside.*use h <="):
        S.fill_shape(lambda p: G.sphere_inside(p, [0, 0, 0], 0.01), [-0.01] * 3, [0.01] * 3, 0.1,
                     sampling="lattice", rng=np.random.default_rng(0))
    with pytest.raises(InputError, match="unknown sampling"):
        S.lattice_points([0] * 3, [1] * 3, 0.1, sampling="random", rng=np.random.default_rng(0))
    with pytest.raises(InputError, match="spacing"):
        S.lattice_points([0] * 3, [1] * 3, -0.1, sampling="lattice", rng=None)
    with pytest.raises(InputError, match="larger spacing"):
        S.lattice_points([0] * 3, [10] * 3, 1e-3, sampling="lattice", rng=None)


# ---------------------------------------------------------------------------- mesh loading
def test_unit_cube_obj_quads():
    m = M.load_surface_mesh(CUBE_OBJ)
    assert m.vertices.shape == (8, 3) and m.triangles.shape == (12, 3)
    assert m.vertices.dtype == np.float64 and m.triangles.dtype == np.int64
    assert m.path == str(CUBE_OBJ.resolve()) and m.repairs == []
    assert math.isclose(M.mesh_volume(m), 1.0)
    lo, hi = M.mesh_bounds(m)
    assert np.allclose(lo, 0) and np.allclose(hi, 1)
    p = RNG.uniform(-0.5, 1.5, (20000, 3))
    away = np.all(np.abs(p - 0.5) < 0.49, axis=1) | np.any(np.abs(p - 0.5) > 0.51, axis=1)
    expect = np.all((p >= 0) & (p <= 1), axis=1)
    assert np.array_equal(B.inside_mesh(m, p[away]), expect[away])


def test_polygon_faces_are_fan_triangulated(tmp_path):
    # pentagonal prism: two pentagons (counter-clockwise seen from outside) and five quads
    ang = 2 * np.pi * np.arange(5) / 5
    ring = np.stack([np.cos(ang), np.sin(ang)], 1)
    lines = [f"v {x} {y} {z}" for z in (0.0, 1.0) for x, y in ring]
    lines += ["f 5 4 3 2 1", "f 6 7 8 9 10"]
    lines += [f"f {i + 1} {(i + 1) % 5 + 1} {(i + 1) % 5 + 6} {i + 6}" for i in range(5)]
    (tmp_path / "prism.obj").write_text("\n".join(lines) + "\n")
    m = M.load_surface_mesh(tmp_path / "prism.obj")
    assert m.triangles.shape == (2 * 3 + 5 * 2, 3)
    assert math.isclose(M.mesh_volume(m), 2.5 * np.sin(2 * np.pi / 5))  # pentagon area x 1


def test_mesh_placement_scale_rotate_translate():
    R = G.rotation_matrix((0, 0, 90))
    m = M.load_surface_mesh(CUBE_OBJ, scale=2.0, translate=(10.0, 0.0, 0.0), R=R)
    assert math.isclose(M.mesh_volume(m), 8.0)
    lo, hi = M.mesh_bounds(m)  # x = R (2 x_file) + t: x in [8, 10], y in [0, 2]
    assert np.allclose(lo, [8, 0, 0]) and np.allclose(hi, [10, 2, 2])
    assert B.inside_mesh(m, [[9.0, 1.0, 1.0], [11.0, 1.0, 1.0]]).tolist() == [True, False]
    m2 = M.load_surface_mesh(CUBE_OBJ, scale=(1.0, 2.0, 3.0))
    assert math.isclose(M.mesh_volume(m2), 6.0)
    with pytest.raises(InputError, match="scale"):
        M.load_surface_mesh(CUBE_OBJ, scale=-1.0)


@pytest.mark.parametrize("ext", ["obj", "stl", "ply", "off", "vtk"])
def test_icosphere_formats_inside_and_volume(tmp_path, ext):
    V, T = icosphere(3)  # 1280 triangles
    V = 0.5 * V + [1.0, 2.0, 3.0]
    m = M.load_surface_mesh(write(tmp_path / f"ball.{ext}", V, T))
    assert m.vertices.shape == (642, 3) and m.triangles.shape == (1280, 3)
    vol = M.mesh_volume(m)
    assert math.isclose(vol, polyhedron_volume(V, T), rel_tol=1e-9)
    assert abs(vol / G.sphere_volume(0.5) - 1) < 0.02
    p = [1.0, 2.0, 3.0] + RNG.uniform(-0.7, 0.7, (20000, 3))
    r = np.linalg.norm(p - [1.0, 2.0, 3.0], axis=1)
    away = np.abs(r - 0.5) > 0.01  # the polyhedron deviates < 0.003 from the sphere
    assert np.array_equal(B.inside_mesh(m, p[away]), r[away] < 0.5)
    # fill with jittered points: volume within 3 % of the mesh volume
    lo, hi = M.mesh_bounds(m)
    pts = S.fill_shape(lambda q: B.inside_mesh(m, q), lo, hi, 0.02, sampling="jittered",
                       rng=np.random.default_rng(3))
    assert abs(pts.shape[0] * 0.02**3 / vol - 1) < 0.03


@pytest.mark.parametrize("binary", [True, False])
def test_stl_triangle_soup_is_welded(tmp_path, binary):
    V, T = icosphere(2)
    soup = V[T].reshape(-1, 3)  # every triangle with its own three vertices
    path = tmp_path / "soup.stl"
    meshio.write(str(path), meshio.Mesh(soup, [("triangle", np.arange(soup.shape[0]).reshape(-1, 3))]),
                 binary=binary)
    m = M.load_surface_mesh(path)
    assert m.vertices.shape == (162, 3) and m.triangles.shape == (320, 3)
    assert math.isclose(M.mesh_volume(m), polyhedron_volume(V, T), rel_tol=1e-6)


def test_near_duplicate_vertices_welded(tmp_path):
    V, T = icosphere(2)
    soup = V[T].reshape(-1, 3) + RNG.uniform(-1e-12, 1e-12, (T.size, 3))
    m = M.load_surface_mesh(write(tmp_path / "soup.obj", soup, np.arange(T.size).reshape(-1, 3)))
    assert m.vertices.shape == (162, 3)
    assert any("merged 798 duplicate vertices" in r for r in m.repairs)


def test_inverted_cube_is_flipped(tmp_path):
    V, T = cube_tris()
    m = M.load_surface_mesh(write(tmp_path / "inv.obj", V, T[:, ::-1]))
    assert math.isclose(M.mesh_volume(m), 1.0)
    assert any("flipped" in r for r in m.repairs)
    assert B.inside_mesh(m, [[0.5, 0.5, 0.5], [1.5, 0.5, 0.5]]).tolist() == [True, False]


def test_cube_with_missing_face_not_closed(tmp_path):
    V, T = cube_tris()
    path = write(tmp_path / "open.obj", V, T[2:])  # remove one quad = two triangles
    with pytest.raises(InputError) as e:
        M.load_surface_mesh(path)
    msg = str(e.value)
    assert "not closed" in msg and "4 boundary edges" in msg and "Fill Holes" in msg
    assert str(path.resolve()) in msg and "(0, 0, 0)" in msg


def test_cube_with_flipped_triangle_orientation(tmp_path):
    V, T = cube_tris()
    T = T.copy()
    T[5] = T[5, ::-1]
    path = write(tmp_path / "flip1.obj", V, T)
    with pytest.raises(InputError, match=r"(?s)inconsistent orientation: at 3 edges.*Recalculate"):
        M.load_surface_mesh(path)


def test_non_manifold_and_degenerate(tmp_path):
    V, T = cube_tris()
    extra = np.array([[0, 1, 6]])  # a triangle through the inside, on existing edges 0-1
    with pytest.raises(InputError, match="non-manifold"):
        M.load_surface_mesh(write(tmp_path / "nm.obj", V, np.vstack([T, extra, extra[:, ::-1]])))
    V2 = np.vstack([V, [[0.5, 0, 0]]])  # a point in the middle of edge 0-1
    slivers = np.array([[0, 1, 8]] * 10)
    with pytest.raises(InputError, match="10 of 22 faces are degenerate"):
        M.load_surface_mesh(write(tmp_path / "deg.obj", V2, np.vstack([T, slivers])))


def test_missing_garbage_and_unknown_files(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError, match="not found") as e:
        M.load_surface_mesh("nope/missing.stl")
    assert str(tmp_path.resolve() / "nope" / "missing.stl") in str(e.value)
    (tmp_path / "garbage.obj").write_text("this is not\nan obj file at all\n")
    with pytest.raises(InputError, match="garbage.obj"):
        M.load_surface_mesh("garbage.obj")
    (tmp_path / "garbage.stl").write_bytes(bytes(RNG.integers(0, 256, 300, dtype=np.uint8)))
    with pytest.raises(InputError, match="garbage.stl"):
        M.load_surface_mesh("garbage.stl")
    (tmp_path / "shape.xyz1").write_text("1 2 3\n")
    with pytest.raises(InputError, match=r"extensions read are .*\.obj.*\.stl"):
        M.load_surface_mesh("shape.xyz1")


# ---------------------------------------------------------------------------- winding number
def test_hierarchical_winding_number_equals_bruteforce():
    for V, T in (icosphere(3), torus()):
        Vv, Tv, _ = M.validate_surface(V, T, "test mesh")
        m = M.SurfaceMesh(Vv, Tv)
        lo, hi = M.mesh_bounds(m)
        far = RNG.uniform(lo - 0.3, hi + 0.3, (3000, 3))
        near = Vv[Tv[:, 0]] * 0.4 + Vv[Tv[:, 1]] * 0.35 + Vv[Tv[:, 2]] * 0.25  # on faces ...
        normal = np.cross(Vv[Tv[:, 1]] - Vv[Tv[:, 0]], Vv[Tv[:, 2]] - Vv[Tv[:, 0]])
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        near = np.vstack([near + 1e-7 * normal, near - 1e-7 * normal, Vv + 1e-6])  # ... just off them
        P = np.vstack([far, near])
        w = B.winding_number(m, P)
        wb = B._winding_number_bruteforce(P, m.vertices, m.triangles)
        assert np.abs(w - wb).max() < 1e-9
        n = near.shape[0] - Vv.shape[0]
        assert np.all(B.inside_mesh(m, near[n // 2: n]))
        assert not np.any(B.inside_mesh(m, near[: n // 2]))


def test_torus_hole_and_cavity():
    V, T = torus()
    Vv, Tv, _ = M.validate_surface(V, T, "torus")
    m = M.SurfaceMesh(Vv, Tv)
    assert B.inside_mesh(m, [[0, 0, 0], [1.0, 0, 0], [0, -1.0, 0.1], [1.5, 0, 0]]).tolist() == [False, True, True, False]
    # cube with an inner, inverted cube: a cavity
    Vo, To = cube_tris(0.0, 1.0)
    Vi, Ti = cube_tris(0.25, 0.75)
    Vc, Tc, rep = M.validate_surface(np.vstack([Vo, Vi]), np.vstack([To, Ti[:, ::-1] + 8]), "hollow")
    hollow = M.SurfaceMesh(Vc, Tc)
    assert math.isclose(M.mesh_volume(hollow), 1.0 - 0.125) and rep == []
    assert B.inside_mesh(hollow, [[0.5, 0.5, 0.5], [0.1, 0.5, 0.5]]).tolist() == [False, True]


@pytest.mark.slow
def test_winding_number_benchmark():
    """1e5 points x 1e4 triangles (torus); prints the time (run with -m slow -s)."""
    Vv, Tv, _ = M.validate_surface(*torus(nu=100, nv=50), "torus")
    m = M.SurfaceMesh(Vv, Tv)
    assert m.n_triangles == 10_000
    P = RNG.uniform([-1.5, -1.5, -0.5], [1.5, 1.5, 0.5], (100_000, 3))
    B.winding_number(m, P[:10])  # compile / load the cache, build the hierarchy
    t0 = time.perf_counter()
    w = B.winding_number(m, P)
    dt = time.perf_counter() - t0
    print(f"\nwinding number: {P.shape[0]} points x {m.n_triangles} triangles: {dt:.2f} s")
    wb = B._winding_number_bruteforce(P[:1000], m.vertices, m.triangles)
    assert np.abs(w[:1000] - wb).max() < 1e-9
