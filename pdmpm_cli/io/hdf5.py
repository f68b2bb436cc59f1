"""The pdmpm run file (``run.h5``): one HDF5 file per run, and its public reader.

Other tools read runs with::

    from pdmpm_cli.io.hdf5 import read_run

    run = read_run("outputs/beam/run.h5")
    run.times                    # (n_frames,) simulation time of each complete frame, seconds
    run.frame(-1)["particle_x"]  # fields of the last complete frame
    run.field("particle_speed")  # (n_frames, n) history of one field
    run.static["particle_mass"]  # fields written once per run

Layout (``format = "pdmpm-run"``, ``format_version = 1``)::

    /                       root attributes:
                              format, format_version, frames_complete (int),
                              pdmpm_version, numpy_version, numba_version, h5py_version,
                              hdf5_version, created (ISO 8601, UTC)
    /scene_text             scalar UTF-8 string dataset: the scene YAML the run was started from
    /plan_json              scalar UTF-8 string dataset: ``json.dumps`` of the resolved run plan; its
                            "scene" key holds the scene as validated (overrides and variant applied)
    /static/<name>          one dataset per field written once (particle_X, particle_mass, ...)
    /frames/time            (n_frames,) float64, simulation time of each frame
    /frames/<name>          (n_frames, *shape) one dataset per per-frame field (particle_x, ...)
    /frames/particle_count  (n_frames,) int64, only in runs with an emitter: the particles of each frame. Their
                            per-particle fields are then (n_frames, capacity, ...), the first count rows of a
                            frame valid and the rest NaN (0 for integers); the static fields cover all capacity
                            particles, of which a frame holds the first count. ``RunData.frame`` returns each
                            frame at its count.

Field names are ``<location>_<quantity>``. Frame datasets hold one frame per chunk (fields under
64 KiB per frame, such as scalars, pack several frames per chunk; frames over 1 GiB are split
along the particle axis) and are compressed with lzf or gzip level 1 (plus the shuffle filter for numeric data), or not at all.

Only the first ``frames_complete`` frames are valid: the writer fills every field of a frame and
``frames/time`` first, then bumps ``frames_complete`` and flushes, so a frame is either counted
and fully on disk or not counted. The reader also clamps to the shortest frame dataset.

Full disks: every write first reserves its bytes (``posix_fallocate``) past the file's current end, so a full
disk or a file-size limit (``ulimit -f``) fails there, before HDF5 has written anything of the frame, and the
file closes cleanly with its complete frames. A failed write inside HDF5 cannot be recovered in-process: the
library's close then frees memory twice, and the process dies with a segmentation fault at the next garbage
collection or at exit (reported to h5py, and closed there as a bug of the HDF5 library). A writer that meets any
other HDF5 error therefore abandons its file: its handles are kept, never closed (``abandoned()`` tells the CLI
to end with ``os._exit``).

Crash safety: the header and static fields are written and the file closed before the first
frame, so a run that dies before any frame leaves a clean file with zero frames. At the first
frame the file is reopened, the frame datasets are created, and the file is switched to HDF5
SWMR (single-writer / multiple-reader) mode, in which the library orders its metadata writes so
that the file is consistent for a reader at every instant. A run killed even with SIGKILL thus
leaves its completed frames readable. Such a file (and one whose run is still going) refuses a
plain read-only open ("file is already open for write"); open it with
``h5py.File(path, "r", swmr=True)``, as ``read_run`` does. Frames are flushed to the OS, not
fsynced: a power loss may still lose the most recent frames. Files use the HDF5 1.10 format
(readable by HDF5 >= 1.10). ``Hdf5RunWriter.reopen`` continues such a file after a given frame
(``pdmpm run --resume``).
"""

from __future__ import annotations

import errno
import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from pdmpm_cli import __version__
from pdmpm_cli.errors import InputError, OutputError, PdmpmError
from pdmpm_cli.io.atomic import atomic_path

FORMAT = "pdmpm-run"
FORMAT_VERSION = 1
COMPRESSIONS = ("none", "lzf", "gzip")

