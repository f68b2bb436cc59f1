"""`pdmpm render`: PNG frames of small runs (particles, a cloth, Voronoi fragments, a fluid), options and errors."""

import importlib.util
import shutil
import sys

import numpy as np
import pytest
import yaml
from PIL import Image

from pdmpm_cli.cli.app import main
from pdmpm_cli.runner import prepare_scene, simulate
from pdmpm_cli.scene.schema import Scene
from tests.conftest import BASE, merge

GRAVITY = {"gravity": [0, -9.81, 0], "simulation": {"duration": 0.2, "fps": 20}}
SOFT = {"model": "elastic", "density": 1000.0, "lam": 1e4, "mu": 1e4}
DROP = merge(BASE, {**GRAVITY, "bodies": [{
    **BASE["bodies"][0], "geometry": {"mode": "cloud", "sampling": "lattice",
                                      "shape": {"type": "box", "center": [0.5, 0.45, 0.5], "size": [0.15] * 3}},
    "material": SOFT, "velocity": [0.5, 0, 0]}],
    "colliders": [{"type": "plane", "point": [0, 0.3, 0], "normal": [0, 1, 0]},
                  {"type": "sphere", "center": [0.65, 0.35, 0.5], "radius": 0.05}],
    "render": {"resolution": [320, 240]}})
CLOTH = merge(BASE, {**GRAVITY, "bodies": [{
    "name": "cloth", "material": SOFT,
    "geometry": {"mode": "shell", "layers": 1, "surface": {"type": "sheet", "center": [0.5, 0.6, 0.5],
                                                           "size": [0.3, 0.3], "rotation": [-90, 0, 0]}}}]})
VORONOI = merge(BASE, {**GRAVITY, "bodies": [{
    "name": "plate", "material": SOFT, "fracture": {"threshold": 0.01}, "velocity": [0, -3, 0],
    "geometry": {"mode": "voronoi", "count": 30, "shape": {"type": "box", "center": [0.5, 0.45, 0.5],
                                                           "size": [0.3, 0.06, 0.2]}}}],
    "colliders": [{"type": "plane", "point": [0, 0.3, 0], "normal": [0, 1, 0]}],
    "output": {"fields": ["particle_speed", "particle_damage"]}})
HONEY = merge(BASE, {**GRAVITY, "simulation": {"duration": 0.1, "fps": 20},
                     "grid": {"cell_size": 0.04, "domain": {"min": [0, 0, 0], "max": [0.6, 0.5, 0.6]}},
                     "bodies": [{"name": "honey", "geometry": {"mode": "cloud", "shape": {
                         "type": "sphere", "center": [0.3, 0.26, 0.3], "radius": 0.08}},
                         "material": {"model": "viscoelastic", "density": 1400.0, "lam": 2e4, "mu": 5e3,
                                      "relaxation_time": 0.02}}]})


def run_scene(folder, scene: dict):
    """Simulate `scene` into `folder` (in-process: no interpreter start-up per run)."""
    text = yaml.safe_dump(scene)
    simulate(prepare_scene(Scene.model_validate(scene), folder / "scene.yaml", text), folder)
    return folder


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    return {name: run_scene(root / name, scene)
            for name, scene in {"drop": DROP, "cloth": CLOTH, "voronoi": VORONOI, "honey": HONEY}.items()}


def pdmpm(monkeypatch, capsys, *args) -> tuple[int, str]:
    """Run the `pdmpm` entry point in-process; (exit code, stderr)."""
    monkeypatch.setattr(sys, "argv", ["pdmpm", *map(str, args)])
    with pytest.raises(SystemExit) as exc:
        main()
    return exc.value.code, capsys.readouterr().err


def pixels(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), dtype=float)


def coloured_fraction(path) -> float:
    """Share of strongly coloured pixels: the bodies (viridis); background, floor and colliders are greyish."""
    return float((np.asarray(Image.open(path).convert("HSV"))[..., 1] > 100).mean())


def test_particle_frames_move_at_scene_resolution(runs, monkeypatch, capsys):
    """One PNG per frame at the scene's render.resolution; consecutive frames differ (no repeated frame)."""
    code, err = pdmpm(monkeypatch, capsys, "render", runs["drop"], "--no-video")
    assert code == 0, err
    frames = sorted((runs["drop"] / "frames").glob("frame_*.png"))
    assert len(frames) == 5 and "5 frames" in err and "s per frame" in err
    images = [pixels(f) for f in frames]
    assert images[0].shape == (240, 320, 3)
    assert all(np.abs(a - b).mean() > 0.05 for a, b in zip(images, images[1:]))
    assert coloured_fraction(frames[-1]) > 0.01


