"""Checkpoints and `pdmpm run --resume`: a run killed mid-frame resumes to the frames of an uninterrupted run,
bit for bit; a changed scene, a corrupt checkpoint or run file, and a second run into the folder are refused."""

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numba
import numpy as np
import pytest

from pdmpm_cli.checkpoint import latest
from pdmpm_cli.engine.solver import Solver
from pdmpm_cli.io.hdf5 import read_run
from pdmpm_cli.io.lock import LOCK_NAME, OutputLock
from pdmpm_cli.io.vtk import read_pvd
from pdmpm_cli.runner import prepare, simulate
from tests.test_cli import SMALL

ROOT = Path(__file__).resolve().parents[1]
LONG = ["simulation.duration=0.75", "simulation.fps=40", "output.checkpoint_every=3"]  # 30 frames, 22 steps each


def cli(monkeypatch, capsys, *args) -> tuple[int, str]:
    """Run the pdmpm CLI in this process; (exit code, stderr)."""
    from pdmpm_cli.cli.app import main

    monkeypatch.setattr(sys, "argv", ["pdmpm", *map(str, args)])
    with pytest.raises(SystemExit) as exc:
        main()
    return exc.value.code or 0, capsys.readouterr().err


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("scene") / "small.yaml"
    path.write_text(SMALL)
    return path


@pytest.fixture(scope="module")
def reference(scene, tmp_path_factory) -> Path:
    """The uninterrupted run, in this process."""
    out = tmp_path_factory.mktemp("reference")
    simulate(prepare(scene, LONG), out, overwrite=True)
    return out


def stopping_after(frames: int):
    """Solver.advance that stops the run past frame `frames` as Ctrl-C would (KeyboardInterrupt)."""
    advance = Solver.advance

    def stop(self, state, t_end, on_substep=None):
        if t_end > (frames + 0.5) * self.plan.frame_dt:
            raise KeyboardInterrupt
        advance(self, state, t_end, on_substep)

    return stop


def interrupt(scene, overrides, out, frames: int) -> None:
    """Run `scene` with `overrides` into `out` and stop it past frame `frames` as Ctrl-C would."""
    advance = Solver.advance
    Solver.advance = stopping_after(frames)
    try:
        with pytest.raises(KeyboardInterrupt):
            simulate(prepare(scene, overrides), out, overwrite=True)
    finally:
        Solver.advance = advance


@pytest.fixture(scope="module")
def interrupted(scene, tmp_path_factory) -> Path:
    """A run stopped after frame 8 (checkpoints at frames 3 and 6), in this process: a template to copy."""
    out = tmp_path_factory.mktemp("interrupted") / "run"
    interrupt(scene, LONG, out, 8)
    return out


def copy_of(run: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(run, tmp_path / "run"))


def assert_same_frames(a: Path, b: Path):
    ra, rb = read_run(a / "run.h5"), read_run(b / "run.h5")
    assert len(ra) == len(rb) == 31 and ra.field_names == rb.field_names
    assert np.array_equal(ra.times, rb.times)
    for name in ra.field_names:
        assert np.array_equal(ra.field(name), rb.field(name)), name
    assert read_pvd(a / "vtk" / "particles.pvd") == read_pvd(b / "vtk" / "particles.pvd")
    assert (a / "vtk" / "frame_00030.vtu").read_bytes() == (b / "vtk" / "frame_00030.vtu").read_bytes()


