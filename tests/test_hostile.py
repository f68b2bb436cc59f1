"""Hostile input and faults: every bad file refused quickly with file:line:col, key and fix; bounded loader work;
memory, frame and output-size budgets; output folders that cannot be written; an injected full disk."""

import errno
import os
import resource
import subprocess
import sys
import textwrap
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import yaml

from pdmpm_cli import budget, runner
from pdmpm_cli.errors import InputError, OutputError
from pdmpm_cli.io.hdf5 import Hdf5RunWriter, read_run
from pdmpm_cli.render.options import parse_camera
from pdmpm_cli.runner import prepare
from pdmpm_cli.scene.loader import SceneError, load_scene, parse_overrides
from pdmpm_cli.scene.schema import Scene
from tests.test_cli import SMALL
from tests.test_io import PLAN, SCENE, make_frame, make_static

ROOT = Path(__file__).resolve().parents[1]


def cli(monkeypatch, capsys, *args) -> tuple[int, str]:
    """Run the pdmpm CLI in this process; (exit code, stderr)."""
    from pdmpm_cli.cli.app import main

    monkeypatch.setattr(sys, "argv", ["pdmpm", *map(str, args)])
    with pytest.raises(SystemExit) as exc:
        main()
    return exc.value.code or 0, capsys.readouterr().err


def refusal(path: Path, text: str | None = None, **kwargs) -> str:
    """The message load_scene refuses `text` (written to `path`) with."""
    if text is not None:
        path.write_text(text)
    with pytest.raises(SceneError) as info:
        load_scene(path, Scene, **kwargs)
    return str(info.value)


def laughs(levels: int) -> str:
    """A 'billion laughs' variant: each anchor is a list of nine aliases of the previous one (9^levels leaves)."""
    lines = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, levels)]
    return SMALL + "variants:\n  boom:\n" + "".join(f"    {line}\n" for line in lines)


# ---------------------------------------------------------------- 1, 7, 8: the loader's bounds


def test_billion_laughs_is_refused_at_the_alias_before_memory_grows(tmp_path):
    tracemalloc.start()
    message = refusal(tmp_path / "laughs.yaml", laughs(9))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert message == (f"{tmp_path / 'laughs.yaml'}:18:23 variants.boom.a5.0.3.3.6.6.3: aliases expand to more than "
                       f"100,000 YAML nodes; write the values out or use fewer aliases")
    assert peak < 200 * 2**20  # 9^9 = 3.9e8 leaves would need tens of GB (wall times: bench/hostile_inputs.py)