_LIBVER = ("v110", "v110")  # lowest format that supports SWMR; readable by HDF5 >= 1.10
_SMALL_CHUNK_BYTES = 64 * 1024  # below this, several frames share a chunk (scalar histories)
_MAX_CHUNK_BYTES = 1 << 30  # HDF5 caps chunks at 4 GiB; stay well under it
_RESERVE_SLACK = 256 * 1024  # metadata one frame may add: object headers, chunk-index blocks, free-space info
_INDEX_BYTES = 32  # per dataset and frame so far: a chunk index grows by blocks as large as what it holds
_UNSUPPORTED = (errno.EOPNOTSUPP, errno.ENOSYS, errno.ENODEV, errno.ESPIPE)  # no fallocate: write unreserved
_ABANDONED: list = []  # h5py objects of files whose HDF5 state broke: kept alive, never closed
_HINT = "pass the run.h5 written by `pdmpm run`"
_CORRUPT_HINT = "the file is truncated or corrupt; re-run the simulation to regenerate it"


def _package_version(name: str) -> str:
    try:
        return version(name)
    except PackageNotFoundError:
        return "unknown"


def _filter_options(compression: str, dtype: np.dtype) -> dict[str, Any]:
    """h5py keyword arguments for the requested compression; shuffle helps multi-byte numbers."""
    if compression == "none":
        return {}
    options: dict[str, Any] = {"compression": compression}
    if compression == "gzip":
        options["compression_opts"] = 1
    if dtype.kind in "fiuc" and dtype.itemsize > 1:
        options["shuffle"] = True
    return options


