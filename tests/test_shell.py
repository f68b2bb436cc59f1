"""Shell geometry: primitive surfaces, open meshes, layered surface sampling, vertex embedding."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pdmpm_cli.errors import InputError
from pdmpm_cli.geometry import embed as E
from pdmpm_cli.geometry import mesh as M
from pdmpm_cli.geometry import primitive_surfaces as PS
from pdmpm_cli.geometry import shapes as G
from pdmpm_cli.geometry import shell as S

ROT = G.rotation_matrix((25.0, -40.0, 70.0))
CENTER = np.array([0.3, -0.2, 1.1])


def edge_lengths(m):
    E = np.concatenate([m.triangles[:, [0, 1]], m.triangles[:, [1, 2]], m.triangles[:, [2, 0]]])
    return np.linalg.norm(m.vertices[E[:, 0]] - m.vertices[E[:, 1]], axis=1)


def area(m):
    P = m.vertices[m.triangles]
    return 0.5 * float(np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1).sum())


def box_offset_area(a, b, c, d):
    """Area of the box a x b x c shrunk by d on every side."""
    a, b, c = a - 2 * d, b - 2 * d, c - 2 * d
    return 2.0 * (a * b + b * c + a * c)


# ---------------------------------------------------------------------------- primitives
@pytest.mark.parametrize(
    "kind, kw, volume, rtol",
    [
        ("box", dict(size=(0.4, 0.2, 0.3)), 0.4 * 0.2 * 0.3, 1e-9),
        ("sphere", dict(radius=0.1), 4.0 / 3.0 * math.pi * 0.1**3, 0.02),
        ("cylinder", dict(radius=0.1, height=0.25), math.pi * 0.1**2 * 0.25, 0.02),
        ("capsule", dict(radius=0.1, length=0.2), math.pi * 0.1**2 * 0.2 + 4.0 / 3.0 * math.pi * 0.1**3, 0.02),
        ("capsule", dict(radius=0.1, length=0.0), 4.0 / 3.0 * math.pi * 0.1**3, 0.02),
    ],
)
@pytest.mark.parametrize("R", [np.eye(3), ROT])
def test_closed_primitives(kind, kw, volume, rtol, R):
    edge = 0.015  # vertices on the true surface: the volume deficit is about 0.45 (edge / radius)^2
    m = PS.primitive_surface(kind, center=CENTER, R=R, edge=edge, **kw)
    assert m.closed and m.repairs == []
    V, T, repairs = M.validate_surface(m.vertices, m.triangles, "again")  # closed, manifold, oriented
    assert repairs == [] and np.array_equal(T, m.triangles)  # not flipped: outward already
    vol = M.mesh_volume(m)
    assert vol > 0.0 and math.isclose(vol, volume, rel_tol=rtol)
    L = edge_lengths(m)
    assert L.min() >= 0.5 * edge and L.max() <= 2.0 * edge
    assert np.allclose(m.vertices.mean(axis=0), CENTER, atol=edge)


def test_sheet_primitive_is_open_with_exact_area():
    m = PS.primitive_surface("sheet", center=CENTER, R=ROT, edge=0.03, size=(1.0, 0.5))
    assert not m.closed
    assert math.isclose(area(m), 0.5, rel_tol=1e-9)
    L = edge_lengths(m)
    assert L.min() >= 0.015 and L.max() <= 0.06
    assert np.allclose((m.vertices - CENTER) @ ROT[:, 2], 0.0, atol=1e-12)  # in the local xy plane
    P = m.vertices[m.triangles]
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    assert np.all(n @ ROT[:, 2] > 0.0)  # normal = local +z
    with pytest.raises(InputError, match="not closed"):
        M.validate_surface(m.vertices, m.triangles, "sheet")
    M.validate_surface(m.vertices, m.triangles, "sheet", allow_open=True)


def test_primitive_errors():
    with pytest.raises(InputError, match="unknown surface primitive 'torus'"):
        PS.primitive_surface("torus", center=(0, 0, 0), R=np.eye(3), edge=0.1)
    with pytest.raises(InputError, match="radius is required"):
        PS.primitive_surface("sphere", center=(0, 0, 0), R=np.eye(3), edge=0.1)
    with pytest.raises(InputError, match="2 positive lengths"):
        PS.primitive_surface("sheet", center=(0, 0, 0), R=np.eye(3), edge=0.1, size=(1.0, 0.0))
    with pytest.raises(InputError, match="edge of at least"):
        PS.primitive_surface("box", center=(0, 0, 0), R=np.eye(3), edge=1e-5, size=(1, 1, 1))


# ---------------------------------------------------------------------------- open meshes
def write_obj(path, V, faces):
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in V]
    lines += ["f " + " ".join(str(i + 1) for i in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_allow_open_single_quad(tmp_path):
    path = write_obj(tmp_path / "quad.obj", [(0, 0, 0), (1, 0, 0), (1, 2, 0), (0, 2, 0)], [(0, 1, 2, 3)])
    m = M.load_surface_mesh(path, allow_open=True)
    assert not m.closed and m.triangles.shape == (2, 3) and m.repairs == []
    assert math.isclose(area(m), 2.0, rel_tol=1e-12)
    with pytest.raises(InputError, match="is not a valid closed surface: the surface is not closed: 4 boundary"):
        M.load_surface_mesh(path)


def _cube_obj(tmp_path):
    V = [(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)]
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (3, 2, 6, 7), (0, 4, 6, 2), (1, 3, 7, 5)]
    return write_obj(tmp_path / "inverted_cube.obj", V, [q[::-1] for q in quads])  # inside out


def test_allow_open_keeps_inverted_closed_flip(tmp_path):
    m = M.load_surface_mesh(_cube_obj(tmp_path), allow_open=True)
    assert m.closed and any("flipped" in r for r in m.repairs) and math.isclose(M.mesh_volume(m), 1.0)


def test_flipped_triangle_fails_in_both_modes(tmp_path):
    V = [(x, y, 0.0) for y in range(3) for x in range(3)]  # 2 x 2 quads, open
    tris = []
    for j in range(2):
        for i in range(2):
            a, b, c, d = 3 * j + i, 3 * j + i + 1, 3 * j + i + 4, 3 * j + i + 3
            tris += [(a, b, c), (a, c, d)]
    tris[3] = tris[3][::-1]
    path = write_obj(tmp_path / "flipped.obj", V, tris)
    for allow_open in (True, False):
        with pytest.raises(InputError, match=r"inconsistent orientation: at \d+ edges.*Recalculate Outside"):
            M.load_surface_mesh(path, allow_open=allow_open)
    with pytest.raises(InputError, match="is not a valid surface: inconsistent orientation"):
        M.load_surface_mesh(path, allow_open=True)


# ---------------------------------------------------------------------------- sampling
def test_flat_sheet_cloth():
    h = 0.02
    m = PS.primitive_surface("sheet", center=CENTER, R=ROT, edge=0.05, size=(1.0, 0.5))
    s = S.shell_particles(m, h, 1, np.random.default_rng(7))
    n = s.points.shape[0]
    assert abs(n - 0.5 / h**2) <= 0.1 * 0.5 / h**2
    d, _ = cKDTree(s.points).query(s.points, k=2)
    assert d[:, 1].min() >= 0.6 * h
    assert np.abs((s.points - CENTER) @ ROT[:, 2]).max() <= 1e-12  # on the plane
    loc = (s.points - CENTER) @ ROT
    assert np.all(np.abs(loc[:, 0]) <= 0.5 + 1e-12) and np.all(np.abs(loc[:, 1]) <= 0.25 + 1e-12)
    assert math.isclose(s.volumes.sum(), 1.0 * 0.5 * h, rel_tol=1e-9)
    assert np.allclose(s.normals, ROT[:, 2], atol=1e-12)
    assert s.layer.dtype == np.int32 and np.all(s.layer == 0)
    again = S.shell_particles(m, h, 1, np.random.default_rng(7))
    assert np.array_equal(again.points, s.points) and np.array_equal(again.volumes, s.volumes)
    other = S.shell_particles(m, h, 1, np.random.default_rng(8))
    assert not np.array_equal(other.points[: min(n, len(other.points))], s.points[: len(other.points)])


def test_open_sheet_layers_go_against_the_normal():
    h = 0.02
    m = PS.primitive_surface("sheet", center=(0, 0, 0), R=np.eye(3), edge=0.05, size=(0.6, 0.4))
    s = S.shell_particles(m, h, 3, np.random.default_rng(1))
    n0 = int((s.layer == 0).sum())
    assert s.points.shape[0] == 3 * n0
    for k in range(3):
        assert np.allclose(s.points[s.layer == k, 2], -k * h, atol=1e-12)
        assert np.allclose(s.points[s.layer == k, :2], s.points[s.layer == 0, :2], atol=1e-12)
    assert math.isclose(s.volumes.sum(), 0.6 * 0.4 * 3 * h, rel_tol=1e-9)


@pytest.mark.parametrize("edge", [0.02, 0.05])
def test_closed_box_layers(edge):
    a, b, c, h, L = 0.4, 0.2, 0.2, 0.02, 3
    m = PS.primitive_surface("box", center=CENTER, R=ROT, edge=edge, size=(a, b, c))
    s = S.shell_particles(m, h, L, np.random.default_rng(3))
    loc = (s.points - CENTER) @ ROT
    depth = np.min(np.array([a, b, c]) / 2 - np.abs(loc), axis=1)  # distance inside the box
    n0 = int((s.layer == 0).sum())
    assert abs(n0 - box_offset_area(a, b, c, 0) / h**2) <= 0.1 * box_offset_area(a, b, c, 0) / h**2
    for k in range(L):
        # every point (near the edges too: the layers are shrunk copies of the faces, no folding)
        assert np.allclose(depth[s.layer == k], k * h, atol=1e-12)
        pk = s.points[s.layer == k]
        d, _ = cKDTree(pk).query(pk, k=2)  # a face shrinks by at most 1 - 2 k h / b
        assert d[:, 1].min() >= 0.6 * h * (1.0 - 2.0 * k * h / b)
    # layer k stands for the offset box area times h: a layer-0 point for [-h/2, h/2] around
    # the surface, so the shell is the box grown by h/2 minus the box shrunk by (L - 1/2) h
    per_layer = [s.volumes[s.layer == k].sum() for k in range(L)]
    for k in range(L):
        assert math.isclose(per_layer[k], box_offset_area(a, b, c, k * h) * h, rel_tol=1e-9)
    grown = (a + h) * (b + h) * (c + h)
    shrunk = (a - (2 * L - 1) * h) * (b - (2 * L - 1) * h) * (c - (2 * L - 1) * h)
    assert math.isclose(s.volumes.sum(), grown - shrunk, rel_tol=0.01)


def test_sphere_layer_volumes_shrink_with_depth():
    r, h, L = 0.1, 0.01, 4
    m = PS.primitive_surface("sphere", center=CENTER, R=np.eye(3), edge=h, radius=r)
    s = S.shell_particles(m, h, L, np.random.default_rng(5))
    per_layer = np.array([s.volumes[s.layer == k].sum() for k in range(L)])
    for k in range(L):
        assert math.isclose(per_layer[k] / per_layer[0], (r - k * h) ** 2 / r**2, rel_tol=0.03)
        radius = np.linalg.norm(s.points[s.layer == k] - CENTER, axis=1)
        assert np.allclose(radius, r - k * h, atol=0.06 * h)  # polyhedral sphere: within its sagitta
    radial = (s.points - CENTER) / np.linalg.norm(s.points - CENTER, axis=1)[:, None]
    assert np.einsum("ij,ij->i", s.normals, radial).min() > 0.999
    assert np.allclose(np.linalg.norm(s.normals, axis=1), 1.0)


def test_layers_deeper_than_a_thin_body_are_cut_locally():
    """Layers that would overlap across a plate are cut where it is thin, and the deepest kept point fills the
    plate to its middle: the volume is the plate's (its layers' slabs reach h/2 outside: first_depth 0)."""
    a, b, c, h = 0.4, 0.2, 0.04, 0.01
    m = PS.primitive_surface("box", center=(0, 0, 0), R=ROT, edge=h, size=(a, b, c))
    assert S.shell_particles(m, h, 2, np.random.default_rng(0)).notes == []  # 2 h fits in half the thickness
    for layers in (3, 4):  # layers * h exceeds half of the 0.04 m thickness
        s = S.shell_particles(m, h, layers, np.random.default_rng(0), what="body 'plate'")
        assert len(s.notes) == 1 and "thinner than its" in s.notes[0] and f"{layers} layers" in s.notes[0]
        assert s.layer.max() == 1  # 0 and h fit: 2 h + h/2 <= 0.04 m
        assert math.isclose(s.volumes.sum(), (a + h) * (b + h) * (c + h), rel_tol=0.01)
        depth = np.min(np.array([a, b, c]) / 2 - np.abs(s.points @ ROT), axis=1)
        assert depth.min() >= -1e-12 and depth.max() <= c / 2 + 1e-12  # inside, none past the middle


@pytest.mark.parametrize("c", [0.006, 0.013, 0.025])
def test_plate_thinner_than_its_layers_gets_its_own_volume(c):
    """A plate 0.6 to 2.5 spacings thick asked for 4 layers (first_depth 1/2, as shell bodies): one layer per
    side, its points at the centre of their half of the plate, the total the plate's volume within 1 %."""
    a, b, h = 0.4, 0.2, 0.01
    m = PS.primitive_surface("box", center=CENTER, R=ROT, edge=h, size=(a, b, c))
    s = S.thin_crowded(S.shell_particles(m, h, 4, np.random.default_rng(2), first_depth=0.5), h)
    print(f"plate {c} m thick, 4 layers at h = {h} m: volume / plate volume - 1 = "
          f"{s.volumes.sum() / (a * b * c) - 1:+.2%}")
    assert math.isclose(s.volumes.sum(), a * b * c, rel_tol=0.01)
    z = np.abs((s.points - CENTER) @ ROT[:, 2])
    faces = np.abs(s.normals @ ROT[:, 2]) > 0.9
    assert np.allclose(z[faces & (s.layer == 0)], c / 4, atol=1e-9 * c) or c < 0.0101  # thinnest: merged pairs
    d, _ = cKDTree(s.points).query(s.points, k=2)
    assert d[:, 1].min() >= 0.5 * h * min(1.0, c / h)  # crowded points from both sides merged


