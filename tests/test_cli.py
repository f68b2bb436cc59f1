"""End-to-end through the `pdmpm` console entry point: exit codes, messages, outputs on disk."""

import dataclasses
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from pdmpm_cli.errors import SimulationError
from pdmpm_cli.io.hdf5 import read_run
from pdmpm_cli.runner import prepare, simulate

ROOT = Path(__file__).resolve().parents[1]

SMALL = textwrap.dedent("""\
    name: small
    simulation:
      duration: 0.1
      fps: 20
    grid:
      cell_size: 0.05
      domain: {min: [0, 0, 0], max: [0.8, 0.8, 0.8]}
    bodies:
      - name: block
        geometry:
          mode: cloud
          shape: {type: box, center: [0.4, 0.45, 0.4], size: [0.2, 0.2, 0.2]}
        material: {model: elastic, density: 1000, lam: 1e4, mu: 1e4}
    colliders:
      - {type: plane, point: [0, 0.3, 0], normal: [0, 1, 0], friction: 0.3}
    """)


def pdmpm(*args, cwd=ROOT):
    env = dict(os.environ, COLUMNS="200")
    return subprocess.run([sys.executable, "-m", "pdmpm_cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, env=env, timeout=600)


@pytest.fixture
def small_scene(tmp_path):
    path = tmp_path / "small.yaml"
    path.write_text(SMALL)
    return path


def test_run_writes_hdf5_and_vtk(small_scene, tmp_path):
    out = tmp_path / "out"
    r = pdmpm("run", small_scene, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    run = read_run(out / "run.h5")
    assert len(run) == 3 and run.times.tolist() == pytest.approx([0.0, 0.05, 0.1])
    assert run.scene_text == SMALL and run.plan["particles"] == run.frame(-1)["particle_x"].shape[0]
    assert run.frame(-1)["particle_x"][:, 1].mean() < run.frame(0)["particle_x"][:, 1].mean()  # it fell
    pvd = (out / "vtk" / "particles.pvd").read_text()
    assert pvd.count("<DataSet") == 3 and (out / "vtk" / "frame_00002.vtu").exists()
    again = pdmpm("run", small_scene, "--out", out, "--quiet")
    assert again.returncode == 2 and "--overwrite" in again.stderr
    assert pdmpm("run", small_scene, "--out", out, "--quiet", "--overwrite").returncode == 0


def test_validate_misspelt_key_exit_2_with_position(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(SMALL.replace("density: 1000", "densty: 1000"))
    r = pdmpm("validate", path)
    assert r.returncode == 2
    assert f"{path}:13:" in r.stderr and "bodies.0.material.densty: unknown key (did you mean density?)" in r.stderr
    assert "Traceback" not in r.stderr


def test_validate_explain_prints_plan(small_scene):
    r = pdmpm("validate", small_scene, "--explain", "--set", "simulation.dt=1.0")
    assert r.returncode == 0, r.stderr
    for text in ("phases per step: fbar -> bonds:elastic -> collider_penalty -> p2g -> grid_update -> g2p", "backend: cpu", "E_eff",
                 "bond_nbr", "rule: conservative; binding: bonds",
                 "warning: simulation.dt = 1 s is above the stability bound"):
        assert text in r.stdout


def test_validate_limits_prints_the_predicted_stability_limits(small_scene):
    r = pdmpm("validate", small_scene, "--limits")
    assert r.returncode == 0, r.stderr
    assert "predicted stability limits" in r.stdout and "grid, 2 / omega_max" in r.stdout
    grid = next(line for line in r.stdout.splitlines() if "grid, 2 / omega_max" in line)
    assert float(grid.split("│")[-2]) > 3  # the step used is well below the grid's limit


def test_override_is_validated(small_scene):
    r = pdmpm("validate", small_scene, "--set", "bodies.0.material.lam=-5")
    assert r.returncode == 2 and "--set bodies.0.material.lam" in r.stderr


def test_schema_is_json_with_units():
    r = pdmpm("schema")
    assert r.returncode == 0 and '"cell_size"' in r.stdout and "[m]" in r.stdout


def test_missing_mesh_exit_2(tmp_path):
    path = tmp_path / "mesh.yaml"
    path.write_text(SMALL.replace("{type: box, center: [0.4, 0.45, 0.4], size: [0.2, 0.2, 0.2]}",
                                  "{type: mesh, path: nothere.obj}"))
    r = pdmpm("validate", path)
    assert r.returncode == 2 and "nothere.obj" in r.stderr and "Traceback" not in r.stderr


def test_body_outside_domain_exit_2(small_scene):
    r = pdmpm("validate", small_scene, "--set", "bodies.0.geometry.shape.center=[0.75, 0.45, 0.4]")
    assert r.returncode == 2 and "enlarge grid.domain" in r.stderr


def test_blow_up_stops_run_and_keeps_written_frames(small_scene, tmp_path):
    """A forced oversize step: SimulationError (exit 1 in the CLI), frames written before it stay readable."""
    prep = prepare(small_scene, ["simulation.duration=2.0"])
    prep.plan = dataclasses.replace(prep.plan, dt_max=20 * prep.plan.dt_max, dt_cfl=20 * prep.plan.dt_cfl)
    with pytest.raises(SimulationError):
        simulate(prep, tmp_path / "blow")
    run = read_run(tmp_path / "blow" / "run.h5")
    assert len(run) >= 1 and run.frame(0)["particle_x"].shape[1] == 3


def test_failed_simulation_exits_1(small_scene, tmp_path, monkeypatch, capsys):
    """The CLI maps SimulationError to exit code 1 and prints the message without a traceback."""
    import pdmpm_cli.runner
    from pdmpm_cli.cli.app import main

    def boom(*args, **kwargs):
        raise SimulationError("NaN or infinite values at step 7")

    monkeypatch.setattr(pdmpm_cli.runner, "simulate", boom)
    monkeypatch.setattr(sys, "argv", ["pdmpm", "run", str(small_scene), "--out", str(tmp_path / "o"), "--quiet"])
    with pytest.raises(SystemExit) as exc:
        main()
    assert exc.value.code == 1 and "NaN or infinite values at step 7" in capsys.readouterr().err


def test_mesh_body_relative_to_scene_file(tmp_path):
    """A cloud body filling a closed OBJ given relative to the scene file; particle volume matches the mesh."""
    import shutil

    shutil.copy(ROOT / "tests" / "data" / "unit_cube.obj", tmp_path / "cube.obj")
    path = tmp_path / "mesh.yaml"
    path.write_text(SMALL.replace("{type: box, center: [0.4, 0.45, 0.4], size: [0.2, 0.2, 0.2]}",
                                  "{type: mesh, path: cube.obj, scale: 0.2, translate: [0.3, 0.35, 0.3]}"))
    prep = prepare(path)
    volume = prep.model.particle_volume.sum()
    assert volume == pytest.approx(0.2**3, rel=0.03)
    assert prep.model.rest_x.min(axis=0) == pytest.approx([0.3, 0.35, 0.3], abs=0.025)


def test_bundled_cloth_scene_writes_moving_meshes(tmp_path):
    """scenes/cloth_pegs.yaml (shell mode, vertex pins, wind) runs; its PLY surfaces move with the particles."""
    import meshio

    scene = Path(__file__).parents[1] / "scenes" / "cloth_pegs.yaml"
    out = tmp_path / "cloth"
    r = pdmpm("run", scene, "--out", out, "--quiet", "--set", "simulation.duration=0.06", "--set", "simulation.fps=50")
    assert r.returncode == 0, r.stderr
    run = read_run(out / "run.h5")
    plys = sorted((out / "meshes").glob("cloth_*.ply"))
    assert len(plys) == len(run) == 4
    first, last = meshio.read(plys[0]), meshio.read(plys[-1])
    assert len(first.points) == 441 and np.allclose(last.points, run.frame(-1)["vertex_x"])
    assert np.allclose(first.points, run.static["vertex_X"], atol=1e-9)
    pegs = run.static["vertex_X"][[20, 440]]
    assert np.abs(last.points[[20, 440]] - pegs).max() < 0.01  # held by the pegs
    assert last.points[:, 1].mean() < first.points[:, 1].mean() - 0.01  # the rest falls