def test_validate_refuses_hostile_files_within_1_gb(tmp_path):
    """The command end to end, in a child whose own peak memory (ru_maxrss) is read."""
    (tmp_path / "laughs.yaml").write_text(laughs(9))
    probe = textwrap.dedent("""\
        import resource, subprocess, sys
        r = subprocess.run([sys.executable, "-m", "pdmpm_cli", "validate", sys.argv[1]], capture_output=True, text=True)
        print(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024)
        print(r.stderr)""")
    r = subprocess.run([sys.executable, "-c", probe, tmp_path / "laughs.yaml"], capture_output=True, text=True,
                       cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    code, peak = r.stdout.split("\n")[0].split()
    assert int(code) == 2 and "aliases expand to more than 100,000 YAML nodes" in r.stdout
    assert int(peak) < 2**30


def test_deep_nesting_is_refused_without_recursion(tmp_path):
    flow = SMALL + "variants:\n  x: " + "[" * 600 + "]" * 600 + "\n"
    assert refusal(tmp_path / "flow.yaml", flow) == f"{tmp_path / 'flow.yaml'}:17:68: nested deeper than 64 levels"
    block = SMALL + "description:\n" + "".join(" " * (i + 1) + "-\n" for i in range(600))
    assert refusal(tmp_path / "block.yaml", block) == f"{tmp_path / 'block.yaml'}:80:65: nested deeper than 64 levels"
    chain = SMALL + "variants:\n" + "".join(f"  a{i}: &a{i} [{f'*a{i - 1}' if i else 1}]\n" for i in range(80))
    assert refusal(tmp_path / "chain.yaml", chain).endswith(": aliases nest deeper than 64 levels; write the values "
                                                            "out or use fewer aliases")


def test_errors_are_capped_and_counted(tmp_path):
    path = tmp_path / "keys.yaml"
    path.write_text(SMALL + "".join(f"k{i}: {i}\n" for i in range(40_000)))
    lines = refusal(path).splitlines()
    assert len(lines) == 21 and lines[0].startswith(f"{path}:16:1 k0: unknown key (allowed keys: name, description,")
    assert lines[-1] == "... and 39980 more problems (fix the ones above and validate again)"
    path.write_text(SMALL + "".join(f"k{i}: {i}\n" for i in range(700_000)))
    assert refusal(path) == (f"{path}: larger than 1024 KiB; a scene is a short hand-written file (meshes go in their "
                             f"own files, named by geometry.shape.path)")


# ---------------------------------------------------------------- 2: a failed write (in-process, injected)


def test_injected_full_disk_stops_before_hdf5_and_keeps_the_frames(tmp_path, monkeypatch):
    """posix_fallocate fails as on a full disk: write_frame raises OutputError before HDF5 writes anything, the
    writer closes cleanly and every frame written before reads back."""
    path = tmp_path / "run.h5"
    writer = Hdf5RunWriter(path, scene_text=SCENE, plan=PLAN, static=make_static(), compression="none")
    frames = [make_frame(i) for i in range(4)]
    for i in range(3):
        writer.write_frame(i, 0.1 * i, frames[i])

    def full(fd, offset, length):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "posix_fallocate", full)
    with pytest.raises(OutputError, match=r"run\.h5: cannot grow the file by .* MiB \(no space left on device\)"):
        writer.write_frame(3, 0.3, frames[3])
    writer.close()
    run = read_run(path)
    assert len(run) == 3 and np.array_equal(run.frame(-1)["particle_x"], frames[2]["particle_x"])
    end = int.from_bytes(path.read_bytes()[28:36], "little")  # the superblock's end-of-file address
    assert path.stat().st_size == end  # the unused reservation is given back on close


# ---------------------------------------------------------------- 3: memory, estimated before sampling


def test_estimate_counts_match_the_sampled_scene():
    prep = prepare(ROOT / "scenes" / "elastic_drop.yaml")
    est = budget.estimate(prep.scene, ROOT / "scenes")
    assert est.particles == pytest.approx(prep.plan.particles, rel=0.05)
    assert est.bonds == pytest.approx(prep.plan.bonds, rel=0.3)


def test_a_scene_too_big_for_memory_is_refused_before_sampling(monkeypatch):
    monkeypatch.setattr(budget, "available_memory", lambda: 16 * 2**30)
    monkeypatch.setattr(runner, "discretize", lambda *a: pytest.fail("sampled"))  # 3.7e7 particles: minutes, 90 GB
    with pytest.raises(InputError) as info:
        prepare(ROOT / "scenes" / "elastic_drop.yaml", ["bodies.0.geometry.spacing=0.0009"])
    grid = budget.estimate(load_scene(ROOT / "scenes" / "elastic_drop.yaml", Scene)[0], ROOT).grid_bytes
    message = str(info.value).replace(f"grid {budget.gib(grid)}", "grid G")  # G depends on the thread count
    assert message == (
        f"{ROOT / 'scenes' / 'elastic_drop.yaml'}: the scene needs about 89.7 GiB of memory (3.7e+07 particles, "
        f"1.2e+09 bonds, grid G), but this machine has 16 GiB available; raise the particle spacing "
        f"(bodies.0.geometry.spacing = 0.00172 m instead of 0.0009 m, or the same factor 1.91 on every body), lower "
        f"geometry.horizon, or shrink the bodies")


# ---------------------------------------------------------------- 4: non-finite numbers


