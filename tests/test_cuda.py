"""The CUDA backend against the CPU one, on numba's CUDA simulator (CI has no GPU).

The simulator must be switched on before numba.cuda is first imported, so everything that touches numba.cuda runs
in a subprocess with NUMBA_ENABLE_CUDASIM=1; this process never imports it. The simulator runs the kernels as
Python threads, so the scenes are tiny and short.

Tolerances. Both backends take the same steps and evaluate the same per-item formulae; they differ in the order of
P2G's atomic adds and in the side of a bond pair its force is evaluated from (the CPU scatters each pair once, the
GPU gathers both sides). The synthetic cases deform strongly, and agree to TOL relative. A body in free flight
(most bundled scenes in their first steps) has bond forces that are round-off of large cancelling terms (1e-16 of
lam / h per bond): the backends draw that noise differently, so velocities agree to FLIGHT_TOL of the largest speed
and positions to TOL of the body.
"""

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from pdmpm_cli.io.hdf5 import read_run
from pdmpm_cli.runner import prepare, prepare_scene, simulate
from pdmpm_cli.scene.schema import Scene
from tests.conftest import BASE, CUDA_COMPARE, CudaCompare, merge
from tests.cuda_compare import BUNDLED

ROOT = Path(__file__).resolve().parents[1]
TOL = 1e-12
FLIGHT_TOL = 1e-6


def python(*args, sim: bool, timeout=900, env=None):
    env = dict(os.environ, COLUMNS="200", NUMBA_ENABLE_CUDASIM="1" if sim else "0", **(env or {}))
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=ROOT, env=env,
                          timeout=timeout)


@pytest.fixture(scope="module")
def compared(request):
    """tests.cuda_compare on every case, once for the module: {case: measured differences}. The runs start in
    the background when the tests are collected (tests/conftest.py), or here under pytest-xdist."""
    runs = request.config.stash.get(CUDA_COMPARE, None)
    if runs is None:
        runs = request.config.stash[CUDA_COMPARE] = CudaCompare()
    rows = [json.loads(line) for line in runs.rows()]
    for row in rows:
        print(f"\n{row['case']}: {row['particles']} particles, {row['steps']} steps, |dx| {row['x_rel']:.1e}, "
              f"|dv| {row['v_rel']:.1e}, |dC| {row['c_rel']:.1e} (relative), arrays "
              f"{max(row['arrays_rel'].values(), default=0):.1e}")
    return {row["case"]: row for row in rows}


def assert_same(row, v_tol=TOL, x_tol=TOL):
    assert row["x_rel"] < x_tol and row["v_rel"] < v_tol and row["c_rel"] < v_tol
    assert row["vmax"][1] == pytest.approx(row["vmax"][0], rel=v_tol)  # hence the same time steps in a real run
    assert row["energy"][1] == pytest.approx(row["energy"][0], rel=v_tol)  # host diagnostics see the device state
    a, b = row["scalars"]
    assert a["step"] == b["step"] and a["bonds_cut"] == b["bonds_cut"]


def test_elastic_block_hitting_the_floor(compared):
    row = compared["elastic_floor"]
    assert row["phases"] == ["fbar", "bonds:elastic", "p2g", "grid_update", "g2p"]
    assert row["external_impulse"] > 5e-3 and row["displacement"] > 0.05  # the floor wall pushed back, it moved
    assert_same(row)


def test_plastic_slab_yields_alike(compared):
    row = compared["plastic_slab"]
    assert {"dilatation:plastic", "bonds:plastic"} <= set(row["phases"]) and row["yielded"] > 0.2
    assert row["arrays_rel"]["bond_ep"] < 1e-9  # e_p is a difference of nearly equal strains: round-off / yield strain
    assert row["yield_residual"][1] == pytest.approx(row["yield_residual"][0], abs=1e-12)
    assert row["yield_residual"][1] < 1e-9  # exactly back on the yield surface
    assert_same(row)