def test_sigkill_mid_frame_then_resume_matches_uninterrupted_run(scene, reference, tmp_path):
    out = tmp_path / "killed"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
               NUMBA_NUM_THREADS=str(numba.get_num_threads()))  # the reference's thread count: identical sums
    sets = [a for item in LONG for a in ("--set", item)]
    proc = subprocess.Popen([sys.executable, "-m", "pdmpm_cli", "run", scene, "--out", out, "--quiet", *sets],
                            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None:
            if (out / "checkpoints" / "frame_00006.h5").exists():
                break
            time.sleep(0.005)
        assert proc.poll() is None, f"the run ended before it could be killed: {proc.stderr.read()}"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    # everything written before the kill is readable, and no file is corrupt
    frames = len(read_run(out / "run.h5"))
    assert 7 <= frames < 31
    assert [name for _, name in read_pvd(out / "vtk" / "particles.pvd")] == [
        f"frame_{i:05d}.vtu" for i in range(len(read_pvd(out / "vtk" / "particles.pvd")))]
    assert all((out / "vtk" / name).is_file() for _, name in read_pvd(out / "vtk" / "particles.pvd"))
    assert latest(out).frame in (6, 9)
    assert (out / LOCK_NAME).exists()  # left by the killed run: it must not block the resume
    r = subprocess.run([sys.executable, "-m", "pdmpm_cli", "run", "--resume", out, "--quiet"], cwd=ROOT, env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "resuming from frame 6" in r.stderr or "resuming from frame 9" in r.stderr
    assert_same_frames(reference, out)
    assert sorted(p.name for p in out.iterdir()) == ["run.h5", "vtk"]  # no checkpoints or lock left


def test_resume_with_the_scene_given_matches(scene, interrupted, reference, tmp_path, monkeypatch, capsys):
    """The scene named again, with the same values; a new checkpoint interval is allowed."""
    out = copy_of(interrupted, tmp_path)
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["frame_00003.h5", "frame_00006.h5"]
    assert len(read_run(out / "run.h5")) == 9
    sets = [a for item in [*LONG[:2], "output.checkpoint_every=4"] for a in ("--set", item)]
    code, err = cli(monkeypatch, capsys, "run", scene, "--resume", out, "--quiet", *sets)
    assert code == 0, err
    assert "resuming from frame 6 (t = 0.15 s, step 114)" in err  # 132 with jittered sampling: a smaller dt_bond
    assert_same_frames(reference, out)
    code, err = cli(monkeypatch, capsys, "run", "--resume", out)
    assert code == 2 and "the run is complete" in err


def test_resume_refuses_a_changed_scene(interrupted, tmp_path, monkeypatch, capsys):
    out = copy_of(interrupted, tmp_path)
    changed = tmp_path / "changed.yaml"
    changed.write_text(SMALL.replace("mu: 1e4", "mu: 2e4"))
    code, err = cli(monkeypatch, capsys, "run", changed, "--resume", out, *(a for s in LONG for a in ("--set", s)))
    assert code == 2
    assert "the scene differs from the one the run" in err and "bodies.0.material.mu: 10000.0 -> 20000.0" in err
    code, err = cli(monkeypatch, capsys, "run", changed, "--resume", out, "--overwrite")
    assert code == 2 and "leave out --overwrite and --out" in err


def test_corrupt_checkpoint_and_run_file_exit_2(interrupted, tmp_path, monkeypatch, capsys):
    out = copy_of(interrupted, tmp_path)
    newest = out / "checkpoints" / "frame_00006.h5"
    with open(newest, "r+b") as f:
        f.truncate(newest.stat().st_size // 2)
    code, err = cli(monkeypatch, capsys, "run", "--resume", out)
    assert code == 2 and "frame_00006.h5: cannot read the checkpoint" in err
    assert "delete it to resume from frame_00003.h5" in err and "Traceback" not in err
    newest.unlink()
    run_h5 = out / "run.h5"
    with open(run_h5, "r+b") as f:
        f.truncate(run_h5.stat().st_size // 3)
    code, err = cli(monkeypatch, capsys, "run", "--resume", out)
    assert code == 2 and "run.h5" in err and "truncated or corrupt" in err
    code, err = cli(monkeypatch, capsys, "render", out, "--no-video")
    assert code == 2 and "run.h5" in err and "truncated or corrupt" in err


def test_second_run_into_a_folder_in_use_is_refused(scene, tmp_path, monkeypatch, capsys):
    out = tmp_path / "busy"
    with OutputLock(out):
        code, err = cli(monkeypatch, capsys, "run", scene, "--out", out, "--quiet")
        assert code == 2 and "another pdmpm run is writing to this folder (pid" in err
    assert not (out / LOCK_NAME).exists()
    with OutputLock(out):  # released: it can be taken again
        pass


def _child_env() -> dict:
    return dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
                NUMBA_NUM_THREADS=str(numba.get_num_threads()))  # the reference's thread count: identical sums


def _file_size_limit(limit: int):
    """For a child process: `ulimit -f` (Python ignores SIGXFSZ, so a write past it fails with EFBIG)."""
    import resource

    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


def test_full_disk_ends_the_run_with_exit_1_and_resume_matches(scene, reference, tmp_path):
    """A file-size limit stands for a full disk: run.h5 cannot grow past about 1 MB (the checkpoints, 0.4 MB,
    still fit). The run stops with exit 1 and a message naming run.h5 and the --resume command; the frames written
    before stay readable, the file closes cleanly (no segmentation fault), and --resume without the limit finishes
    with the frames of the uninterrupted run, bit for bit."""
    out = tmp_path / "full"
    sets = [a for item in LONG for a in ("--set", item)]
    r = subprocess.run([sys.executable, "-m", "pdmpm_cli", "run", scene, "--out", out, "--quiet", *sets], cwd=ROOT,
                       env=_child_env(), capture_output=True, text=True, timeout=300,
                       preexec_fn=_file_size_limit(1_000_000))
    assert r.returncode == 1, r.stderr
    assert f"error: {out / 'run.h5'}: failed writing frame " in r.stderr
    assert "cannot grow the file by" in r.stderr and "(file too large)" in r.stderr
    assert f"the frames written before are complete and readable; once there is room, continue it with: pdmpm run " \
           f"--resume {out}" in r.stderr and "Traceback" not in r.stderr
    written = read_run(out / "run.h5")
    assert 7 <= len(written) < 31
    assert np.array_equal(written.field("particle_x"), read_run(reference / "run.h5").field("particle_x")[:len(written)])
    with h5py.File(out / "run.h5", "r") as f:  # closed cleanly: a plain read-only open works (no SWMR flag left)
        assert f.attrs["frames_complete"] == len(written)
    assert latest(out).frame in range(len(written) - 3, len(written))
    r = subprocess.run([sys.executable, "-m", "pdmpm_cli", "run", "--resume", out, "--quiet"], cwd=ROOT,
                       env=_child_env(), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert_same_frames(reference, out)


def test_an_error_inside_hdf5_exits_1_without_a_crash(scene, tmp_path):
    """With the reservation switched off, the file-size limit hits inside HDF5, whose state then cannot be closed
    (closing crashed the process with SIGSEGV, exit 139): the writer abandons the file and the run exits 1."""
    out = tmp_path / "hdf5"
    code = ("import pdmpm_cli.io.hdf5 as h; h.reserve = lambda *a: None; "
            "from pdmpm_cli.cli.app import main; main()")
    sets = [a for item in LONG for a in ("--set", item)]
    r = subprocess.run([sys.executable, "-c", code, "run", scene, "--out", out, "--quiet", *sets], cwd=ROOT,
                       env=_child_env(), capture_output=True, text=True, timeout=300,
                       preexec_fn=_file_size_limit(1_000_000))
    assert r.returncode == 1, r.stderr
    assert "file too large (inside HDF5: " in r.stderr and "run.h5 is left as HDF5 had it" in r.stderr
    assert "start it again with --overwrite" in r.stderr and "Traceback" not in r.stderr


def test_sigterm_stops_like_ctrl_c(scene, tmp_path):
    """SIGTERM (a batch system's stop) ends the run between two substeps: exit 143, the same message as Ctrl-C, the
    frames and checkpoints kept, the folder's lock released."""
    out = tmp_path / "term"
    sets = [a for item in LONG for a in ("--set", item)]
    proc = subprocess.Popen([sys.executable, "-m", "pdmpm_cli", "run", scene, "--out", out, "--quiet", *sets],
                            cwd=ROOT, env=_child_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None and not (out / "checkpoints").is_dir():
            time.sleep(0.005)
        assert proc.poll() is None, f"the run ended before it could be stopped: {proc.stderr.read()}"
        proc.send_signal(signal.SIGTERM)
        err = proc.communicate(timeout=120)[1]
    finally:
        proc.kill()
    assert proc.returncode == 143, err
    assert f"continue it with: pdmpm run --resume {out}\nterminated (SIGTERM): frames written so far are complete " \
           f"and readable" in err and "Traceback" not in err
    assert len(read_run(out / "run.h5")) >= 4 and latest(out).frame >= 3
    assert not (out / LOCK_NAME).exists()


def test_resume_into_a_folder_in_use_says_nothing_of_resuming(interrupted, tmp_path, monkeypatch, capsys):
    out = copy_of(interrupted, tmp_path)
    with OutputLock(out):
        code, err = cli(monkeypatch, capsys, "run", "--resume", out, "--quiet")
    assert code == 2 and "another pdmpm run is writing to this folder (pid" in err
    assert "resuming" not in err


def test_checkpoints_keep_the_thread_count_the_run_started_with(interrupted, tmp_path, monkeypatch, capsys):
    """A resumed run writes the original run's thread count into its checkpoints, so a second resume warns with
    the count an uninterrupted run had, not the last segment's."""
    out = copy_of(interrupted, tmp_path)
    with h5py.File(out / "checkpoints" / "frame_00006.h5", "r+") as f:
        f.attrs["threads"] = 7  # as if the run had started with 7 threads
    monkeypatch.setattr(Solver, "advance", stopping_after(12))
    code, err = cli(monkeypatch, capsys, "run", "--resume", out, "--quiet")
    assert code == 130 and "the run started with 7 Numba threads" in err
    assert latest(out).frame == 12 and latest(out).attrs["threads"] == 7


def interrupt_and_resume(scene, overrides, tmp_path, monkeypatch, capsys):
    """The uninterrupted run with `overrides`, and the same stopped after frame 8 then resumed through the CLI; the
    checkpoint it resumed from."""
    reference = tmp_path / "reference"
    simulate(prepare(scene, overrides), reference, overwrite=True)
    out = tmp_path / "run"
    interrupt(scene, overrides, out, 8)
    ckpt = latest(out)
    code, err = cli(monkeypatch, capsys, "run", scene, "--resume", out, "--quiet",
                    *[a for item in overrides for a in ("--set", item)])
    assert code == 0, err
    assert_same_frames(reference, out)
    return ckpt


def test_plastic_run_resumes_bitwise_with_its_reverse_bonds(scene, tmp_path, monkeypatch, capsys):
    """A yielding plastic block: the checkpoint carries bond_reverse with e_p (format 4), and the resumed run ends on
    the uninterrupted run's frames."""
    plastic = [*LONG, "bodies.0.material.model=plastic", "bodies.0.material.yield_stress=300"]
    ckpt = interrupt_and_resume(scene, plastic, tmp_path, monkeypatch, capsys)
    assert "bond_reverse" in ckpt.arrays and np.count_nonzero(ckpt.arrays["bond_ep"]) > 0


def test_cracking_run_resumes_bitwise_with_its_crack_fields(scene, tmp_path, monkeypatch, capsys):
    """A block that cracks on landing, with crack fields (contact.cracks auto): the checkpoint carries the broken
    bonds, the resumed run rebuilds the crack directions, pieces and dust from them, and ends on the uninterrupted
    run's frames."""
    cracking = [*LONG, "bodies.0.fracture.threshold=0.002"]
    assert prepare(scene, cracking).model.crack_bodies == (0,)
    ckpt = interrupt_and_resume(scene, cracking, tmp_path, monkeypatch, capsys)
    assert (ckpt.arrays["bond_active"] == 0).any()
