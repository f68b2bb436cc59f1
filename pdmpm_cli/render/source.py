"""A run as render reads it (`RunSource`): from run.h5, or from the VTK series and PLY meshes."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from pdmpm_cli.errors import InputError

_RUN_FIRST = "run `pdmpm run SCENE.yaml --out {folder}` first"


@dataclass(frozen=True)
class BodyInfo:
    name: str
    model: str  # elastic, plastic or viscoelastic
    spacing: float  # particle spacing h [m]


@dataclass(frozen=True)
class MeshPart:
    """A shell surface or a Voronoi body's cell polyhedra, as written per frame."""

    name: str
    body: int
    is_cells: bool
    faces: np.ndarray  # pyvista face array (3, a, b, c, 3, ...)
    owner: np.ndarray  # particle whose value colours each triangle (cells) or each vertex (shells)


@dataclass(frozen=True)
class Frame:
    index: int
    time: float
    x: np.ndarray  # (n, 3) particle positions [m]
    fields: dict[str, np.ndarray]  # per-frame particle fields
    vertices: list[np.ndarray]  # vertex positions of each MeshPart [m]


@dataclass
class RunSource:
    """What render needs of a run, whichever files it came from."""

    folder: Path
    times: np.ndarray
    bodies: list[BodyInfo]
    particle_body: np.ndarray
    particle_volume: np.ndarray
    meshes: list[MeshPart]
    field_names: set[str]
    scene: dict  # the parsed scene YAML; empty when only the VTK series is there
    read: Callable[[int], Frame]
    floor_cells: int | None = None  # material rests this many cells inside the domain walls; None: not recorded

    def __len__(self) -> int:
        return len(self.times)


# ---------------------------------------------------------------- reading a run


def open_run(folder: Path) -> RunSource:
    """The run in `folder`: run.h5 when present, else the VTK series and PLY meshes."""
    folder = Path(folder)
    if (folder / "run.h5").is_file():
        return _h5_source(folder)
    if (folder / "vtk" / "particles.pvd").is_file():
        return _vtk_source(folder)
    what = "does not exist" if not folder.exists() else "holds no run.h5 and no vtk/particles.pvd"
    raise InputError(f"{folder}: {what}; {_RUN_FIRST.format(folder=folder)}")


def nearest(points: np.ndarray, queries: np.ndarray, k: int = 1) -> np.ndarray:
    """Index of the nearest point to each query; (queries, k) indices of the k nearest when k > 1."""
    from scipy.spatial import cKDTree

    return cKDTree(points).query(queries, k=min(k, len(points)))[1]


def _faces(triangles: np.ndarray) -> np.ndarray:
    return np.hstack([np.full((len(triangles), 1), 3), triangles]).ravel()


def _h5_source(folder: Path) -> RunSource:
    from pdmpm_cli.io.hdf5 import read_run

    run = read_run(folder / "run.h5")
    if len(run) == 0:
        raise InputError(f"{folder / 'run.h5'}: the run has no complete frame yet; wait, or re-run it")
    s = run.static
    bodies = [BodyInfo(b["name"], b["model"], float(b["spacing"])) for b in run.plan["bodies"]]
    spans = list(zip(s["mesh_vertex_start"][:-1], s["mesh_vertex_start"][1:])) if "mesh_vertex_start" in s else []
    meshes = [_h5_mesh(s, m, bodies) for m in range(len(spans))]

    def read(i: int) -> Frame:
        f = run.frame(i)
        vertices = [f["vertex_x"][a:b] for a, b in spans]
        return Frame(i, float(run.times[i]), f["particle_x"], f, vertices)

    wall = run.plan.get("wall_cells")  # the engine's wall layer, recorded with the run
    return RunSource(folder, run.times, bodies, s["particle_body"], s["particle_volume"], meshes,
                     set(run.field_names) | {"particle_body"}, run.plan.get("scene") or _scene_dict(run.scene_text),
                     read, None if wall is None else wall - 1)