def test_bunny_shell_layers_fill_the_shell_volume():
    """The bunny with 4 layers at h = 5 mm: thin ears and feet get fewer layers instead of a refusal; the
    particles' volume is the volume within 4 h of the surface (Monte Carlo: winding number and the distance
    to a dense surface sample) within 3 %."""
    from pdmpm_cli.geometry import bunny, bvh

    hgt, h, L = 0.2, 0.005, 4
    surf = bunny.bunny_surface((0.0, 0.0, 0.0), hgt, np.eye(3), h)
    s = S.shell_particles(surf, h, L, np.random.default_rng(0), first_depth=0.5)
    assert s.notes and "fewer layers" in s.notes[0]
    rng = np.random.default_rng(1)
    P = surf.vertices[surf.triangles]
    w = rng.dirichlet((1.0, 1.0, 1.0), 400_000)
    tri = rng.choice(len(P), 400_000, p=area_weights(P))
    dense = np.einsum("ik,ikd->id", w, P[tri])  # uniform on the surface, about 0.2 mm apart
    lo, hi = surf.vertices.min(axis=0), surf.vertices.max(axis=0)
    q = rng.uniform(lo, hi, (150_000, 3))
    q = q[bvh.inside_mesh(surf, q)]
    tree = cKDTree(dense, balanced_tree=False, compact_nodes=False)  # the balanced tree is slow from inside
    near = tree.query(q, distance_upper_bound=L * h)[0] < L * h
    shell = np.prod(hi - lo) * near.sum() / 150_000
    full = int((s.layer == L - 1).sum())
    print(f"bunny, {L} layers at h = {h} m: {full} of {int((s.layer == 0).sum())} surface samples keep all layers; "
          f"volume / volume within {L} h of the surface - 1 = {s.volumes.sum() / shell - 1:+.2%}")
    assert math.isclose(s.volumes.sum(), shell, rel_tol=0.03)