def test_collider_and_pins(compared):
    row = compared["collider_pins"]
    assert "fbar" not in row["phases"]  # mu = 0
    assert row["pinned"] > row["pin_stopped"] > 0 and row["pin_v_err"] == 0.0
    assert row["external_impulse"] > 1e-2
    assert_same(row)


def test_mesh_collider_alike(compared):
    row = compared["mesh_collider"]
    assert row["external_impulse"] > 1e-2  # the moving mesh stopped the block
    assert_same(row)


def test_penalty_collider_alike(compared):
    row = compared["penalty_floor"]
    assert "collider_penalty" in row["phases"] and row["external_impulse"] > 1e-3  # the floor pushed back
    assert_same(row)


@pytest.mark.parametrize("case", ["two_bodies", "penalty_contact"])
def test_two_bodies_in_contact_alike(compared, case):
    row = compared[case]
    assert "contact" in row["phases"] and row["exchanged"] > 0.01  # the bodies pushed each other
    assert_same(row)


@pytest.mark.parametrize("case", ["flip_pins", "flip_contact"])
def test_flip_share_alike(compared, case):
    row = compared[case]
    assert row["phases"][-2:] == ["g2p", "remap"]
    assert_same(row)


def test_viscoelastic_splat_rebuilds_alike(compared):
    row = compared["viscous_splat"]
    assert "families:viscoelastic" in row["phases"] and row["rebuilt"]
    assert max(row["arrays_rel"].values()) < 1e-12  # bond forces, formation lengths, families
    assert_same(row)


def test_liquid_shift_alike(compared):
    """The particle shift (shift:viscoelastic) moves the particles alike on both backends."""
    row = compared["liquid_shift"]
    assert row["phases"][-2:] == ["g2p", "shift:viscoelastic"] and row["shifted"] > 1e-4
    assert_same(row)


@pytest.mark.parametrize("case", BUNDLED)
def test_bundled_scene_matches_cpu(compared, case):
    """Every bundled scene, fracture (wall_break, thrown hard so that bonds break within the steps) and
    viscoelastic (honey, cream_pie) included."""
    row = compared[case]
    assert_same(row, v_tol=FLIGHT_TOL, x_tol=FLIGHT_TOL * 1e-3)
    if case == "wall_break":
        assert "crack" in row["phases"] and row["broken"] > 0 and row["crack_particles"] > 0
        assert row["arrays_rel"]["bond_active"] == 0 and row["arrays_rel"]["particle_damage"] < TOL


def test_kernels_compile_for_an_h100():
    """What the simulator cannot check: each kernel, with the argument types of real runs, compiles to PTX for
    sm_90 (needs the CUDA toolkit's NVVM, no GPU; skipped without it)."""
    r = python("-m", "tests.cuda_ptx", sim=False)
    if r.returncode == 3:
        pytest.skip(r.stderr.strip())
    assert r.returncode == 0, r.stderr[-3000:]
    compiled = {line.split(":")[0] for line in r.stdout.splitlines()}
    assert compiled == {"averaged_deformation_at", "elastic_force_at", "fbar_dilatation_at", "plastic_force_at",
                        "incremental_dilatation_at", "viscoelastic_force_at", "volume_pressure_at", "copy_row_at",
                        "grid_volume_ratio_at", "shift_at", "apply_shift_at", "penalty_at",
                        "zero_box", "p2g_kernel", "grid_update_kernel", "reset_stats", "g2p_kernel",
                        "crack_contact_kernel", "crack_update_kernel", "criterion_at", "zero_cells", "count_cells",
                        "cell_fraction", "field_bounds", "surface_kernel", "contact_kernel", "advect_kernel"}


