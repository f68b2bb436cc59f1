"""Output layer: atomic writes, the HDF5 run file and its reader, VTU series, the background sink."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import meshio
import numpy as np
import pytest
import pyvista as pv

from pdmpm_cli.errors import InputError
from pdmpm_cli.io.atomic import atomic_path, atomic_write_bytes, atomic_write_text
from pdmpm_cli.io.hdf5 import COMPRESSIONS, Hdf5RunWriter, _frame_chunks, read_run
from pdmpm_cli.io.sink import FrameSink, FrameWriteError
from pdmpm_cli.io.vtk import VtkSeriesWriter

N = 64
SCENE = "name: test\nparticles: 64\n"
PLAN = {"dt": 1e-4, "frames": 4, "materials": ["steel"]}


def make_static(n: int = N) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(1)
    return {
        "particle_X": rng.random((n, 3)),
        "particle_volume": np.full(n, 1e-9),
        "particle_mass": rng.random(n),
        "particle_body": np.arange(n, dtype=np.int32) % 3,
    }


def make_frame(i: int, n: int = N) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(100 + i)
    v = rng.normal(size=(n, 3))
    return {
        "particle_x": rng.random((n, 3)).astype(np.float32),
        "particle_v": v,
        "particle_speed": np.linalg.norm(v, axis=1),
        "particle_damage": rng.random(n) < 0.3,
        "energy_kinetic": np.float64(i * 1.5),
    }


def write_run(path: Path, n_frames: int, compression: str = "lzf") -> list[dict[str, np.ndarray]]:
    frames = [make_frame(i) for i in range(n_frames)]
    writer = Hdf5RunWriter(path, scene_text=SCENE, plan=PLAN, static=make_static(), compression=compression)
    try:
        for i, fields in enumerate(frames):
            writer.write_frame(i, 0.01 * i, fields)
    finally:
        writer.close()
    return frames


# --- atomic writes -------------------------------------------------------------------------


def test_atomic_write_replaces_and_leaves_no_temp_file(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    atomic_write_text(target, "old")
    atomic_write_bytes(target, b"new \xe2\x9c\x93")
    assert target.read_text(encoding="utf-8") == "new \u2713"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def test_atomic_path_failure_keeps_old_file(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            assert tmp.parent == tmp_path and tmp.name.startswith(".out.txt.tmp-")
            tmp.write_text("half")
            raise RuntimeError("writer failed")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


# --- HDF5 run file -------------------------------------------------------------------------


@pytest.mark.parametrize("compression", COMPRESSIONS)
def test_hdf5_round_trip(tmp_path: Path, compression: str) -> None:
    path = tmp_path / "run.h5"
    frames = write_run(path, 4, compression)
    run = read_run(path)

    assert len(run) == 4
    np.testing.assert_array_equal(run.times, [0.0, 0.01, 0.02, 0.03])
    assert run.scene_text == SCENE
    assert run.plan == PLAN
    assert run.attrs["format"] == "pdmpm-run" and run.attrs["format_version"] == 1
    assert run.attrs["frames_complete"] == 4
    for key in ("pdmpm_version", "numpy_version", "numba_version", "h5py_version", "created"):
        assert isinstance(run.attrs[key], str) and run.attrs[key]
    assert run.field_names == sorted(frames[0])
    for name, expected in make_static().items():
        np.testing.assert_array_equal(run.static[name], expected)
        assert run.static[name].dtype == expected.dtype
    for i in (0, 3, -1):
        got = run.frame(i)
        for name, expected in frames[i].items():
            np.testing.assert_array_equal(got[name], expected)
            assert got[name].dtype == np.asarray(expected).dtype
    np.testing.assert_array_equal(run.field("particle_v"), np.stack([f["particle_v"] for f in frames]))
    np.testing.assert_array_equal(run.field("energy_kinetic"), [0.0, 1.5, 3.0, 4.5])

    with h5py.File(path, "r") as f:
        x = f["frames/particle_x"]
        assert x.chunks[1:] == (N, 3)
        assert x.compression == (None if compression == "none" else compression)
        assert x.shuffle == (compression != "none")


def test_frame_chunks() -> None:
    assert _frame_chunks((1_000_000, 3), 8) == (1, 1_000_000, 3)  # one frame per chunk
    assert _frame_chunks((), 8) == (8192,)  # scalar histories pack 64 KiB per chunk
    rows = _frame_chunks((100_000_000, 3), 8)[1]  # 2.4 GB frames split under HDF5's 4 GiB cap
    assert rows * 3 * 8 <= 1 << 30


def test_hdf5_run_without_frames_is_readable(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    writer = Hdf5RunWriter(path, scene_text=SCENE, plan=PLAN, static=make_static())
    run = read_run(path)  # before close, as after a crash before the first frame
    writer.close()
    assert len(run) == 0 and run.field_names == [] and run.scene_text == SCENE
    with pytest.raises(IndexError):
        run.frame(0)


def test_hdf5_readable_while_writing_and_after_interrupt(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    writer = Hdf5RunWriter(path, scene_text=SCENE, plan=PLAN, static=make_static())
    with pytest.raises(KeyboardInterrupt):
        try:
            for i in range(3):
                writer.write_frame(i, float(i), make_frame(i))
            assert len(read_run(path)) == 3
            raise KeyboardInterrupt
        finally:
            writer.close()
    run = read_run(path)
    assert len(run) == 3
    np.testing.assert_array_equal(run.frame(2)["particle_speed"], make_frame(2)["particle_speed"])


def test_hdf5_rejects_out_of_order_and_changed_fields(tmp_path: Path) -> None:
    writer = Hdf5RunWriter(tmp_path / "run.h5", scene_text=SCENE, plan=PLAN, static={})
    try:
        with pytest.raises(ValueError, match="out of order"):
            writer.write_frame(1, 0.0, make_frame(0))
        writer.write_frame(0, 0.0, make_frame(0))
        with pytest.raises(ValueError, match="out of order"):
            writer.write_frame(0, 0.0, make_frame(0))
        with pytest.raises(ValueError, match="fields"):
            writer.write_frame(1, 0.1, {"particle_x": np.zeros((N, 3))})
        with pytest.raises(ValueError, match="shape"):
            writer.write_frame(1, 0.1, make_frame(1, n=N + 1))
        writer.write_frame(1, 0.1, make_frame(1))
    finally:
        writer.close()
    assert len(read_run(tmp_path / "run.h5")) == 2
    with pytest.raises(ValueError, match="compression"):
        Hdf5RunWriter(tmp_path / "x.h5", scene_text="", plan={}, static={}, compression="zstd")


def _assert_input_error(path: Path, fragment: str) -> None:
    with pytest.raises(InputError) as info:
        read_run(path)
    assert str(path) in str(info.value)
    assert fragment in str(info.value)


def test_read_run_errors(tmp_path: Path) -> None:
    _assert_input_error(tmp_path / "missing.h5", "no such file")

    text = tmp_path / "scene.yaml"
    text.write_text("not: hdf5\n")
    _assert_input_error(text, "not an HDF5 file")

    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["data"] = np.arange(3)
    _assert_input_error(foreign, "missing attribute 'format'")

    truncated = tmp_path / "truncated.h5"
    write_run(truncated, 4, "none")
    with open(truncated, "r+b") as f:
        f.truncate(truncated.stat().st_size // 2)
    _assert_input_error(truncated, "truncated")

    newer = tmp_path / "newer.h5"
    write_run(newer, 1)
    with h5py.File(newer, "r+") as f:
        f.attrs["format_version"] = 99
    _assert_input_error(newer, "format_version")


_CHILD = """
import sys
import numpy as np
from pdmpm_cli.io.hdf5 import Hdf5RunWriter

