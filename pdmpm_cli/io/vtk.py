"""ParaView output: one VTU file of particles per frame plus a ``particles.pvd`` time collection.

``<directory>/frame_00000.vtu`` ... hold the particles as points (``particle_x``) with one
``vertex`` cell each and every other per-particle field (per-frame and static) as point data.
``particles.pvd`` lists the frames with their simulation times; open it in ParaView to get an
animation. Every file is written atomically, so a crashed run leaves only complete frames and a
collection that lists exactly the frames written.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from xml.sax.saxutils import quoteattr

import meshio
import numpy as np

from pdmpm_cli.errors import InputError
from pdmpm_cli.io.atomic import atomic_path, atomic_write_text
from pdmpm_cli.io.sink import check_order

POSITION_FIELD = "particle_x"
PVD_NAME = "particles.pvd"
VTU_COMPRESSIONS = (None, "zlib", "lzma")


def _point_data(fields: dict[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
    """Per-particle fields (named particle_*, shaped (n, ...)) as VTK point data; mesh fields go to PLY files."""
    out: dict[str, np.ndarray] = {}
    for name, value in fields.items():
        array = np.asarray(value)
        if name == POSITION_FIELD or not name.startswith("particle_") or array.ndim == 0 or array.shape[0] < n:
            continue
        array = array[:n]  # static fields cover every particle an emitter will bear; a frame holds the first n
        if array.dtype == np.bool_:
            array = array.astype(np.uint8)
        if array.ndim > 2:
            array = array.reshape(n, -1)
        out[name] = array
    return out


def _pvd_text(entries: list[tuple[float, str]]) -> str:
    rows = "".join(
        f'    <DataSet timestep="{time!r}" group="" part="0" file={quoteattr(name)}/>\n'
        for time, name in entries
    )
    return (
        '<?xml version="1.0"?>\n'
        '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
        "  <Collection>\n"
        f"{rows}"
        "  </Collection>\n"
        "</VTKFile>\n"
    )


def read_pvd(path: Path) -> list[tuple[float, str]]:
    """(time, VTU file name) of every frame a collection lists; InputError naming the file if unreadable."""
    try:
        sets = ET.parse(path).getroot().iter("DataSet")
        return [(float(d.get("timestep")), d.get("file")) for d in sets]
    except (ET.ParseError, OSError, TypeError, ValueError) as error:
        raise InputError(f"{path}: not a readable ParaView collection ({error}); re-run the simulation") from error


def frame_index(name: str) -> int:
    """The frame number in a file name such as frame_00012.vtu or cloth_00012.ply."""
    return int(re.search(r"(\d+)\.\w+$", name).group(1))


class VtkSeriesWriter:
    """Writes ``frame_NNNNN.vtu`` per frame and keeps ``particles.pvd`` listing them."""

    def __init__(
        self,
        directory: str | os.PathLike[str],
        *,
        static: dict[str, np.ndarray],
        binary_compression: str | None = None,
    ) -> None:
        if binary_compression not in VTU_COMPRESSIONS:
            raise ValueError(f"binary_compression must be one of {VTU_COMPRESSIONS}, got {binary_compression!r}")
        self.directory = Path(directory)
        self.path = self.directory / PVD_NAME
        self._static = static
        self._compression = binary_compression
        self._cells: list[tuple[str, np.ndarray]] | None = None
        self._static_point_data: dict[str, np.ndarray] = {}
        self._entries: list[tuple[float, str]] = []
        self._last_index = -1
        self._closed = False
        self.directory.mkdir(parents=True, exist_ok=True)

    @classmethod
    def reopen(cls, directory: str | os.PathLike[str], *, static: dict[str, np.ndarray], frames: int
               ) -> VtkSeriesWriter:
        """Continue the series in ``directory`` after its first ``frames`` frames; later frames are deleted."""
        writer = cls(directory, static=static)
        entries = read_pvd(writer.path)
        kept = [(time, name) for time, name in entries if frame_index(name) < frames]
        if len(kept) < frames:
            raise InputError(f"{writer.path}: lists {len(kept)} of the {frames} frames the checkpoint needs; "
                             f"start the run again with --overwrite")
        atomic_write_text(writer.path, _pvd_text(kept))
        for vtu in writer.directory.glob("frame_*.vtu"):
            if frame_index(vtu.name) >= frames:
                vtu.unlink()
        writer._entries = kept
        writer._last_index = frames - 1
        return writer

    def write_frame(self, index: int, time: float, fields: dict[str, np.ndarray]) -> None:
        """Write frame ``index`` (greater than the previous one) and update the collection."""
        check_order(self.path, self._closed, self._last_index, index)
        if POSITION_FIELD not in fields:
            raise ValueError(f"frame {index} has no {POSITION_FIELD!r} field to use as point positions")
        points = np.asarray(fields[POSITION_FIELD])
        n = points.shape[0]
        if self._cells is None or self._cells[0][1].shape[0] != n:
            self._cells = [("vertex", np.arange(n, dtype=np.int64).reshape(n, 1))]
            self._static_point_data = _point_data(self._static, n)
        mesh = meshio.Mesh(
            points,
            self._cells,
            point_data={**self._static_point_data, **_point_data(fields, n)},
        )
        name = f"frame_{index:05d}.vtu"
        with atomic_path(self.directory / name) as tmp:
            meshio.write(tmp, mesh, file_format="vtu", binary=True, compression=self._compression)
        self._entries.append((float(time), name))
        self._last_index = index
        atomic_write_text(self.path, _pvd_text(self._entries))

    def close(self) -> None:
        """Nothing is buffered (each frame is complete on disk); marks the writer closed."""
        self._closed = True

    def __enter__(self) -> VtkSeriesWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