TINY = textwrap.dedent("""\
    name: tiny
    simulation: {duration: 0.004, fps: 500}
    grid: {cell_size: 0.05, domain: {min: [0, 0, 0], max: [1, 1, 1]}}
    gravity: [0, -9.81, 0]
    bodies:
      - name: block
        geometry: {mode: cloud, sampling: lattice, spacing: 0.05,
                   shape: {type: box, center: [0.5, 0.3, 0.5], size: [0.15, 0.15, 0.15]}}
        material: {model: elastic, density: 1000, lam: 2e5, mu: 1e5}
        velocity: [0, -2, 0]
    """)


def test_run_with_backend_cuda_writes_the_cpu_frames(tmp_path):
    """`pdmpm run --backend cuda` end to end (simulator): frames from the device State match a CPU run."""
    scene = tmp_path / "tiny.yaml"
    scene.write_text(TINY)
    r = python("-m", "pdmpm_cli", "run", scene, "--out", tmp_path / "gpu", "--quiet", "--backend", "cuda", sim=True)
    assert r.returncode == 0, r.stderr
    assert "on cuda" in r.stderr
    simulate(prepare(scene), tmp_path / "cpu")
    gpu, cpu = read_run(tmp_path / "gpu" / "run.h5"), read_run(tmp_path / "cpu" / "run.h5")
    assert gpu.plan["backend"] == "cuda" and cpu.plan["backend"] == "cpu"
    assert len(gpu) == len(cpu) == 3 and gpu.times.tolist() == cpu.times.tolist()
    for f in (1, 2):
        np.testing.assert_allclose(gpu.frame(f)["particle_x"], cpu.frame(f)["particle_x"], rtol=0, atol=TOL)
        np.testing.assert_allclose(gpu.frame(f)["particle_v"], cpu.frame(f)["particle_v"], rtol=0, atol=2 * TOL)
    assert not np.allclose(gpu.frame(2)["particle_x"], gpu.frame(0)["particle_x"])


@pytest.mark.skipif(shutil.which("nvidia-smi") is not None, reason="this machine may have a GPU")
def test_cuda_without_gpu_is_an_input_error_and_cpu_never_imports_numba_cuda(tmp_path):
    scene = tmp_path / "tiny.yaml"
    scene.write_text(TINY)
    code = textwrap.dedent(f"""\
        import sys
        from pdmpm_cli.runner import prepare, simulate
        simulate(prepare({str(scene)!r}), __import__("pathlib").Path({str(tmp_path / "cpu")!r}))
        print("numba.cuda" in sys.modules)
        """)
    r = python("-c", code, sim=False)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"
    (tmp_path / "gpu").mkdir()
    (tmp_path / "gpu" / "keep.txt").write_text("an earlier run")
    r = python("-m", "pdmpm_cli", "run", scene, "--out", tmp_path / "gpu", "--overwrite", "--backend", "cuda",
               sim=False)
    assert r.returncode == 2
    assert "error: simulation.backend = cuda needs an NVIDIA GPU with a working CUDA driver, and numba.cuda finds " \
           "none; run with --backend cpu" in r.stderr
    assert (tmp_path / "gpu" / "keep.txt").exists()


def test_cuda_plan_has_no_per_thread_arrays(tmp_path):
    scene = merge(BASE, {"simulation": {"backend": "cuda"}, "bodies": [
        {**BASE["bodies"][0], "geometry": {**BASE["bodies"][0]["geometry"], "spacing": 0.05}}]})
    plan = prepare_scene(Scene.model_validate(scene), tmp_path / "s.yaml").plan
    assert plan.fields["grid_private"][0][0] == 0 and plan.fields["particle_force_private"][0][0] == 0
    assert plan.phases[-3:] == ("p2g", "grid_update", "g2p")


@pytest.mark.slow
def test_bench_cuda_runs_on_the_simulator():
    r = python("bench/bench_cuda.py", "--sizes", "60", "--steps", "2", "--profile", sim=True)
    assert r.returncode == 0, r.stderr
    assert "device: numba.cuda simulator" in r.stdout and "| 64 |" in r.stdout
