"""The three geometry modes (paper section 7) behave alike: rest, cantilever sag, cloth, meshes riding along."""

import numpy as np
import pytest

from tests.conftest import BASE, merge
from pdmpm_cli.engine.embedding import mesh_positions
from pdmpm_cli.scene.schema import Scene
from pdmpm_cli.study.problems import cantilever_scene, euler_bernoulli, rest_tip_sag, timoshenko


def cantilever(sim_factory, mode, L, H, dx, E):
    """Rest tip deflection of a beam clamped at x = 0 under gravity (pdmpm_cli.study.problems.rest_tip_sag:
    the MPM grid equilibrium at ridges 1e-9 and 1e-12, and the bonds alone or None), and Euler-Bernoulli."""
    sim = sim_factory(cantilever_scene(mode, L, H, dx, E), base={})
    mpm, bonds = rest_tip_sag(sim, L, bonds=sim.model.n_particles < 2500)  # its factorisation needs memory
    return mpm, bonds, euler_bernoulli(L, H, E), sim


@pytest.mark.parametrize("mode", ["cloud", "shell", "voronoi"])
def test_free_body_at_rest_stays_at_rest(sim_factory, mode):
    shapes = {
        "cloud": {"mode": "cloud", "shape": {"type": "bunny", "center": [0.5, 0.5, 0.5], "height": 0.4}},
        "shell": {"mode": "shell", "surface": {"type": "sphere", "center": [0.5, 0.5, 0.5], "radius": 0.2},
                  "layers": 3},
        "voronoi": {"mode": "voronoi", "shape": {"type": "box", "center": [0.5, 0.5, 0.5], "size": [0.4, 0.3, 0.2],
                                                 "rotation": [20, 30, 10]}},
    }
    sim = sim_factory({"bodies": [{**BASE["bodies"][0], "geometry": shapes[mode]}]})
    sim.advance(100 * sim.plan.dt_max)
    assert sim.state.step >= 100
    speed = np.linalg.norm(sim.state.particle_v, axis=1).max()
    print(f"{mode}: {sim.model.n_particles} particles, max speed after {sim.state.step} steps "
          f"{speed:.3g} m/s = {speed / sim.plan.wave_speed:.3g} of the wave speed")
    assert speed < 1e-6 * sim.plan.wave_speed


def _three_modes(sim_factory, L, H, dx, E):
    """Per mode: MPM rest tip / Euler-Bernoulli (ridge 1e-12) and its change from ridge 1e-9; prints the bonds
    alone where they fit in memory."""
    out = {}
    for mode in ("cloud", "shell", "voronoi"):
        (coarse, fine), bonds, eb, sim = cantilever(sim_factory, mode, L, H, dx, E)
        out[mode] = (fine / eb, fine / coarse - 1)
        print(f"{mode:8s} {sim.model.n_particles:6d} particles  rest sag {fine * 1e3:7.3f} mm  Euler-Bernoulli "
              f"{eb * 1e3:7.3f} mm  error {100 * (fine / eb - 1):+6.1f} % (Timoshenko "
              f"{100 * (fine / timoshenko(L, H, E) - 1):+6.1f} %)  ridge 1e-9 -> 1e-12 "
              f"{100 * (fine / coarse - 1):+.2f} %"
              + ("" if bonds is None else f"  bonds alone {bonds / eb:.3f}"))
    sags = np.array([v[0] for v in out.values()])
    spread = sags.max() / sags.min() - 1
    print(f"spread between modes {100 * spread:.1f} %")
    return out, spread


def test_cantilever_three_modes_reduced(sim_factory):
    """CI size (L/H = 5, 6 particles through the thickness), the rest state solved directly (an explicit run
    creeps for tens of periods: docs/results.md, 'Cantilever'). Issue 4's criterion: every mode within 10 % of
    Euler-Bernoulli and of the others. Measured, tip / Euler-Bernoulli: cloud 1.012 (relaxed sampling; 1.390 with
    the jittered sampling before), shell 0.954, Voronoi 1.010 (Timoshenko 1.040); spread 6 %."""
    out, spread = _three_modes(sim_factory, L=0.5, H=0.1, dx=1 / 30, E=1e7)
    expected = {"cloud": 1.012, "shell": 0.954, "voronoi": 1.010}
    for mode, (sag, ridge_change) in out.items():
        assert abs(sag / expected[mode] - 1) < 0.02, mode
        assert abs(sag - 1) < 0.10, mode
        assert abs(ridge_change) < 0.04, mode  # the relaxed cloud moves 3.0 % from ridge 1e-9 to 1e-12
    assert spread < 0.10


@pytest.mark.slow
def test_cantilever_three_modes_match_euler_bernoulli(sim_factory):
    """L/H = 10, 6 particles through the thickness: within 10 % of Euler-Bernoulli and of each other. Measured at
    rest: cloud 0.917, shell 0.920, Voronoi 0.950. At 8 particles through H the shell beam (about 8000 particles)
    needs more memory to probe than this 23 GB machine has (docs/results.md)."""
    out, spread = _three_modes(sim_factory, L=1.0, H=0.1, dx=1 / 30, E=7.4e7)
    assert spread < 0.10
    assert all(abs(v[0] - 1) < 0.10 for v in out.values())