@pytest.mark.parametrize("old, new, where", [
    ("lam: 1e4", "lam: .inf", "13:52 bodies.0.material.lam"),
    ("duration: 0.1", "duration: .inf", "3:13 simulation.duration"),
    ("center: [0.4, 0.45, 0.4]", "center: [.nan, 0.45, 0.4]", "12:35 bodies.0.geometry.shape.center.0"),
    ("normal: [0, 1, 0]", "normal: [0, 1, 0], velocity: [0, -.inf, 0]", "15:72 colliders.0.velocity.1"),
    ("  - name: block\n", "  - name: block\n    velocity: [.inf, 0, 0]\n", "10:16 bodies.0.velocity.0"),
])
def test_non_finite_numbers_are_refused_where_written(tmp_path, old, new, where):
    path = tmp_path / "scene.yaml"
    got = "nan" if ".nan" in new else ("-inf" if "-.inf" in new else "inf")
    assert refusal(path, SMALL.replace(old, new)) == \
        f"{path}:{where}: must be a finite number, not .inf or .nan (got {got})"
    path.write_text(SMALL)
    assert refusal(path, overrides=["gravity=[0, .nan, 0]"]) == \
        "--set gravity.1: must be a finite number, not .inf or .nan (got nan)"


# ---------------------------------------------------------------- 5: absurd frame counts and outputs


def test_absurd_frame_count_is_refused(tmp_path):
    path = tmp_path / "scene.yaml"
    assert refusal(path, SMALL.replace("fps: 20", "fps: 1e9")) == (
        f"{path}:4:8 simulation.fps: 0.1 s at 1e+09 frames/s is 1e+08 frames, more than 100,000; lower fps (at most "
        f"1e+06 for this duration) (got 1000000000.0)")


def test_large_output_is_warned_and_a_full_disk_refused(tmp_path, monkeypatch):
    path = tmp_path / "scene.yaml"
    path.write_text(SMALL)
    prep = prepare(path, ["simulation.duration=100", "simulation.fps=1000"])  # 1e5 frames of 512 particles
    assert budget.warnings(prep) == ["the run writes 100001 frames of 512 particles, about 7.44 GiB before "
                                     "compression; lower simulation.fps or output.fields, or set output.vtk: false"]
    monkeypatch.setattr(os, "statvfs", lambda p: os.statvfs_result((4096, 4096, 0, 0, 1000, 0, 0, 0, 0, 255)))
    with pytest.raises(InputError, match=r"out: the run writes about 7.44 GiB \(100000 frames of 512 particles, "
                                         r"before compression\), but its disk has 3.91 MiB free; free some space"):
        budget.check_output(prep, tmp_path / "out")


# ---------------------------------------------------------------- 6: output folders that cannot be written


def test_out_that_is_a_file_or_under_a_file_exit_2(tmp_path, monkeypatch, capsys):
    scene = tmp_path / "scene.yaml"
    scene.write_text(SMALL)
    afile = tmp_path / "afile"
    afile.write_text("x")
    code, err = cli(monkeypatch, capsys, "run", scene, "--out", afile)
    assert code == 2 and f"error: {afile}: is a file, not a folder; give a folder for the outputs with --out" in err
    code, err = cli(monkeypatch, capsys, "run", scene, "--out", afile / "sub" / "out")
    assert code == 2 and f"{afile / 'sub' / 'out'}: {afile} is a file, so no folder can be made in it" in err


def test_out_without_write_permission_exit_2(tmp_path, monkeypatch, capsys):
    """A real read-only folder where permissions bind; as root (which writes anyway) the refusal is injected at
    the lock file, the first thing a run writes."""
    scene = tmp_path / "scene.yaml"
    scene.write_text(SMALL)
    locked = tmp_path / "locked"
    locked.mkdir()
    if os.geteuid() != 0:
        locked.chmod(0o500)
        code, err = cli(monkeypatch, capsys, "run", scene, "--out", locked / "out")
        locked.chmod(0o700)
        assert code == 2 and f"{locked / 'out'}: no permission to write in {locked}; choose another --out" in err
    real_open = os.open

    def denied(path, *args, **kwargs):
        if str(path).startswith(str(locked)):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(os, "open", denied)
    from pdmpm_cli.io.lock import OutputLock

    with pytest.raises(InputError, match=f"{locked}: cannot write in this folder \\(Permission denied\\); choose "
                                         f"another --out"):
        OutputLock(locked).acquire()


# ---------------------------------------------------------------- 9: spacing and tiny bodies


