"""Surfaces of fluid (viscoelastic) bodies reconstructed from their particles, for render and the exported files.

`fluid_surface` splats the particle volumes on a grid of about h/2, smooths them over h and contours the level
whose enclosed volume matches the particles' (a fixed level loses thin streams), then smooths the triangles
lightly. `FluidSurfaces` computes each frame's surfaces once for every writer that asks (the PLY series and the
USD stage run one after the other on the output thread).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pdmpm_cli.io.atomic import atomic_path
from pdmpm_cli.io.ply import safe_name, write_ply
from pdmpm_cli.io.sink import check_order

FLUID_GRID_CELLS = 2e7  # cap on the splatting grid of a fluid surface (memory, marching-cubes time)


def fluid_surface(x: np.ndarray, volume: np.ndarray, spacing: float):
    """A smooth closed surface (pyvista PolyData, with normals) around fluid particles; empty for no particles.
    Particles alone read as sand, not honey."""
    import pyvista as pv
    from scipy.ndimage import gaussian_filter

    if len(x) == 0:
        return pv.PolyData()
    pad = 4 * spacing
    lo, hi = x.min(axis=0) - pad, x.max(axis=0) + pad
    cell = max(spacing / 2, (np.prod(hi - lo) / FLUID_GRID_CELLS) ** (1 / 3))
    shape = tuple(np.ceil((hi - lo) / cell).astype(int) + 1)
    nodes = np.ravel_multi_index(np.rint((x - lo) / cell).astype(int).T, shape)
    phi = np.bincount(nodes, weights=volume, minlength=int(np.prod(shape))).reshape(shape) / cell**3
    phi = gaussian_filter(phi, sigma=spacing / cell)
    inside = int(np.clip(round(volume.sum() / cell**3), 1, phi.size))
    level = float(np.partition(phi.ravel(), -inside)[-inside])
    grid = pv.ImageData(dimensions=shape, spacing=(cell,) * 3, origin=lo)
    grid.point_data["phi"] = phi.ravel(order="F")
    surface = grid.contour([level], scalars="phi")
    if surface.n_points == 0:
        return surface
    return surface.smooth_taubin(n_iter=15, pass_band=0.1).compute_normals(split_vertices=False)


def triangles_of(surface) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (n, 3) float64, triangles (m, 3) int64) of a triangulated PolyData."""
    if surface.n_points == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    faces = surface.triangulate().faces.reshape(-1, 4)
    return np.asarray(surface.points, dtype=np.float64), faces[:, 1:].astype(np.int64)


@dataclass(frozen=True)
class FluidBody:
    name: str
    start: int  # particle range [start, end)
    end: int
    spacing: float  # h [m]
    volume: np.ndarray  # (end - start,) particle volumes [m^3]


class FluidSurfaces:
    """Each fluid body's surface at one frame, computed once however many writers read it."""

    def __init__(self, bodies: list[FluidBody]) -> None:
        self.bodies = bodies
        self._index, self._surfaces = None, []

    def at(self, index: int, x: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        if index != self._index:
            # x[start:end] is a prefix of the range while an emitter is still bearing the body's particles
            self._surfaces = [triangles_of(fluid_surface(x[b.start:b.end], b.volume[:max(0, len(x) - b.start)],
                                                         b.spacing)) for b in self.bodies]
            self._index = index
        return self._surfaces


class FluidSurfaceWriter:
    """Writes ``<body>_surface_NNNNN.ply`` for every fluid body at every frame (the topology changes)."""

    def __init__(self, directory: str | os.PathLike[str], surfaces: FluidSurfaces) -> None:
        self.directory = self.path = Path(directory)
        self.surfaces = surfaces
        self.directory.mkdir(parents=True, exist_ok=True)
        self._last_index, self._closed = -1, False

    @classmethod
    def reopen(cls, directory: str | os.PathLike[str], surfaces: FluidSurfaces, frames: int) -> FluidSurfaceWriter:
        """Continue the series after its first ``frames`` frames; later files are deleted."""
        from pdmpm_cli.io.vtk import frame_index

        writer = cls(directory, surfaces)
        for body in surfaces.bodies:
            for ply in writer.directory.glob(f"{safe_name(body.name)}_surface_*.ply"):
                if frame_index(ply.name) >= frames:
                    ply.unlink()
        writer._last_index = frames - 1
        return writer

    def write_frame(self, index: int, time: float, fields: dict[str, np.ndarray]) -> None:
        check_order(self.path, self._closed, self._last_index, index)
        for body, (V, T) in zip(self.surfaces.bodies, self.surfaces.at(index, fields["particle_x"])):
            with atomic_path(self.directory / f"{safe_name(body.name)}_surface_{index:05d}.ply") as tmp:
                write_ply(tmp, V, T)
        self._last_index = index

    def close(self) -> None:
        """Nothing is buffered: each file is complete on disk."""
        self._closed = True