n = 20_000
writer = Hdf5RunWriter(sys.argv[1], scene_text="s", plan={}, static={"particle_mass": np.ones(n)})
i = 0
while True:
    writer.write_frame(i, 0.5 * i, {"particle_x": np.full((n, 3), float(i)), "particle_speed": np.full(n, float(i))})
    print(i + 1, flush=True)
    i += 1
"""


def test_hdf5_survives_sigkill(tmp_path: Path) -> None:
    """A writer killed at an arbitrary point leaves every frame it reported readable and correct."""
    path = tmp_path / "run.h5"
    with subprocess.Popen([sys.executable, "-c", _CHILD, str(path)], stdout=subprocess.PIPE, text=True) as child:
        try:
            assert child.stdout is not None
            reported = 0
            for line in child.stdout:
                reported = int(line)
                if reported == 3:
                    assert len(read_run(path)) >= 3  # a concurrent reader sees the live run
                if reported >= 6:
                    break
        finally:
            child.send_signal(signal.SIGKILL)
    assert child.returncode == -signal.SIGKILL

    run = read_run(path)
    assert len(run) >= reported
    np.testing.assert_array_equal(run.times, 0.5 * np.arange(len(run)))
    xs = run.field("particle_x")
    for i in range(len(run)):
        assert np.all(xs[i] == i) and np.all(run.frame(i)["particle_speed"] == i)


# --- VTU series ----------------------------------------------------------------------------


@pytest.mark.parametrize("compression", [None, "zlib", "lzma"])
def test_vtk_series_round_trip(tmp_path: Path, compression: str | None) -> None:
    static = make_static()
    frames = [make_frame(i) for i in range(3)]
    times = [0.0, 0.125, 0.25 + 2.5e-7]  # full float precision must survive the .pvd
    writer = VtkSeriesWriter(tmp_path / "vtk", static=static, binary_compression=compression)
    for i, fields in enumerate(frames):
        writer.write_frame(i, times[i], fields)
    writer.close()

    names = sorted(p.name for p in (tmp_path / "vtk").iterdir())
    assert names == ["frame_00000.vtu", "frame_00001.vtu", "frame_00002.vtu", "particles.pvd"]

    mesh = meshio.read(tmp_path / "vtk" / "frame_00001.vtu")
    np.testing.assert_array_equal(mesh.points, frames[1]["particle_x"])
    assert mesh.points.dtype == np.float32
    assert mesh.cells[0].type == "vertex" and len(mesh.cells[0].data) == N
    assert set(mesh.point_data) == {*static, "particle_v", "particle_speed", "particle_damage"}
    np.testing.assert_array_equal(mesh.point_data["particle_v"], frames[1]["particle_v"])
    np.testing.assert_array_equal(mesh.point_data["particle_damage"], frames[1]["particle_damage"])
    assert mesh.point_data["particle_damage"].dtype == np.uint8
    assert mesh.point_data["particle_body"].dtype == np.int32
    np.testing.assert_array_equal(mesh.point_data["particle_X"], static["particle_X"])

    grid = pv.read(tmp_path / "vtk" / "frame_00002.vtu")
    assert grid.n_points == N
    np.testing.assert_allclose(grid["particle_speed"], frames[2]["particle_speed"])

    reader = pv.get_reader(tmp_path / "vtk" / "particles.pvd")
    assert isinstance(reader, pv.PVDReader)
    assert reader.time_values == times
    reader.set_active_time_value(times[2])
    block = reader.read()[0]
    np.testing.assert_allclose(block.points, frames[2]["particle_x"])


def test_vtk_rejects_out_of_order(tmp_path: Path) -> None:
    writer = VtkSeriesWriter(tmp_path, static={})
    writer.write_frame(0, 0.0, make_frame(0))
    with pytest.raises(ValueError, match="out of order"):
        writer.write_frame(0, 0.0, make_frame(0))
    with pytest.raises(ValueError, match="particle_x"):
        writer.write_frame(1, 0.0, {"particle_v": np.zeros((N, 3))})
    writer.close()


# --- FrameSink -----------------------------------------------------------------------------


class RecordingWriter:
    def __init__(self, fail_on: int | None = None, fail_close: bool = False) -> None:
        self.frames: list[tuple[int, float, dict[str, np.ndarray]]] = []
        self.closed = False
        self.failed = threading.Event()
        self._fail_on = fail_on
        self._fail_close = fail_close

    def write_frame(self, index: int, time: float, fields: dict[str, np.ndarray]) -> None:
        if index == self._fail_on:
            self.failed.set()
            raise OSError("disk full")
        self.frames.append((index, time, fields))

    def close(self) -> None:
        self.closed = True
        if self._fail_close:
            raise OSError("cannot close")


def test_sink_writes_copies_in_order() -> None:
    writers = [RecordingWriter(), RecordingWriter()]
    x = np.zeros(5)
    with FrameSink(writers) as sink:
        for i in range(10):
            x[:] = i
            sink.submit(i, 0.1 * i, {"particle_speed": x})  # the solver reuses its arrays
    for writer in writers:
        assert writer.closed
        assert [index for index, _, _ in writer.frames] == list(range(10))
        assert all(np.all(fields["particle_speed"] == i) for i, _, fields in writer.frames)
        assert writer.frames[3][1] == pytest.approx(0.3)


def test_sink_raises_writer_error_on_next_submit() -> None:
    failing, other = RecordingWriter(fail_on=2), RecordingWriter()
    sink = FrameSink([other, failing])
    for i in range(3):
        sink.submit(i, float(i), {"a": np.zeros(2)})
    assert failing.failed.wait(5)
    with pytest.raises(FrameWriteError, match="RecordingWriter failed writing frame 2: OSError: disk full") as info:
        for i in range(3, 500):  # the failure surfaces on one of the next submits
            sink.submit(i, float(i), {"a": np.zeros(2)})
            time.sleep(0.01)
    assert isinstance(info.value.__cause__, OSError)
    sink.close()  # already reported: closing does not raise it again
    assert failing.closed and other.closed
    assert [index for index, _, _ in failing.frames] == [0, 1]


def test_sink_raises_writer_error_on_close_and_closes_all() -> None:
    failing, bad_close, other = RecordingWriter(fail_on=2), RecordingWriter(fail_close=True), RecordingWriter()
    sink = FrameSink([failing, bad_close, other])
    for i in range(3):
        sink.submit(i, float(i), {"a": np.zeros(2)})
    with pytest.raises(FrameWriteError, match="frame 2"):
        sink.close()
    assert failing.closed and bad_close.closed and other.closed
    assert [index for index, _, _ in other.frames] == [0, 1]  # frame 2 onward is dropped everywhere

    sink = FrameSink([bad_close, RecordingWriter()])
    with pytest.raises(FrameWriteError, match="failed to close"):
        sink.close()
    with pytest.raises(ValueError, match="closed"):
        sink.submit(0, 0.0, {})


def test_sink_drives_real_writers(tmp_path: Path) -> None:
    static = make_static()
    writers = [
        Hdf5RunWriter(tmp_path / "run.h5", scene_text=SCENE, plan=PLAN, static=static),
        VtkSeriesWriter(tmp_path / "vtk", static=static),
    ]
    with FrameSink(writers) as sink:
        for i in range(3):
            sink.submit(i, 0.5 * i, make_frame(i))
    assert len(read_run(tmp_path / "run.h5")) == 3
    assert pv.PVDReader(tmp_path / "vtk" / "particles.pvd").time_values == [0.0, 0.5, 1.0]
    assert os.path.exists(tmp_path / "vtk" / "frame_00002.vtu")
