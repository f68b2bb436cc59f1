"""Animated meshes for Blender, Houdini and ParaView: one binary PLY per mesh and frame.

``<directory>/<body>_NNNNN.ply`` holds a shell body's surface (its input mesh, carried by the particles) or a
Voronoi body's cell polyhedra (each cell's own vertices, so fragments separate as solid pieces; run.h5's
``triangle_cell`` gives the particle index of each triangle's cell). Blender imports a numbered PLY sequence with a
mesh-sequence add-on, ParaView opens ``<body>_..ply`` as a file series. Every file is written atomically.

The vertex positions come from the frame field ``vertex_x`` (all meshes' vertices, concatenated); the
static layout (``mesh_vertex_start`` ...) is in :func:`mesh_static_fields`.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from pdmpm_cli.io.atomic import atomic_path

VERTEX_FIELD = "vertex_x"


def mesh_static_fields(meshes) -> dict[str, np.ndarray]:
    """Static arrays describing every embedded mesh (stored in run.h5 so `render` needs nothing else)."""
    if not meshes:
        return {}
    nv = np.cumsum([0] + [len(m.vertices) for m in meshes])
    nt = np.cumsum([0] + [len(m.triangles) for m in meshes])
    return {
        "mesh_vertex_start": nv.astype(np.int64),
        "mesh_triangle_start": nt.astype(np.int64),
        "mesh_body": np.array([m.body for m in meshes], dtype=np.int32),
        "mesh_is_cells": np.array([m.kind == "cells" for m in meshes], dtype=np.uint8),
        "vertex_X": np.concatenate([m.vertices for m in meshes]),
        "mesh_triangles": np.concatenate([m.triangles for m in meshes]).astype(np.int64),  # per-mesh indices
        "triangle_cell": np.concatenate([m.triangle_cell if len(m.triangle_cell) else np.full(len(m.triangles), -1)
                                         for m in meshes]).astype(np.int64),
    }


def safe_name(name: str) -> str:
    """A body name usable in a file name."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "body"


def write_ply(path: Path, vertices: np.ndarray, triangles: np.ndarray) -> None:
    """Binary little-endian PLY of float32 vertices and triangles, written directly (meshio warns on 64-bit
    indices and cannot read back scalar face properties, so none are written)."""
    faces = np.empty(len(triangles), dtype=[("n", "u1"), ("vertex_indices", "<i4", (3,))])
    faces["n"] = 3
    faces["vertex_indices"] = triangles
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(vertices)}", "property float x",
              "property float y", "property float z", f"element face {len(triangles)}",
              "property list uchar int vertex_indices", "end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(np.ascontiguousarray(vertices, dtype="<f4").tobytes())
        f.write(faces.tobytes())


class MeshSeriesWriter:
    """Writes ``<body>_NNNNN.ply`` for every embedded mesh at every frame."""

    def __init__(self, directory: str | os.PathLike[str], meshes) -> None:
        self.directory = Path(directory)
        self.path = self.directory
        self._meshes = [(safe_name(m.name), m.triangles) for m in meshes]
        self._starts = np.cumsum([0] + [len(m.vertices) for m in meshes])
        self.directory.mkdir(parents=True, exist_ok=True)

    @classmethod
    def reopen(cls, directory: str | os.PathLike[str], meshes, frames: int) -> MeshSeriesWriter:
        """Continue the series in ``directory`` after its first ``frames`` frames; later files are deleted."""
        from pdmpm_cli.io.vtk import frame_index

        writer = cls(directory, meshes)
        for ply in writer.directory.glob("*.ply"):
            if frame_index(ply.name) >= frames:
                ply.unlink()
        return writer

    def write_frame(self, index: int, time: float, fields: dict[str, np.ndarray]) -> None:
        vertices = fields[VERTEX_FIELD]
        for (name, triangles), a, b in zip(self._meshes, self._starts[:-1], self._starts[1:]):
            with atomic_path(self.directory / f"{name}_{index:05d}.ply") as tmp:
                write_ply(tmp, vertices[a:b], triangles)

    def close(self) -> None:
        """Nothing is buffered: each file is complete on disk."""