def _frame_chunks(shape: tuple[int, ...], itemsize: int) -> tuple[int, ...]:
    """One frame per chunk; several frames for tiny fields, a split particle axis for huge ones."""
    dims = tuple(max(1, s) for s in shape)
    frame_bytes = int(np.prod(dims, dtype=np.int64)) * itemsize
    if frame_bytes < _SMALL_CHUNK_BYTES:
        return (max(1, _SMALL_CHUNK_BYTES // frame_bytes), *dims)
    if frame_bytes > _MAX_CHUNK_BYTES:
        rows = max(1, dims[0] * _MAX_CHUNK_BYTES // frame_bytes)
        return (1, rows, *dims[1:])
    return (1, *dims)


def reserve(path: str | os.PathLike[str], end: int, nbytes: int) -> None:
    """Allocate bytes [end, end + nbytes) of the file at `path` on disk; OutputError when the disk, a quota or the
    file-size limit cannot hold them. HDF5 then writes into space that is already the file's (it truncates the
    file to its own end when it closes)."""
    fd = os.open(path, os.O_WRONLY)
    try:
        os.posix_fallocate(fd, end, max(nbytes, 1))
    except OSError as error:
        if error.errno not in _UNSUPPORTED:
            raise OutputError(f"{path}: cannot grow the file by {nbytes / 2**20:.3g} MiB "
                              f"({os.strerror(error.errno).lower()})") from None
    finally:
        os.close(fd)


def trim(path: str | os.PathLike[str]) -> None:
    """Give back what a closed file holds past the end its superblock records (the unused part of the last
    reservation). Superblock versions 2 and 3 (HDF5 1.8+ formats) keep the base and end-of-file addresses at
    bytes 12 and 28; a file of another layout is left as it is."""
    with open(path, "r+b") as f:
        head = f.read(36)
        if len(head) < 36 or head[:8] != b"\x89HDF\r\n\x1a\n" or head[8] not in (2, 3) or head[9] != 8:
            return
        end = int.from_bytes(head[12:20], "little") + int.from_bytes(head[28:36], "little")
        if 0 < end < os.fstat(f.fileno()).st_size:
            f.truncate(end)


@contextmanager
def reserved_file(path: str | os.PathLike[str], nbytes: int) -> Iterator[h5py.File]:
    """A new HDF5 file (format 1.10) at `path` whose `nbytes` (plus metadata slack) are reserved on disk before
    anything is written; trimmed to its content once closed. An error from inside HDF5 abandons the file."""
    f = h5py.File(path, "w", libver=_LIBVER)
    try:
        reserve(path, 0, nbytes + _RESERVE_SLACK)
        yield f
    except PdmpmError:
        f.close()
        raise
    except BaseException:
        _ABANDONED.append(f)
        raise
    f.close()
    trim(path)


def abandoned() -> bool:
    """Whether a writer gave up a file after an HDF5 error (the process must then end without closing it)."""
    return bool(_ABANDONED)


class Hdf5RunWriter:
    """Appends frames to one ``run.h5``; every frame counted in ``frames_complete`` survives a crash."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        scene_text: str,
        plan: dict,
        static: dict[str, np.ndarray],
        compression: str = "lzf",
        capacity: int | None = None,
    ) -> None:
        """capacity: the most particles a frame may hold (a run with an emitter), or None for a fixed count."""
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of {COMPRESSIONS}, got {compression!r}")
        self.path = Path(path)
        self._compression = compression
        self._file: h5py.File | None = None
        self._closed = False
        self._frames: dict[str, h5py.Dataset] = {}
        self._shapes: dict[str, tuple[int, ...]] = {}
        self._n_frames = 0
        self._capacity = capacity
        self._count: h5py.Dataset | None = None
        # Closed again right away: until the first frame the file is a clean, readable run with 0 frames.
        need = sum(np.asarray(v).nbytes for v in static.values()) + 4 * (len(scene_text) + len(json.dumps(plan)))
        with reserved_file(self.path, need) as f:
            self._write_header(f, scene_text, plan, static)

    @classmethod
    def reopen(cls, path: str | os.PathLike[str], frames: int) -> Hdf5RunWriter:
        """Continue the run file at ``path`` after its first ``frames`` frames; later frames are dropped.

        The kept part is copied (chunk by chunk, without recompressing) to a new file that atomically
        replaces the old one: a file left by a killed writer is still flagged as open for writing, and only
        a fresh file can be reopened for appending.
        """
        path = Path(path)
        run = read_run(path)
        if len(run) < frames:
            raise InputError(f"{path}: holds {len(run)} complete frames, but the checkpoint needs {frames}; "
                             f"{_CORRUPT_HINT}")
        with _open(path) as src, atomic_path(path) as tmp, reserved_file(tmp, os.path.getsize(path)) as dst:
            try:
                dst.attrs.update(src.attrs)
                dst.attrs["frames_complete"] = np.int64(frames)
                for name in src:
                    src.copy(src[name], dst, name)
                for dataset in dst["frames"].values():
                    dataset.resize(frames, axis=0)
            except (OSError, KeyError, ValueError) as error:
                raise _corrupt(path, error) from error
        writer = cls.__new__(cls)
        writer.path = path
        writer._closed = False
        writer._file = h5py.File(path, "r+", libver=_LIBVER)
        group = writer._file["frames"]
        writer._frames = {name: group[name] for name in run.field_names}
        writer._shapes = {name: dataset.shape[1:] for name, dataset in writer._frames.items()}
        writer._n_frames = frames
        writer._count = group["particle_count"] if COUNT in group else None
        writer._capacity = writer._shapes["particle_x"][0] if writer._count is not None else None
        writer._file.swmr_mode = True
        return writer

    def _write_header(self, f: h5py.File, scene_text: str, plan: dict, static: dict[str, np.ndarray]) -> None:
        f.attrs.update(
            {
                "format": FORMAT,
                "format_version": FORMAT_VERSION,
                "frames_complete": np.int64(0),
                "pdmpm_version": __version__,
                "numpy_version": np.__version__,
                "numba_version": _package_version("numba"),
                "h5py_version": h5py.__version__,
                "hdf5_version": h5py.version.hdf5_version,
                "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            }
        )
        text = h5py.string_dtype("utf-8")
        f.create_dataset("scene_text", data=scene_text, dtype=text)
        f.create_dataset("plan_json", data=json.dumps(plan), dtype=text)
        group = f.create_group("static")
        for name, value in static.items():
            array = np.asarray(value)
            options = _filter_options(self._compression, array.dtype) if array.size else {}
            group.create_dataset(name, data=array, **options)
        frames = f.create_group("frames")
        frames.create_dataset("time", shape=(0,), maxshape=(None,), dtype=np.float64, chunks=(1024,))

    def _open_for_frames(self, fields: dict[str, np.ndarray]) -> h5py.File:
        """Reopen, create one dataset per field, then enter SWMR mode (no objects can be added after)."""
        f = h5py.File(self.path, "r+", libver=_LIBVER)
        try:
            group = f["frames"]
            for name, array in fields.items():
                self._frames[name] = group.create_dataset(
                    name,
                    shape=(0, *array.shape),
                    maxshape=(None, *array.shape),
                    dtype=array.dtype,
                    chunks=_frame_chunks(array.shape, array.dtype.itemsize),
                    **({"fillvalue": _pad_value(array.dtype)} if self._capacity is not None else {}),
                    **_filter_options(self._compression, array.dtype),
                )
                self._shapes[name] = array.shape
            if self._capacity is not None:
                self._count = group.create_dataset(COUNT, shape=(0,), maxshape=(None,), dtype=np.int64,
                                                   chunks=(1024,))
            f.swmr_mode = True
        except BaseException:
            _ABANDONED.extend([f, *self._frames.values()])
            self._frames.clear()
            raise
        return f

    def write_frame(self, index: int, time: float, fields: dict[str, np.ndarray]) -> None:
        """Append frame ``index`` (must equal the number of frames already written)."""
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")
        if index != self._n_frames:
            raise ValueError(f"frame index {index} out of order: expected {self._n_frames}")
        arrays = {name: np.asarray(value) for name, value in fields.items()}
        count = len(arrays["particle_x"]) if "particle_x" in arrays else 0
        if self._capacity is not None:
            if count > self._capacity:
                raise ValueError(f"frame {index} has {count} particles, more than the run's capacity {self._capacity}")
            arrays = {name: _padded(a, self._capacity) if _per_particle(name, a, count) else a
                      for name, a in arrays.items()}
        if self._file is None:
            if "time" in arrays:
                raise ValueError("field name 'time' is reserved for frame times; use <location>_<quantity>")
            reserve(self.path, os.path.getsize(self.path), self._frame_reserve(arrays, 0))
            self._file = self._open_for_frames(arrays)
        elif arrays.keys() != self._frames.keys():
            raise ValueError(
                f"frame {index} has fields {sorted(arrays)}, but the run has {sorted(self._frames)}"
            )
        for name, array in arrays.items():
            if array.shape != self._shapes[name]:
                raise ValueError(
                    f"frame {index}: field {name!r} has shape {array.shape}, expected {self._shapes[name]}"
                )
        n = index + 1
        reserve(self.path, self._file.id.get_filesize(), self._frame_reserve(arrays, index))
        try:
            for name, array in arrays.items():
                dataset = self._frames[name]
                dataset.resize(n, axis=0)
                dataset[index] = array
            if self._count is not None:
                self._count.resize(n, axis=0)
                self._count[index] = count
            times = self._file["frames/time"]
            times.resize(n, axis=0)
            times[index] = time
            self._file.attrs["frames_complete"] = np.int64(n)
            self._file.flush()
        except BaseException:
            self._abandon()
            raise
        self._n_frames = n

    def _frame_reserve(self, arrays: dict[str, np.ndarray], frames: int) -> int:
        """Bytes one frame may add to the file: a whole chunk per field (small fields rewrite a chunk shared by
        several frames; compression may not shrink it), their index entries and the metadata slack."""
        chunks = [int(np.prod(_frame_chunks(a.shape, a.itemsize), dtype=np.int64)) * a.itemsize
                  for a in arrays.values()]
        return int(1.01 * sum(chunks)) + 8 * 1024 + (len(chunks) + 1) * _INDEX_BYTES * (frames + 1) + _RESERVE_SLACK

    def _abandon(self) -> None:
        """Give up the file after an error inside HDF5: keep its handles alive and never close them."""
        _ABANDONED.extend([self._file, *self._frames.values()])
        self._file, self._frames, self._closed = None, {}, True

    def close(self) -> None:
        """Close the file (every written frame is already flushed); safe to call twice."""
        self._closed = True
        if self._file is not None:
            file, self._file = self._file, None
            file.close()
            trim(self.path)

    def __enter__(self) -> Hdf5RunWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _open(path: Path) -> h5py.File:
    """Open read-only; use SWMR read mode for a run still being written or killed mid-run."""
    if not path.exists():
        raise InputError(f"{path}: no such file; {_HINT}")
    if not path.is_file():
        raise InputError(f"{path}: not a file; {_HINT}")
    if not h5py.is_hdf5(path):
        raise InputError(f"{path}: not an HDF5 file; {_HINT}")
    try:
        return h5py.File(path, "r")
    except OSError as error:
        # Only a file flagged as open for writing goes to SWMR mode: SWMR readers retry failed
        # metadata reads for minutes instead of failing, so a truncated or corrupt file must not
        # get there (HDF5 reports truncation before it checks the flag).
        if "already open for write" not in str(error):
            raise InputError(f"{path}: cannot open the HDF5 file ({error}); {_CORRUPT_HINT}") from error
    try:
        return h5py.File(path, "r", swmr=True)
    except OSError as error:
        raise InputError(
            f"{path}: the run writing this file is still starting or was killed before its first frame "
            f"was complete ({error}); wait and retry, or re-run the simulation"
        ) from error


def _attr(value: Any) -> Any:
    """HDF5 attribute values as plain Python values."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def _corrupt(path: Path, error: BaseException) -> InputError:
    return InputError(f"{path}: cannot read the run file ({type(error).__name__}: {error}); {_CORRUPT_HINT}")


COUNT = "particle_count"  # /frames dataset of a run with an emitter: the particles of each frame


def _per_particle(name: str, array: np.ndarray, count: int) -> bool:
    return name.startswith("particle_") and array.ndim > 0 and array.shape[0] == count


def _pad_value(dtype: np.dtype):
    return np.nan if np.issubdtype(dtype, np.floating) else 0


def _padded(array: np.ndarray, capacity: int) -> np.ndarray:
    """The per-particle array with rows past its count filled (NaN, or 0 for integers), `capacity` rows."""
    out = np.full((capacity,) + array.shape[1:], _pad_value(array.dtype), dtype=array.dtype)
    out[:len(array)] = array
    return out


class RunData:
    """A snapshot of a run file: header and static fields in memory, frames read on demand.

    Frame data is read by reopening the file on each call, so no file handle stays open and a
    run still being written can be read; only frames complete at ``read_run`` time are visible.
    """

    def __init__(
        self,
        path: Path,
        *,
        scene_text: str,
        plan: dict,
        attrs: dict[str, Any],
        times: np.ndarray,
        static: dict[str, np.ndarray],
        field_names: list[str],
        counts: np.ndarray | None = None,
    ) -> None:
        self.path = path
        self.counts = counts  # particles of each frame (a run with an emitter), or None: all, every frame
        self.scene_text = scene_text
        self.plan = plan
        self.attrs = attrs
        self.times = times
        self.static = static
        self.field_names = field_names

    def __len__(self) -> int:
        return len(self.times)

    def __repr__(self) -> str:
        return f"RunData({str(self.path)!r}, frames={len(self)}, fields={self.field_names})"

    def frame(self, i: int) -> dict[str, np.ndarray]:
        """All per-frame fields of complete frame ``i`` (negative counts from the last)."""
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"{self.path}: frame {i} out of range ({n} complete frames)")
        i %= n
        with _open(self.path) as f:
            try:
                frame = {name: f["frames"][name][i] for name in self.field_names}
            except (OSError, KeyError, ValueError) as error:
                raise _corrupt(self.path, error) from error
        if self.counts is not None:
            capacity, count = len(frame["particle_x"]), int(self.counts[i])
            frame = {name: a[:count] if name.startswith("particle_") and a.ndim and len(a) == capacity else a
                     for name, a in frame.items()}
        return frame

    def field(self, name: str) -> np.ndarray:
        """The history of one per-frame field over the complete frames, shape (n_frames, ...); with an emitter,
        (n_frames, capacity, ...) with NaN (0) past each frame's count (`counts`)."""
        if name not in self.field_names:
            raise KeyError(f"{self.path}: no per-frame field {name!r}; available: {self.field_names}")
        with _open(self.path) as f:
            try:
                return f["frames"][name][: len(self)]
            except (OSError, KeyError, ValueError) as error:
                raise _corrupt(self.path, error) from error


def read_run(path: str | os.PathLike[str]) -> RunData:
    """Read a ``run.h5`` written by :class:`Hdf5RunWriter`; raise InputError if it is not one."""
    path = Path(path)
    with _open(path) as f:
        try:
            attrs = {key: _attr(value) for key, value in f.attrs.items()}
            if attrs.get("format") != FORMAT:
                what = "missing attribute 'format'" if "format" not in attrs else f"format is {attrs['format']!r}"
                raise InputError(f"{path}: not a pdmpm run file ({what}); {_HINT}")
            if attrs.get("format_version") != FORMAT_VERSION:
                raise InputError(
                    f"{path}: unsupported run file format_version {attrs.get('format_version')!r} "
                    f"(this pdmpm {__version__} reads version {FORMAT_VERSION}); read it with a matching pdmpm"
                )
            for required in ("scene_text", "plan_json", "static", "frames", "frames/time"):
                if required not in f:
                    raise InputError(f"{path}: run file is incomplete (missing '{required}'); {_HINT}")
            scene_text = f["scene_text"].asstr()[()]
            plan = json.loads(f["plan_json"].asstr()[()])
            static = {name: dataset[()] for name, dataset in f["static"].items()}
            frames = f["frames"]
            field_names = sorted(name for name in frames if name not in ("time", COUNT))
            n = min(
                int(attrs.get("frames_complete", 0)),
                frames["time"].shape[0],
                *(frames[name].shape[0] for name in field_names),
            )
            times = frames["time"][:n]
            counts = frames[COUNT][:n] if COUNT in frames else None
        except InputError:
            raise
        except (OSError, KeyError, ValueError, TypeError, AttributeError) as error:
            raise _corrupt(path, error) from error
    return RunData(
        path,
        scene_text=scene_text,
        plan=plan,
        attrs=attrs,
        times=times,
        static=static,
        field_names=field_names,
        counts=counts,
    )