def _h5_mesh(s: dict, m: int, bodies: list[BodyInfo]) -> MeshPart:
    """Mesh m of run.h5; a shell vertex takes the colour of the particle nearest to it at rest."""
    v0, v1 = s["mesh_vertex_start"][m:m + 2]
    t0, t1 = s["mesh_triangle_start"][m:m + 2]
    body, is_cells = int(s["mesh_body"][m]), bool(s["mesh_is_cells"][m])
    if is_cells:
        owner = s["triangle_cell"][t0:t1]
    else:
        mine = np.flatnonzero(s["particle_body"] == body)
        owner = mine[nearest(s["particle_X"][mine], s["vertex_X"][v0:v1])]
    return MeshPart(bodies[body].name, body, is_cells, _faces(s["mesh_triangles"][t0:t1]), owner)


def _scene_dict(text: str) -> dict:
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        return {}
    return data if isinstance(data, dict) else {}


def _vtk_source(folder: Path) -> RunSource:
    """The ParaView series: no plan or scene, so spacing comes from particle volumes, models are unknown."""
    import meshio

    entries = _pvd_entries(folder / "vtk" / "particles.pvd")
    first = meshio.read(entries[0][2])
    x0, data = first.points, first.point_data
    # With an emitter the last frame holds the most particles, and every frame a prefix of them
    last = meshio.read(entries[-1][2]).point_data if len(entries) > 1 else data
    body, volume = last["particle_body"].astype(int), last["particle_volume"]
    plys = _ply_series(folder / "meshes", entries[0][1])
    meshes = [_ply_mesh(name, path, x0, body[:len(x0)]) for name, path in plys]
    names = {m.body: m.name for m in meshes}
    bodies = [BodyInfo(names.get(b, f"body {b}"), "elastic", float(np.median(volume[body == b]) ** (1 / 3)))
              for b in range(body.max() + 1)]

    def read(i: int) -> Frame:
        t, index, path = entries[i]
        vtu = meshio.read(path)
        vertices = [meshio.read(folder / "meshes" / f"{name}_{index:05d}.ply").points for name, _ in plys]
        return Frame(i, t, vtu.points, vtu.point_data, vertices)

    return RunSource(folder, np.array([e[0] for e in entries]), bodies, body, volume, meshes,
                     set(data) | {"particle_body"}, {}, read)


def _pvd_entries(pvd: Path) -> list[tuple[float, int, Path]]:
    """(time, frame index, VTU path) of every frame the collection lists."""
    from pdmpm_cli.io.vtk import frame_index, read_pvd

    entries = read_pvd(pvd)
    if not entries:
        raise InputError(f"{pvd}: lists no frames; {_RUN_FIRST.format(folder=pvd.parents[1])}")
    return [(t, frame_index(name), pvd.parent / name) for t, name in entries]


def _ply_series(meshes: Path, index: int) -> list[tuple[str, Path]]:
    """(mesh name, its PLY file at frame `index`) for every mesh series in `meshes`."""
    found = (re.fullmatch(rf"(.+)_{index:05d}\.ply", p.name) for p in sorted(meshes.glob("*.ply")))
    return [(m.group(1), meshes / m.group(0)) for m in found if m]


def _ply_mesh(name: str, path: Path, x0: np.ndarray, body: np.ndarray) -> MeshPart:
    """A PLY mesh and its owners: Voronoi cells are separate closed pieces (one per particle), a shell is
    one connected surface; pieces and vertices take the particle nearest to them."""
    import meshio
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    mesh = meshio.read(path)
    tri, points = mesh.cells_dict["triangle"], mesh.points
    edges = coo_matrix((np.ones(2 * len(tri)), (tri[:, [0, 1]].ravel(), tri[:, [1, 2]].ravel())),
                       shape=(len(points), len(points)))
    n_pieces, piece = connected_components(edges, directed=False)
    if n_pieces > 1:
        centres = np.stack([np.bincount(piece, weights=c) for c in points.T], axis=1) / np.bincount(piece)[:, None]
        owner = nearest(x0, centres)[piece[tri[:, 0]]]
    else:
        owner = nearest(x0, points)
    return MeshPart(name, int(np.bincount(body[owner]).argmax()), n_pieces > 1, _faces(tri), owner)
