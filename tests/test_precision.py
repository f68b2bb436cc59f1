"""simulation.precision: float32 stores the per-particle and per-bond arrays in single precision (engine/fields.py,
Field.dtype_for), keeping positions, 1 / |xi|, Fbar and the grids in float64. Answers from physics: a body at rest
free of bond forces, a free fall against the parabola (Sulsky's bar: tests/test_dynamics.py); a checkpoint
resumes bitwise at float32 and refuses another precision; the CUDA backend (numba's simulator) runs float32 as the
CPU does."""

import numpy as np
import pytest

from pdmpm_cli.checkpoint import latest
from pdmpm_cli.io.hdf5 import read_run
from pdmpm_cli.runner import prepare, simulate
from pdmpm_cli.scene.loader import merge
from tests.test_checkpoint import LONG, cli, interrupt, interrupt_and_resume, scene  # noqa: F401 (scene: a fixture)
from tests.test_cuda import TINY, python

SINGLE = {"simulation": {"precision": "float32"}}


def test_float32_arrays_and_free_fall(sim_factory):
    """A jittered sphere falls 0.3 s: every particle at the half step's -g (t - dt / 2) to float32's round-off over
    its 867 steps, and so its centre of mass on the parabola to the same share of the drop (float64: exact); at rest
    it is free of bond forces, as in float64."""
    sim = sim_factory(merge(SINGLE, {
        "gravity": [0, -9.81, 0], "grid": {"domain": {"min": [0, -1, 0], "max": [1, 1, 1]}},
        "bodies": [{**sim_factory().scene.bodies[0].model_dump(),
                    "geometry": {"mode": "cloud", "sampling": "jittered",
                                 "shape": {"type": "sphere", "center": [0.5, 0.6, 0.5], "radius": 0.1}}}]}))
    dtypes = {name: a.dtype.str for name, a in sim.state.arrays.items()}
    assert {dtypes[n] for n in ("particle_v", "particle_C", "particle_force", "bond_wv")} == {"<f4"}
    assert {dtypes[n] for n in ("particle_x", "particle_Fbar", "bond_inv_len", "grid", "grid_private")} == {"<f8"}
    sim.solver.bond_forces(0.0)  # force-free at rest: K_p sums the stored (rounded) weights, 1 / |xi| is float64
    assert np.abs(sim.state.particle_force).max() < 1e-12 * 3e5 * sim.model.body_spacing[0] ** 2
    assert sim.plan.precision == "float32" and sim.plan.fields["particle_v"][1] == "f4"
    y0 = sim.com()[1]
    dts = []
    sim.advance(0.3, lambda s, dt: dts.append(dt))
    err = sim.com()[1] - (y0 - 0.5 * 9.81 * 0.3**2)
    print(f"\nfloat32 free fall: y_com - exact = {err:.3e} m")
    assert abs(err) <= 5e-5 * 0.5 * 9.81 * 0.3**2  # measured 2.9e-6 m, 6.6e-6 of the drop
    np.testing.assert_allclose(sim.state.particle_v[:, 1], -9.81 * (0.3 - dts[-1] / 2), rtol=5e-5)


def test_float32_checkpoint_resumes_bitwise_and_refuses_float64(scene, tmp_path, monkeypatch, capsys):
    """A float32 run stopped after frame 8 resumes to the uninterrupted run's frames; its checkpoint records the
    precision and holds float32 arrays; resuming it at float64 is bad input (exit 2) that says what to do."""
    single = [*LONG, "simulation.precision=float32"]
    ckpt = interrupt_and_resume(scene, single, tmp_path, monkeypatch, capsys)
    assert ckpt.attrs["precision"] == "float32"
    assert ckpt.arrays["particle_v"].dtype == np.float32 and ckpt.arrays["particle_x"].dtype == np.float64
    assert read_run(tmp_path / "run" / "run.h5").field("particle_v").dtype == np.float32
    out = tmp_path / "again"
    interrupt(scene, single, out, 4)
    assert latest(out).attrs["precision"] == "float32"
    code, err = cli(monkeypatch, capsys, "run", scene, "--resume", out, *(a for s in LONG for a in ("--set", s)))
    assert code == 2
    assert "was started with simulation.precision = float32" in err and "asks for float64" in err
    assert "--set simulation.precision=float32" in err and "Traceback" not in err


def test_float32_on_cuda_simulator_matches_the_cpu(tmp_path):
    """`pdmpm run --backend cuda` at float32 on numba's simulator: the kernels specialise on the float32 arrays as
    the CPU's do, and the frames agree with a CPU float32 run to float32's round-off."""
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY)
    sets = ["--set", "simulation.precision=float32"]
    r = python("-m", "pdmpm_cli", "run", path, "--out", tmp_path / "gpu", "--quiet", "--backend", "cuda", *sets,
               sim=True)
    assert r.returncode == 0, r.stderr
    simulate(prepare(path, ["simulation.precision=float32"]), tmp_path / "cpu")
    gpu, cpu = read_run(tmp_path / "gpu" / "run.h5"), read_run(tmp_path / "cpu" / "run.h5")
    assert gpu.plan["precision"] == cpu.plan["precision"] == "float32"
    assert len(gpu) == len(cpu) == 3
    for f in (1, 2):
        assert gpu.frame(f)["particle_v"].dtype == np.float32
        np.testing.assert_allclose(gpu.frame(f)["particle_x"], cpu.frame(f)["particle_x"], rtol=0, atol=1e-8)
        np.testing.assert_allclose(gpu.frame(f)["particle_v"], cpu.frame(f)["particle_v"], rtol=0, atol=1e-6)


@pytest.mark.slow
def test_float32_kernels_compile_for_an_h100():
    """What the simulator cannot check (tests/test_cuda.py's PTX test, at float32): every kernel the CUDA backend
    launches compiles to PTX for sm_90 with float32 particle and bond arrays (needs NVVM; skipped without it)."""
    r = python("-m", "tests.cuda_ptx", "--precision", "float32", sim=False)
    if r.returncode == 3:
        pytest.skip(r.stderr.strip())
    assert r.returncode == 0, r.stderr[-3000:]
    assert len([line for line in r.stdout.splitlines() if line.endswith("characters of PTX")]) == 27
