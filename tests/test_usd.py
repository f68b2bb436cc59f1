"""`output.usd: true`: one USD file per run that reads back with Pixar's pxr as what run.h5 and the PLY files hold."""

import meshio
import numpy as np
import pytest

from pdmpm_cli.io.hdf5 import read_run
from pdmpm_cli.runner import prepare, simulate

pxr = pytest.importorskip("pxr")
from pxr import Usd, UsdGeom  # noqa: E402

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]

# reduced resolution and duration, as tests/table1.py runs the bundled scenes: a few frames each
SCENES = {
    "elastic_drop": ("grid.cell_size=0.06", "simulation.duration=0.125"),
    "cloth": ("grid.cell_size=0.02", "simulation.duration=0.07"),
    "wall_break": ("grid.cell_size=0.04", "bodies.0.geometry.spacing=0.04", "bodies.1.geometry.spacing=0.03",
                   "simulation.duration=0.06"),
}


@pytest.mark.parametrize("name", SCENES)
def test_usd_matches_run_h5_and_the_ply_meshes(name, tmp_path):
    """One time sample per frame at frame x fps, metres and +y up; each body's points equal run.h5's frames to
    float32 precision, its width the spacing, its velocities and speed primvar those of run.h5; each mesh has
    the PLY's triangles and run.h5's vertex positions."""
    overrides = (*SCENES[name], "output.usd=true", "output.fields=[particle_v, particle_speed]")
    prep = prepare(ROOT / "scenes" / f"{name}.yaml", overrides)
    out = tmp_path / "out"
    out.mkdir()
    simulate(prep, out)
    run = read_run(out / "run.h5")
    stage = Usd.Stage.Open(str(out / "run.usd"))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    fps = 1.0 / prep.plan.frame_dt
    assert stage.GetTimeCodesPerSecond() == fps and stage.GetDefaultPrim().GetPath() == "/pdmpm"
    codes = [t * fps for t in run.times]
    assert len(run) == prep.plan.frames + 1 >= 3
    for body, (start, end), h in zip(prep.scene.bodies, prep.disc.body_ranges, prep.disc.body_spacing):
        points = UsdGeom.Points(stage.GetPrimAtPath(f"/pdmpm/{body.name}/particles"))
        assert points.GetPointsAttr().GetTimeSamples() == pytest.approx(codes)
        assert list(points.GetWidthsAttr().Get()) == pytest.approx([h])
        speed = UsdGeom.PrimvarsAPI(points).GetPrimvar("particle_speed")
        for f, code in enumerate(codes):
            frame = run.frame(f)
            x = np.asarray(points.GetPointsAttr().Get(code))
            assert np.array_equal(x, frame["particle_x"][start:end].astype(np.float32))
            v = np.asarray(points.GetVelocitiesAttr().Get(code))
            assert np.array_equal(v, frame["particle_v"][start:end].astype(np.float32))
            assert np.array_equal(np.asarray(speed.Get(code)), frame["particle_speed"][start:end].astype(np.float32))
    meshes = prep.disc.meshes
    assert bool(meshes) == (name != "elastic_drop")
    starts = np.cumsum([0] + [len(m.vertices) for m in meshes])
    for m, a, b in zip(meshes, starts[:-1], starts[1:]):
        usd_mesh = UsdGeom.Mesh(stage.GetPrimAtPath(f"/pdmpm/{m.name}/{'cells' if m.kind == 'cells' else 'surface'}"))
        faces = np.asarray(usd_mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
        assert set(np.asarray(usd_mesh.GetFaceVertexCountsAttr().Get())) == {3}
        assert usd_mesh.GetPointsAttr().GetTimeSamples() == pytest.approx(codes)
        last = meshio.read(out / "meshes" / f"{m.name}_{len(run) - 1:05d}.ply")
        assert np.array_equal(faces, last.cells_dict["triangle"])
        for f, code in enumerate(codes):
            x = np.asarray(usd_mesh.GetPointsAttr().Get(code))
            assert np.array_equal(x, run.frame(f)["vertex_x"][a:b].astype(np.float32))
        assert np.array_equal(x, last.points.astype(np.float32))


def test_usd_reopen_drops_the_frames_after_the_checkpoint(tmp_path):
    """`pdmpm run --resume` continues the stage: the samples after the checkpoint's frame go, the frames computed
    again are added, and each frame has one sample."""
    from pdmpm_cli.io.usd import UsdBody, UsdWriter

    bodies = [UsdBody("a b", 0, 2, 0.01), UsdBody("a_b", 2, 3, 0.02)]  # names that need care as prim names
    path = tmp_path / "run.usd"
    writer = UsdWriter(path, fps=10.0, bodies=bodies, meshes=[])
    for f in range(5):
        writer.write_frame(f, 0.1 * f, {"particle_x": np.full((3, 3), float(f))})
    writer.close()  # a run killed after frame 4, its checkpoint at frame 2
    writer = UsdWriter.reopen(path, fps=10.0, bodies=bodies, meshes=[], frames=3)
    for f in (3, 4):
        writer.write_frame(f, 0.1 * f, {"particle_x": np.full((3, 3), 10.0 * f)})
    writer.close()
    stage = Usd.Stage.Open(str(path))
    for prim, n in (("/pdmpm/a_b/particles", 2), ("/pdmpm/a_b_2/particles", 1)):
        attr = UsdGeom.Points(stage.GetPrimAtPath(prim)).GetPointsAttr()
        assert attr.GetTimeSamples() == pytest.approx([0, 1, 2, 3, 4])
        assert [float(np.asarray(attr.Get(t))[0, 0]) for t in range(5)] == [0, 1, 2, 30, 40]
        assert len(attr.Get(0)) == n
    with pytest.raises(Exception, match="holds 5 of the 6 frames"):
        UsdWriter.reopen(path, fps=10.0, bodies=bodies, meshes=[], frames=6)


def test_fluid_bodies_export_their_reconstructed_surface_as_ply_and_usd(tmp_path):
    """A viscoelastic body gets a closed surface per frame, meshes/<body>_surface_NNNNN.ply and the USD prim
    fluid_surface with time-sampled points and faces (the topology changes); the surface encloses the particles'
    volume within 15 % (render draws the same reconstruction) and the USD faces equal the PLY's."""
    overrides = ("grid.cell_size=0.06", "bodies.0.geometry.spacing=0.03", "simulation.duration=0.1",
                 "output.usd=true", "output.meshes=true")
    prep = prepare(ROOT / "scenes" / "cream_pie.yaml", overrides)
    out = tmp_path / "out"
    out.mkdir()
    simulate(prep, out)
    name = prep.scene.bodies[0].name
    plys = sorted((out / "meshes").glob(f"{name}_surface_*.ply"))
    assert len(plys) == prep.plan.frames + 1
    stage = Usd.Stage.Open(str(out / "run.usd"))
    prim = UsdGeom.Mesh.Get(stage, f"/pdmpm/{name}/fluid_surface")
    volume = float(prep.model.particle_volume.sum())
    for k in (0, len(plys) - 1):
        ply = meshio.read(plys[k])
        tri = ply.cells_dict["triangle"]
        v = ply.points[tri]
        enclosed = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6
        assert enclosed == pytest.approx(volume, rel=0.15)
        code = k * 1.0
        np.testing.assert_array_equal(np.asarray(prim.GetFaceVertexIndicesAttr().Get(code)).reshape(-1, 3), tri)
        np.testing.assert_allclose(np.asarray(prim.GetPointsAttr().Get(code)), ply.points, atol=1e-6)