def test_frames_slice_resolution_and_video(runs, monkeypatch, capsys, tmp_path):
    """--frames 1::2 of 5 frames renders frames 1 and 3, at --resolution, into --out; the video goes there too and
    the run folder's own video (of an earlier render) is left alone."""
    (runs["drop"] / "animation.gif").write_bytes(b"earlier")
    out = tmp_path / "pictures"
    code, err = pdmpm(monkeypatch, capsys, "render", runs["drop"], "--frames", "1::2", "--resolution", "160x120",
                      "--out", out, "--fps", "5")
    assert code == 0, err
    assert sorted(p.name for p in out.glob("*.png")) == ["frame_00001.png", "frame_00003.png"]
    assert Image.open(out / "frame_00001.png").size == (160, 120)
    if importlib.util.find_spec("imageio") and importlib.util.find_spec("imageio_ffmpeg"):
        assert (out / "animation.mp4").stat().st_size > 0
    else:
        assert Image.open(out / "animation.gif").n_frames == 2
    assert (runs["drop"] / "animation.gif").read_bytes() == b"earlier"
    assert not (runs["drop"] / "animation.mp4").exists()


def test_shell_renders_its_surface(runs):
    """A cloth is drawn as its smooth-shaded surface mesh, not as particles."""
    from pdmpm_cli.render.fields import field_values
    from pdmpm_cli.render.run import render_run
    from pdmpm_cli.render.scene import body_layers
    from pdmpm_cli.render.source import open_run

    source = open_run(runs["cloth"])
    assert len(source.meshes) == 1 and not source.meshes[0].is_cells
    frame = source.read(-1)
    surface = body_layers(source)[0].build(frame, field_values(source, "speed", frame))
    assert surface.n_cells == len(source.meshes[0].faces) // 4 and "Normals" in surface.point_data
    result = render_run(runs["cloth"], frames="-1", resolution=(320, 240), video=False)
    assert coloured_fraction(result.images[0]) > 0.02


def test_voronoi_renders_cell_polyhedra(runs):
    """Voronoi cells are solid polyhedra coloured per cell, also when only the VTK and PLY files are left."""
    from pdmpm_cli.render.fields import field_values
    from pdmpm_cli.render.run import render_run
    from pdmpm_cli.render.scene import body_layers
    from pdmpm_cli.render.source import open_run

    vtk_only = runs["voronoi"].parent / "voronoi_vtk"
    for sub in ("vtk", "meshes"):
        shutil.copytree(runs["voronoi"] / sub, vtk_only / sub)
    for folder in (runs["voronoi"], vtk_only):
        source = open_run(folder)
        assert [m.is_cells for m in source.meshes] == [True]
        assert len(np.unique(source.meshes[0].owner)) == 30  # every cell owns its faces
        frame = source.read(-1)
        cells = body_layers(source)[0].build(frame, field_values(source, "damage", frame))
        assert len(cells.cell_data["value"]) == cells.n_cells > 30 * 4
    result = render_run(vtk_only, field="damage", frames="-1", resolution=(320, 240), video=False)
    assert coloured_fraction(result.images[0]) > 0.01


def test_fluid_renders_a_surface(runs):
    """A viscoelastic body becomes one closed surface enclosing about its particles' volume."""
    from pdmpm_cli.render.run import render_run
    from pdmpm_cli.io.surface import fluid_surface
    from pdmpm_cli.render.source import open_run

    source = open_run(runs["honey"])
    surface = fluid_surface(source.read(-1).x, source.particle_volume, source.bodies[0].spacing)
    assert surface.n_cells > 100 and surface.n_open_edges == 0
    assert surface.volume == pytest.approx(source.particle_volume.sum(), rel=0.2)
    result = render_run(runs["honey"], frames="-1", resolution=(320, 240), video=False)
    assert coloured_fraction(result.images[0]) > 0.02


def test_missing_field_exit_2(runs, monkeypatch, capsys):
    code, err = pdmpm(monkeypatch, capsys, "render", runs["drop"], "--field", "damage")
    assert code == 2
    assert "no particle_damage" in err and "available: speed, body" in err and "output.fields" in err


def test_missing_outdir_exit_2(tmp_path, monkeypatch, capsys):
    code, err = pdmpm(monkeypatch, capsys, "render", tmp_path / "nothere")
    assert code == 2 and "nothere" in err and "pdmpm run" in err and "Traceback" not in err


def test_contact_sheet_tiles_with_captions(tmp_path):
    from pdmpm_cli.render.sheet import contact_sheet

    paths = []
    for k in range(4):
        paths.append(tmp_path / f"{k}.png")
        Image.new("RGB", (80, 60), (60 * k, 0, 0)).save(paths[-1])
    sheet = Image.open(contact_sheet(paths, ["a", "b", "c", "d"], tmp_path / "sheet.png", columns=3))
    assert sheet.size[0] == 3 * 80 and sheet.size[1] > 2 * 60


def test_camera_without_a_direction_exit_2_and_no_frame(runs, monkeypatch, capsys, tmp_path):
    """Position at the focus, or up along the view: refused before any frame is drawn (no blank PNG)."""
    out = tmp_path / "pictures"
    for camera in ("0.5,0.5,0.5;0.5,0.5,0.5", "0.5,1.5,0.5;0.5,0.5,0.5"):
        code, err = pdmpm(monkeypatch, capsys, "render", runs["drop"], "--camera", camera, "--out", out)
        assert code == 2 and f"--camera '{camera}': " in err and "Traceback" not in err and "Warning" not in err
    assert not out.exists()