def test_spacing_above_the_cell_is_refused_and_tiny_bodies_warned(tmp_path):
    path = tmp_path / "scene.yaml"
    text = SMALL.replace("mode: cloud\n", "mode: cloud\n      spacing: 0.08\n")
    assert refusal(path, text) == (
        f"{path}:12:16 bodies.0.geometry.spacing: 0.08 m is larger than the grid cell (0.05 m): cells inside the body "
        f"would hold no particle; use at most 0.05 m, or leave spacing out for 0.025 m (2 particles per cell per "
        f"axis) (got 0.08)")
    path.write_text(SMALL.replace("mode: cloud\n", "mode: cloud\n      sampling: lattice\n      spacing: 0.05\n")
                    .replace("size: [0.2, 0.2, 0.2]", "size: [0.15, 0.15, 0.15]"))
    prep = prepare(path)
    assert prep.plan.particles == 27
    assert budget.warnings(prep) == ["body 'block' has only 27 particles (spacing 0.05 m): too few to bend or vibrate "
                                     "like a solid; lower bodies.0.geometry.spacing"]


# ---------------------------------------------------------------- 10: cameras without a direction


def test_camera_without_a_view_direction_is_refused(tmp_path):
    with pytest.raises(InputError) as info:
        parse_camera("1,1,1;1,1,1")
    assert str(info.value) == ("--camera '1,1,1;1,1,1': position and focus are the same point [1.0, 1.0, 1.0]: the "
                               "camera has no direction to look in; move the position away from the focus")
    with pytest.raises(InputError) as info:
        parse_camera("1,1,1;1,3,1")
    assert str(info.value) == ("--camera '1,1,1;1,3,1': up [0.0, 1.0, 0.0] is zero or along the view direction "
                               "[0.0, 2.0, 0.0]: the image has no up; give an up direction across the view, e.g. "
                               "[0, 1, 0] or [0, 0, 1]")
    assert parse_camera("1,1,1;1,3,1;0,0,1").up == (0.0, 0.0, 1.0)
    path = tmp_path / "scene.yaml"
    assert refusal(path, SMALL + "render:\n  camera: {position: [1, 1, 1], focus: [1, 1, 1]}\n").startswith(
        f"{path}:17:3 render.camera: position and focus are the same point")


# ---------------------------------------------------------------- 11: the small ones


def test_small_messages(tmp_path, monkeypatch, capsys):
    path = tmp_path / "scene.yaml"
    path.write_text(SMALL)
    code, err = cli(monkeypatch, capsys, "validate", path, "--set", "x:100:=1")
    assert code == 2 and "--set x:100:: unknown key" in err  # printed as text: rich would make :100: an emoji
    with pytest.raises(SceneError) as info:
        load_scene(ROOT / "scenes" / "cloth.yaml", Scene, variant="sofft")
    assert "no variant 'sofft' (did you mean soft?); it defines soft, medium, stiff" in str(info.value)
    with pytest.raises(SceneError, match=r"e\.g\. --set bodies\.0\.material\.mu=2e5"):
        parse_overrides(["=3"])
    assert load_scene(path, Scene, ["bodies.0.material.mu=2e5"])[0].bodies[0].material.mu == 2e5  # the example works


def test_readme_quick_start_particle_count():
    """The count the README states is the one `pdmpm validate --explain scenes/elastic_drop.yaml` prints."""
    prep = prepare(ROOT / "scenes" / "elastic_drop.yaml")
    readme = (ROOT / "README.md").read_text()
    assert f"{prep.plan.particles} particles, {prep.plan.bonds} bonds" in readme
    assert yaml.safe_load((ROOT / "scenes" / "elastic_drop.yaml").read_text())["name"] == "elastic_drop"
    assert f"{prep.plan.particles} particles" in (ROOT / "scenes" / "elastic_drop.yaml").read_text()


def test_file_size_limit_is_reported_not_fatal(tmp_path):
    """Past `ulimit -f` the kernel sends SIGXFSZ, which kills a process by default; Python ignores it, so the write
    fails with EFBIG and is reported (here by `pdmpm schema -o`)."""
    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (1000, 1000))

    out = tmp_path / "schema.json"
    r = subprocess.run([sys.executable, "-m", "pdmpm_cli", "schema", "-o", out], cwd=ROOT, capture_output=True,
                       text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)), preexec_fn=limit, timeout=60)
    assert r.returncode == 1 and r.stderr == f"error: {out}: cannot write the schema (File too large)\n"
    assert not out.exists() and not list(tmp_path.iterdir())  # the temporary file is removed