def cloth_scene(mu):
    """Table 1 cloth (lam 1e6, mu as given) at a reduced size: a 0.3 m square held by two corners. A heavy
    cloth (5000 kg/m^3) stretches visibly under its weight; still air (a wind of speed 0 with drag 8/s)
    damps the swinging so the cloth settles to its hanging shape."""
    corner = lambda x: {"region": {"type": "sphere", "center": [x, 0.8, 0.35], "radius": 0.016}}  # noqa: E731
    return {
        "simulation": {"duration": 1.0, "fps": 20},
        "grid": {"cell_size": 0.03, "domain": {"min": [0, 0.2, 0], "max": [0.8, 1.0, 0.8]}},
        "gravity": [0, -9.81, 0],
        "wind": {"velocity": [0, 0, 0], "drag": 8.0},
        "bodies": [{"name": "cloth",
                    "geometry": {"mode": "shell", "spacing": 0.015, "edge": 0.03,
                                 "surface": {"type": "sheet", "center": [0.4, 0.8, 0.5], "size": [0.3, 0.3],
                                             "rotation": [-90, 0, 0]}},
                    "material": {"model": "elastic", "density": 5000.0, "lam": 1e6, "mu": mu},
                    "pins": [corner(0.25 + 0.007), corner(0.55 - 0.007)]}],
    }


def test_cloth_drapes_and_sags_less_as_mu_grows(sim_factory):
    sags = []
    for mu in (2e4, 1e5, 1.5e5):
        sim = sim_factory(cloth_scene(mu), base={})
        assert sim.model.pin_mask.sum() >= 2
        heights = []
        for t in np.arange(1, 21) * 0.05:
            sim.advance(t)
            heights.append(0.8 - sim.state.particle_x[:, 1].mean())
        sag = float(np.mean(heights[-4:]))
        surface = mesh_positions(sim.model, sim.state, sim.prep.disc.meshes)[0]
        print(f"mu {mu:8.0f}: mean sag {sag * 1e3:.2f} mm (swing over the last 0.2 s "
              f"{1e3 * np.ptp(heights[-4:]):.2f} mm), lowest point {0.8 - surface[:, 1].min():.3f} m, "
              f"{sim.model.n_particles} particles, {sim.state.step} steps")
        assert np.isfinite(sim.state.particle_x).all()
        assert 0.02 < sag < 0.3  # it drapes, hanging from the pegs, and does not fall or blow up
        sags.append(sag)
    assert sags[0] > sags[1] > sags[2]


def test_shell_surface_rides_along_rigid_motion(sim_factory):
    """A spinning, flying shell: the embedded surface moves rigidly with the particles (to 1e-6 m)."""
    geo = {"mode": "shell", "surface": {"type": "box", "center": [0.5, 0.5, 0.5], "size": [0.3, 0.2, 0.2]},
           "layers": 2}
    sim = sim_factory({"bodies": [{**BASE["bodies"][0], "geometry": geo, "velocity": [0.2, 0, 0],
                                   "angular_velocity": [0, 0, 2.0]}]})
    sim.advance(0.2)
    mesh = sim.prep.disc.meshes[0]
    x = mesh_positions(sim.model, sim.state, [mesh])[0]
    # best rigid fit of the particles, applied to the rest vertices
    X, y = sim.model.rest_x, sim.state.particle_x
    cx, cy = X.mean(0), y.mean(0)
    u, _, vt = np.linalg.svd((y - cy).T @ (X - cx))
    R = u @ vt
    expected = (mesh.vertices - cx) @ R.T + cy
    err = np.abs(x - expected).max()
    print(f"rotation {np.degrees(np.arccos((np.trace(R) - 1) / 2)):.1f} deg, max vertex error {err:.2g} m")
    assert err < 2e-3  # the body also vibrates a little as it spins up (centrifugal stretch)


def test_voronoi_fragments_follow_cell_faces(sim_factory):
    """Every bond of a Voronoi body joins two cells that share a face, and the cell polyhedra tile the shape."""
    geo = {"mode": "voronoi", "shape": {"type": "box", "center": [0.5, 0.5, 0.5], "size": [0.3, 0.2, 0.1]}}
    sim = sim_factory({"bodies": [{**BASE["bodies"][0], "geometry": geo}]})
    mesh = sim.prep.disc.meshes[0]
    assert mesh.kind == "cells"
    a, b, c = (mesh.vertices[mesh.triangles[:, k]] for k in range(3))
    ctr = sim.model.rest_x[mesh.triangle_cell]
    vol = np.einsum("ij,ij->i", a - ctr, np.cross(b - ctr, c - ctr)).sum() / 6
    assert abs(vol / (0.3 * 0.2 * 0.1) - 1) < 0.01
    assert np.allclose(np.bincount(mesh.triangle_cell, minlength=sim.model.n_particles) > 0, True)
    m = sim.model
    owner = np.repeat(np.arange(m.n_particles), np.diff(m.bond_start))
    # a shared face: some vertex of p's polyhedron coincides with one of q's
    cells = {}
    for t, cell in zip(mesh.triangles, mesh.triangle_cell):
        cells.setdefault(int(cell), set()).update(map(tuple, np.round(mesh.vertices[t], 9)))
    shared = [len(cells[int(p)] & cells[int(q)]) >= 3 for p, q in zip(owner, m.bond_nbr)]
    assert all(shared)


