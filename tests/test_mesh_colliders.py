"""Mesh colliders: a closed mesh file's signed distance as a level set, static or moving, with the primitives'
boundary types and friction. Answers from geometry: a sphere's and a box's exact distances, a bowl's inside."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import pyvista as pv

from pdmpm_cli.assemble import collider_table
from pdmpm_cli.engine.colliders import signed_distance
from pdmpm_cli.errors import InputError
from pdmpm_cli.geometry.mesh import SurfaceMesh, mesh_volume, validate_surface
from pdmpm_cli.geometry.sdf import distance_samples
from pdmpm_cli.runner import prepare
from pdmpm_cli.study.sim import Sim
from tests.mesh_corpus import _outward, bowl, box_quads, icosphere, write_off
from tests.test_cli import pdmpm

RNG = np.random.default_rng(7)


def mesh_table(V, T, spacing, inside_out=False):
    """The packed collider table of one static mesh collider."""
    Vv, Tv, _ = validate_surface(V, T, "mesh")
    c = SimpleNamespace(type="mesh", velocity=(0.0, 0.0, 0.0), boundary="separate", friction=0.0,
                        inside_out=inside_out)
    return collider_table([c], {0: distance_samples(SurfaceMesh(Vv, Tv), spacing)})


def test_distance_samples_of_a_sphere_mesh_give_its_distance_and_normal():
    """Within 4 cm of a 0.2 m sphere sampled at 2 cm: the distance to within 5 % of a sample (the facets lie up to
    0.1 mm inside the sphere) and the normal within 0.1 rad."""
    V, T = icosphere(4, 0.2)
    table = mesh_table(V + 0.5, T, 0.02)
    n = np.zeros(3)
    checked = 0
    for p in 0.5 + RNG.uniform(-0.25, 0.25, (3000, 3)):
        r = float(np.linalg.norm(p - 0.5))
        if abs(r - 0.2) < 0.04:
            phi = signed_distance(table, 0, *p, 0.0, n)
            assert phi == pytest.approx(r - 0.2, abs=1e-3)
            assert np.linalg.norm(n - (p - 0.5) / r) < 0.1
            checked += 1
    assert checked > 500


def test_mesh_box_matches_the_box_primitive_inside_out_included():
    V, faces = box_quads(size=(0.3, 0.2, 0.1), n=3)
    T = np.array([(f[0], f[i], f[i + 1]) for f in _outward(V, faces) for i in (1, 2)])
    prim = collider_table([SimpleNamespace(type="box", center=(0.0, 0.0, 0.0), size=(0.3, 0.2, 0.1), inside_out=True,
                                           velocity=(0.0, 0.0, 0.0), boundary="separate", friction=0.0)])
    mesh = mesh_table(V, T, 0.01, inside_out=True)
    n, m = np.zeros(3), np.zeros(3)
    half = np.array([0.15, 0.1, 0.05])
    for p in RNG.uniform(-0.17, 0.17, (2000, 3)):
        want = signed_distance(prim, 0, *p, 0.0, n)
        if abs(want) < 0.015 and np.sum(np.abs(p) > half - 0.02) == 1:  # near one face (interpolation rounds edges)
            assert signed_distance(mesh, 0, *p, 0.0, m) == pytest.approx(want, abs=1e-9 + 0.2 * 0.01)


def scene_with(collider_path, bodies, colliders, **extra):
    return {"simulation": {"duration": 1.0, "fps": 20}, "gravity": [0, 0, 0], "bodies": bodies,
            "colliders": [{"type": "mesh", "path": str(collider_path), **c} for c in colliders], **extra}


@pytest.mark.parametrize("response", ["projection", "penalty"])
def test_a_moving_mesh_pushes_a_block_and_no_particle_passes_through(tmp_path, response):
    """A mesh cube moving at 0.5 m/s meets an elastic block at rest (no gravity): it pushes the block ahead and no
    particle enters the cube (the level set at every particle stays above -1/4 of a spacing). With the projection
    (an inelastic impact) the block ends moving with the cube; with the penalty (an elastic push) it is thrown ahead
    faster than the cube, as by a bat (2 v for an elastic impact on a rigid pusher), and comes back off the domain's
    far wall."""
    V, faces = box_quads(size=(0.2, 0.2, 0.2), n=2)
    write_off(tmp_path / "pusher.off", V, faces)
    h = 0.025
    sim = Sim(scene_with(tmp_path / "pusher.off", grid={"cell_size": 0.05,
                                                        "domain": {"min": [0, 0, 0], "max": [1.2, 1, 1]}},
                         bodies=[{"name": "block", "material": {"model": "elastic", "density": 1000.0, "lam": 2e4,
                                                                "mu": 2e4},
                                  "geometry": {"mode": "cloud", "spacing": h, "sampling": "lattice",
                                               "shape": {"type": "box", "center": [0.5, 0.5, 0.5],
                                                         "size": [0.2, 0.2, 0.2]}}}],
                         colliders=[{"translate": [0.24, 0.5, 0.5], "velocity": [0.5, 0.0, 0.0],
                                     "response": response}]),
              tmp_path / "scene.yaml")
    table, n = sim.model.colliders, np.zeros(3)
    deepest, fastest = 0.0, 0.0
    for k in range(1, 15):
        sim.advance(0.05 * k)
        x, t = sim.state.particle_x, sim.state.time
        deepest = min(deepest, min(signed_distance(table, 0, *p, t, n) for p in x))
        fastest = max(fastest, sim.momentum()[0] / sim.model.particle_mass.sum())
    assert deepest > -0.25 * h
    assert sim.com()[0] > 0.5 + 0.15  # the cube's face moved 0.31 m past the block's first face
    v = sim.momentum() / sim.model.particle_mass.sum()
    if response == "projection":
        assert v[0] == pytest.approx(0.5, rel=0.2) and abs(v[1]) < 0.05 and abs(v[2]) < 0.05
    else:
        print(f"fastest {fastest:.3f} m/s, deepest {deepest / h:.3f} h")
        assert fastest > 0.75 and abs(v[1]) < 0.05 and abs(v[2]) < 0.05


def test_a_bowl_from_a_mesh_file_holds_a_liquid_poured_into_it(tmp_path):
    """A blob of viscoelastic liquid dropped into a bowl (a closed solid mesh, open side up) ends in the bowl's
    hollow: every particle inside the inner hemisphere (to half a cell), none through the wall."""
    V, T = bowl(outer=0.2, inner=0.16, edge=0.015)
    write_off(tmp_path / "bowl.off", V, [tuple(t) for t in T])
    centre = np.array([0.3, 0.26, 0.3])  # the rim's centre
    liquid = {"model": "viscoelastic", "density": 1000.0, "lam": 5e3, "mu": 500.0, "relaxation_time": 0.05,
              "relaxing_fraction": 1.0, "break_stretch": 0.03}
    sim = Sim(scene_with(tmp_path / "bowl.off", grid={"cell_size": 0.025,
                                                      "domain": {"min": [0, 0, 0], "max": [0.6, 0.6, 0.6]}},
                         bodies=[{"name": "liquid", "material": liquid,
                                  "geometry": {"mode": "cloud", "spacing": 0.0125,
                                               "shape": {"type": "sphere", "center": [0.3, 0.42, 0.3],
                                                         "radius": 0.06}}}],
                         colliders=[{"translate": centre.tolist(), "boundary": "slip", "friction": 0.2}],
                         gravity=[0, -9.81, 0]),
              tmp_path / "scene.yaml")
    sim.advance(0.5)
    x = sim.state.particle_x
    r = np.linalg.norm(x - centre, axis=1)
    assert np.all(r < 0.16 + 0.0125), r.max()
    assert np.all(x[:, 1] < centre[1] + 0.0125)  # below the rim: it sits in the hollow
    assert np.all(np.isfinite(sim.state.particle_v)) and float(np.abs(sim.state.particle_v).max()) < 1.0


def test_an_open_mesh_collider_is_refused_with_its_scene_key(tmp_path):
    V, T = icosphere(2, 0.1)
    write_off(tmp_path / "cup.off", V + 0.5, [tuple(t) for t in T[:-10]])  # ten triangles missing: a hole
    path = tmp_path / "scene.yaml"
    path.write_text(
        "simulation: {duration: 0.1}\n"
        "grid: {cell_size: 0.05, domain: {min: [0, 0, 0], max: [1, 1, 1]}}\n"
        "bodies:\n"
        "  - name: b\n"
        "    geometry: {mode: cloud, shape: {type: sphere, center: [0.5, 0.6, 0.5], radius: 0.05}}\n"
        "    material: {model: elastic, density: 1000, lam: 1e5, mu: 1e5}\n"
        "colliders:\n"
        "  - {type: mesh, path: cup.off}\n")
    with pytest.raises(InputError) as info:
        prepare(path)
    assert str(info.value).startswith(f"{path}:8:24 colliders.0.path: ")
    assert "cup.off" in str(info.value)


def test_bowl_helper_is_a_closed_solid_of_the_right_volume():
    Vv, Tv, report = validate_surface(*bowl(outer=0.2, inner=0.16, edge=0.015), "bowl")
    assert report == [] and mesh_volume(SurfaceMesh(Vv, Tv)) == pytest.approx(
        2 * math.pi * (0.2**3 - 0.16**3) / 3, rel=0.01)


def test_run_writes_the_placed_collider_surface_and_render_draws_it(tmp_path):
    """`pdmpm run` stores each mesh collider's surface (placed, at time 0) beside run.h5; `pdmpm render` reads it."""
    V, T = icosphere(2, 0.1)
    write_off(tmp_path / "ball.off", V, [tuple(t) for t in T])
    path = tmp_path / "scene.yaml"
    path.write_text(
        "simulation: {duration: 0.05, fps: 20}\n"
        "grid: {cell_size: 0.05, domain: {min: [0, 0, 0], max: [1, 1, 1]}}\n"
        "bodies:\n"
        "  - name: b\n"
        "    geometry: {mode: cloud, spacing: 0.05, shape: {type: sphere, center: [0.5, 0.7, 0.5], radius: 0.1}}\n"
        "    material: {model: elastic, density: 1000, lam: 1e5, mu: 1e5}\n"
        "colliders:\n"
        "  - {type: mesh, path: ball.off, units: cm, scale: 100, translate: [0.5, 0.4, 0.5], velocity: [0, 1, 0]}\n"
        "render: {resolution: [160, 120]}\n")
    out = tmp_path / "out"
    r = pdmpm("run", path, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    V2 = pv.read(out / "colliders" / "collider_0.ply").points
    np.testing.assert_allclose(V2.min(axis=0), [0.4, 0.3, 0.4], atol=1e-6)  # cm x 100 = m, then translated
    r = pdmpm("render", out, "--no-video", "--frames", "0")
    assert r.returncode == 0, r.stderr
    assert (out / "frames" / "frame_00000.png").is_file()