def area_weights(P):
    a = np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
    return a / a.sum()


def test_shell_argument_errors():
    m = PS.primitive_surface("sheet", center=(0, 0, 0), R=np.eye(3), edge=0.1, size=(0.5, 0.5))
    rng = np.random.default_rng(0)
    with pytest.raises(InputError, match="layers must be a whole number >= 1"):
        S.shell_particles(m, 0.02, 0, rng)
    with pytest.raises(InputError, match="spacing h must be a positive length"):
        S.shell_particles(m, -0.02, 1, rng)
    with pytest.raises(InputError, match="too small for the spacing"):
        S.shell_particles(m, 0.3, 1, rng, what="body 'tiny'")
    with pytest.raises(InputError, match=r"body 'huge'.*limit 5,000,000.*at least h ="):
        S.shell_particles(m, 1e-4, 1, rng, what="body 'huge'")


# ---------------------------------------------------------------------------- embedding
def test_embed_points():
    rng = np.random.default_rng(11)
    X = rng.uniform(-1.0, 1.0, (400, 3))
    P = rng.uniform(-0.8, 0.8, (60, 3))
    idx, w = E.embed_points(P, X, k=8)
    assert idx.shape == (60, 8) and idx.dtype == np.int64 and w.dtype == np.float64
    assert np.all(w > 0.0) and np.allclose(w.sum(axis=1), 1.0, atol=1e-14)
    brute = np.argsort(np.linalg.norm(P[:, None] - X[None], axis=2), axis=1)[:, :8]
    assert all(set(a) == set(b) for a, b in zip(idx, brute))
    A = rng.normal(size=(3, 3))
    t = rng.normal(size=3)
    Xi = X[idx]  # (60, 8, 3)
    moved = np.einsum("mk,mkd->md", w, Xi @ A.T + t + (P[:, None] - Xi) @ A.T)
    assert np.allclose(moved, P @ A.T + t, atol=1e-12)
    idx3, w3 = E.embed_points(P, X[:3], k=8)  # fewer particles than k
    assert idx3.shape == (60, 3) and np.allclose(w3.sum(axis=1), 1.0)
    idx0, w0 = E.embed_points(X[:5], X, k=4)  # a point on a particle: finite weights, biggest there
    assert np.all(np.isfinite(w0)) and np.array_equal(idx0[:, 0], np.arange(5))
    assert np.all(w0[:, 0] == w0.max(axis=1))


def test_first_depth_half_fills_the_body():
    """first_depth=0.5: layers at (k + 1/2) h, a box whose half thickness is layers * h is filled exactly."""
    a, b, c, h, L = 1.1, 0.1, 0.1, 0.0125, 4
    m = PS.primitive_surface("box", center=CENTER, R=ROT, edge=h, size=(a, b, c))
    s = S.shell_particles(m, h, L, np.random.default_rng(4), first_depth=0.5)
    depth = np.min(np.array([a, b, c]) / 2 - np.abs((s.points - CENTER) @ ROT), axis=1)
    for k in range(L):
        assert np.allclose(depth[s.layer == k], (k + 0.5) * h, atol=1e-12)
    assert math.isclose(s.volumes.sum(), a * b * c, rel_tol=0.005)  # midpoint rule over the depth
    five = S.shell_particles(m, h, 5, np.random.default_rng(4), first_depth=0.5)  # one more than fits: cut
    assert five.layer.max() == 3 and math.isclose(five.volumes.sum(), a * b * c, rel_tol=0.01)
    with pytest.raises(InputError, match="first layer must be >= 0"):
        S.shell_particles(m, h, 2, np.random.default_rng(4), first_depth=-1.0)