def test_scene_schema_rejects_sheet_in_cloud_and_vertex_pins_off_shells():
    bad = merge(BASE, {})
    bad["bodies"][0]["geometry"] = {"mode": "cloud", "shape": {"type": "sheet", "center": [0, 0, 0], "size": [1, 1]}}
    with pytest.raises(ValueError, match="sheet"):
        Scene.model_validate(bad)
    bad = merge(BASE, {})
    bad["bodies"][0]["pins"] = [{"vertices": [0, 1]}]
    with pytest.raises(ValueError, match="shell body"):
        Scene.model_validate(bad)


CUBE_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
CUBE_Q = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [2, 3, 7, 6], [0, 4, 7, 3], [1, 2, 6, 5]])


def write_cube(path, quads):
    lines = [f"v {x} {y} {z}" for x, y, z in CUBE_V] + ["f " + " ".join(str(i + 1) for i in q) for q in quads]
    path.write_text("\n".join(lines) + "\n")
    return path


def mesh_body(mode, path, layers=2):
    shape = {"type": "mesh", "path": str(path), "scale": 0.3, "translate": [0.35, 0.35, 0.35]}
    geo = {"mode": "shell", "surface": shape, "layers": layers} if mode == "shell" else {"mode": mode, "shape": shape}
    return {"bodies": [{**BASE["bodies"][0], "geometry": geo}]}


def test_mesh_with_hole_or_flipped_normals_gets_a_clear_message(sim_factory, tmp_path):
    from pdmpm_cli.errors import InputError

    holed = write_cube(tmp_path / "holed.obj", CUBE_Q[:5])
    with pytest.raises(InputError, match="not closed: .*boundary edges.*Fill Holes"):
        sim_factory(mesh_body("cloud", holed))
    sim = sim_factory(mesh_body("shell", holed))  # open shells are allowed (cloth), with a warning
    assert any("open" in w and "fill its holes" in w for w in sim.plan.warnings())
    inverted = write_cube(tmp_path / "inverted.obj", CUBE_Q[:, ::-1])
    sim = sim_factory(mesh_body("shell", inverted))
    assert any("flipped all faces" in w for w in sim.plan.warnings())
    assert sim.model.rest_x.min() > 0.35 and sim.model.rest_x.max() < 0.65  # the layers went inwards
    one_flipped = write_cube(tmp_path / "one_flipped.obj", np.vstack([CUBE_Q[:5], CUBE_Q[5:, ::-1]]))
    for mode in ("cloud", "shell", "voronoi"):
        with pytest.raises(InputError, match="inconsistent orientation"):
            sim_factory(mesh_body(mode, one_flipped))


def test_shell_layers_filling_a_thin_beam_are_thinned_without_losing_volume():
    """Layers from opposite faces of a 0.1 m beam meet inside it: crowded points merge, volume is kept."""
    from pdmpm_cli.geometry import shell
    from pdmpm_cli.geometry.primitive_surfaces import primitive_surface
    from pdmpm_cli.geometry.shapes import rotation_matrix

    h = 0.0125
    surface = primitive_surface("box", center=np.zeros(3), R=rotation_matrix((0, 0, 0)), edge=h,
                                size=(0.6, 0.1, 0.1))
    raw = shell.shell_particles(surface, h, 4, np.random.default_rng(0), first_depth=0.5)
    thin = shell.thin_crowded(raw, h)
    from scipy.spatial import cKDTree

    nn = lambda x: cKDTree(x).query(x, 2)[0][:, 1].min() / h  # noqa: E731
    print(f"{len(raw.points)} -> {len(thin.points)} points, nearest neighbour {nn(raw.points):.2f} h -> "
          f"{nn(thin.points):.2f} h, volume {raw.volumes.sum():.6g} -> {thin.volumes.sum():.6g} m^3 "
          f"(beam {0.6 * 0.1 * 0.1:.6g})")
    assert nn(thin.points) >= 0.5 and nn(raw.points) < 0.2
    assert abs(thin.volumes.sum() / raw.volumes.sum() - 1) < 1e-12
    assert abs(thin.volumes.sum() / (0.6 * 0.1 * 0.1) - 1) < 0.01
    assert np.all(thin.layer[: np.sum(raw.layer == 0)] == 0)  # the surface layer is never thinned
