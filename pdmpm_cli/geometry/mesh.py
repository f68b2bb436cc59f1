"""Triangle surface meshes (closed; open ones on request): loading, validation/repair, volume.

Loading (:func:`load_surface_mesh`)
    Any format meshio reads (OBJ, STL, PLY, OFF, VTK/VTU, ...). Quads and polygons are
    fan-triangulated, higher-order faces use their corner nodes; unused vertices are dropped
    and vertices closer than 1e-9 of the bounding-box diagonal are welded (STL stores every
    triangle separately). The placement ``x = R @ (scale * x_file) + translate`` is applied
    (rotation about the file's origin, then translation).

Validation (each failure is an :class:`InputError` naming the file and the fix)
    * no triangle / polygon faces, a flat (2-D) or empty mesh;
    * more than a few degenerate (zero-area) faces; a few are tolerated (faces collapsed by the
      weld are dropped, zero-area faces with distinct corners are kept: they add nothing to the
      inside test);
    * not closed: every edge must be shared by exactly two triangles;
    * non-manifold edges (shared by more than two triangles);
    * inconsistent orientation (two adjacent triangles traverse their shared edge in the same
      direction);
    * zero enclosed volume.

    With ``allow_open=True`` (cloth / shell surfaces) boundary edges are accepted and
    ``SurfaceMesh.closed`` is False; the other checks stay, the zero-volume check and the
    inverted-surface flip below apply to closed surfaces only (an open surface has no inside).

Repair (no error, recorded in ``SurfaceMesh.repairs``)
    A consistently oriented but *inverted* surface (signed volume < 0: normals point inwards)
    is flipped, since the intent is unambiguous. Inner shells oriented opposite to the outer
    one are kept as they are: they describe cavities.

The inside test and ray queries over these meshes live in :mod:`pdmpm_cli.geometry.bvh`.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pdmpm_cli.errors import InputError

__all__ = [
    "SurfaceMesh",
    "load_surface_mesh",
    "validate_surface",
    "is_closed",
    "mesh_volume",
    "mesh_bounds",
]

#: relative (to the bbox diagonal) distance below which vertices are merged
WELD_TOLERANCE = 1e-9
#: relative (to diagonal**2) doubled triangle area below which a face counts as degenerate
DEGENERATE_AREA = 1e-12
#: degenerate faces tolerated: max(DEGENERATE_MAX_COUNT, DEGENERATE_MAX_FRACTION * n_faces)
DEGENERATE_MAX_COUNT = 5
DEGENERATE_MAX_FRACTION = 1e-3

_FIX_HOLES = "close the holes, e.g. with Blender's 'Fill Holes' (Edit mode: Select > All by Trait > Non Manifold, then Face > Fill) or meshfix"
_FIX_NONMANIFOLD = (
    "make every edge belong to exactly two faces: remove internal/duplicate faces and "
    "separate bodies that touch along an edge (Blender: Select > All by Trait > Non Manifold; "
    "or repair with meshfix)"
)
_FIX_ORIENT = (
    "make the face orientation consistent (Blender: Edit mode, select all, Mesh > Normals > "
    "Recalculate Outside; or meshfix)"
)
_FIX_UNMERGED = (
    "merge the duplicates (Blender: Edit mode, select all, Mesh > Clean Up > Merge by Distance; or meshfix)"
)
_FIX_DEGENERATE = (
    "remove the zero-area faces (Blender: Mesh > Clean Up > Merge by Distance and Degenerate "
    "Dissolve; or meshfix)"
)


# ----------------------------------------------------------------------------------------
# data
# ----------------------------------------------------------------------------------------
@dataclass(eq=False)
class SurfaceMesh:
    """A validated closed, consistently outward-oriented triangle surface (metres).

    ``vertices`` (nv, 3) float64, ``triangles`` (nt, 3) int64 (counter-clockwise seen from
    outside), ``path`` the resolved source file (``""`` if built in memory), ``repairs``
    human-readable notes of what loading changed (welds, dropped faces, flipped orientation).
    ``closed`` is False for an open surface accepted with ``allow_open=True`` (its
    orientation is as given and the inside test is meaningless for it).
    Treat the arrays as read-only: the inside-test hierarchy is cached on the object.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    path: str = ""
    repairs: list[str] = field(default_factory=list)
    closed: bool = True
    _bvh: tuple | None = field(default=None, init=False, repr=False)

    def __post_init__(self):
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int64)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise ValueError(f"vertices must have shape (nv, 3), got {self.vertices.shape}")
        if self.triangles.ndim != 2 or self.triangles.shape[1] != 3:
            raise ValueError(f"triangles must have shape (nt, 3), got {self.triangles.shape}")

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_triangles(self) -> int:
        return int(self.triangles.shape[0])


def mesh_volume(mesh: SurfaceMesh) -> float:
    """Signed enclosed volume: sum over triangles of (a . (b x c)) / 6 (relative to the centroid)."""
    V = mesh.vertices
    if mesh.triangles.shape[0] == 0:
        return 0.0
    o = V.mean(axis=0)
    a = V[mesh.triangles[:, 0]] - o
    b = V[mesh.triangles[:, 1]] - o
    c = V[mesh.triangles[:, 2]] - o
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def mesh_bounds(mesh: SurfaceMesh) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds (lo, hi) of the vertices."""
    return mesh.vertices.min(axis=0).copy(), mesh.vertices.max(axis=0).copy()


# ----------------------------------------------------------------------------------------
# loading
# ----------------------------------------------------------------------------------------
#: readers by file extension: trimesh for what it reads well, meshio's format readers for PLY and the rest
TRIMESH_FORMATS = {".obj": "OBJ", ".stl": "STL", ".off": "OFF", ".glb": "glTF binary", ".gltf": "glTF"}
#: length of one file unit in metres (``units``)
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
_EXPORT_HINT = ("export it again from the modelling tool, e.g. Blender: File > Export > Wavefront (.obj) or "
                "Stl (.stl)")


def _meshio_extensions() -> dict[str, list[str]]:
    import meshio

    return meshio.extension_to_filetypes


def supported_extensions() -> list[str]:
    """Every mesh file extension the loader reads."""
    return sorted(set(TRIMESH_FORMATS) | set(_meshio_extensions()))


def _format_of(resolved: Path) -> tuple[str, str]:
    """(reader, format name) for a file, by its extension; InputError naming the readable ones."""
    name = resolved.name.lower()
    if resolved.suffix.lower() in TRIMESH_FORMATS:
        return "trimesh", TRIMESH_FORMATS[resolved.suffix.lower()]
    for ext, types in sorted(_meshio_extensions().items(), key=lambda e: -len(e[0])):
        if name.endswith(ext):
            return "meshio", types[0]  # meshio's name of the format (e.g. "ply")
    raise InputError(
        f"mesh file {resolved}: unknown file extension '{resolved.suffix}'. Fix: export it as OBJ, STL, PLY, OFF or "
        f"glTF (.glb); the extensions read are {', '.join(supported_extensions())}"
    )


def _fmt_point(x) -> str:
    return "(" + ", ".join(f"{v:.6g}" for v in x) + ")"


def _fan(block: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons (m, k) -> (m*(k-2), 3): (v0, vi, vi+1)."""
    k = block.shape[1]
    if k == 3:
        return block
    tris = [block[:, [0, i, i + 1]] for i in range(1, k - 1)]
    return np.stack(tris, axis=1).reshape(-1, 3)


_CORNERS = {"triangle": 3, "triangle6": 3, "triangle7": 3, "quad": 4, "quad8": 4, "quad9": 4}
_VOLUME_CELLS = ("tetra", "hexahedron", "wedge", "pyramid")


def _read_trimesh(resolved: Path) -> tuple[np.ndarray, np.ndarray, str]:
    """OBJ (v/vt/vn corners, groups, materials, n-gons), STL, OFF, glTF through trimesh, as one mesh: polygons
    come fan-triangulated, scenes (OBJ objects, glTF nodes) concatenated with their transforms, vertex order
    kept as far as the format allows (OBJ: the file's order, so shell pins by vertex index match it)."""
    import trimesh

    options = {"maintain_order": True, "skip_materials": True} if resolved.suffix.lower() == ".obj" else {}
    m = trimesh.load(str(resolved), file_type=resolved.suffix.lower()[1:], force="mesh", process=False, **options)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64).reshape(-1, 3), ""


def _read_meshio(resolved: Path, file_format: str) -> tuple[np.ndarray, np.ndarray, str]:
    """PLY (any mix of polygon sizes, which trimesh's binary PLY reader cannot take), VTK, VTU, ... through
    meshio's reader for the format (which prints and ends the process on a file it cannot read: the caller
    catches that). Returns (points, triangles, a hint when there are no faces)."""
    import meshio

    m = meshio.read(str(resolved), file_format=file_format)
    pts = np.asarray(m.points, dtype=np.float64)
    faces: list[np.ndarray] = []
    volume_types = []
    for block in m.cells:
        ctype = block.type
        try:
            data = np.asarray(block.data, dtype=np.int64)
        except (TypeError, ValueError):  # ragged list of polygons of different sizes
            if ctype.startswith("polygon"):
                faces.extend(_fan(np.asarray(f, dtype=np.int64)[None, :]) for f in block.data if len(f) >= 3)
            continue
        if data.ndim != 2 or data.shape[0] == 0:
            continue
        if ctype in _CORNERS:
            faces.append(_fan(data[:, : _CORNERS[ctype]]))
        elif ctype.startswith("polygon") and data.shape[1] >= 3:
            faces.append(_fan(data))
        elif ctype.startswith(_VOLUME_CELLS):
            volume_types.append(ctype)
    hint = ""
    if volume_types:
        hint = (f"it holds only volume cells ({', '.join(sorted(set(volume_types)))}). Fix: export its boundary "
                "surface as triangles (e.g. STL or OBJ)")
    tris = np.concatenate(faces, axis=0) if faces else np.zeros((0, 3), np.int64)
    return pts, tris, hint


def read_mesh_file(resolved: Path) -> tuple[np.ndarray, np.ndarray]:
    """(points (n, 3), triangles (m, 3)) as the file stores them; InputError naming the file and the fix for a
    missing, empty, unreadable or damaged file, one without faces, NaN coordinates or faces naming missing vertices.

    Whatever a reader raises (or a `SystemExit`) becomes that InputError: no file makes pdmpm crash. The reader is
    chosen by extension (:data:`TRIMESH_FORMATS`, else meshio): on the test corpus (``bench/mesh_readers.py``)
    meshio refused Blender's OBJ with texture or normal indices and ended the process on an OFF file with quads;
    trimesh read those and glTF, but not a binary PLY that mixes triangles and quads (as Blender writes it), which
    meshio reads."""
    if not resolved.exists():
        raise InputError(f"mesh file not found: {resolved}. Fix: check the file name and folder (a relative path "
                         "starts from the scene file's folder)")
    if resolved.is_dir():
        inside = sorted(p.name for p in resolved.iterdir() if p.suffix.lower() in supported_extensions())[:5]
        holds = f" (it holds {', '.join(inside)})" if inside else ""
        raise InputError(f"mesh path {resolved} is a folder, not a mesh file{holds}. Fix: give the path of the mesh "
                         "file itself")
    if not resolved.is_file():
        raise InputError(f"mesh path {resolved} is not a regular file. Fix: give the path of a mesh file")
    reader, file_format = _format_of(resolved)
    fmt = file_format if reader == "trimesh" else file_format.upper()
    a_fmt = ("an " if fmt[0] in "AEFHILMNORSX" else "a ") + fmt  # as the letter is spoken: an OBJ, an STL, a PLY
    if resolved.stat().st_size == 0:
        raise InputError(f"mesh file {resolved} is empty (0 bytes). Fix: {_EXPORT_HINT}")
    said = io.StringIO()  # what a reader prints instead of raising (meshio)
    try:
        with (warnings.catch_warnings(), contextlib.redirect_stdout(said), contextlib.redirect_stderr(io.StringIO()),
              _quiet_logger("trimesh")):
            warnings.simplefilter("ignore")
            pts, tris, hint = _read_trimesh(resolved) if reader == "trimesh" else _read_meshio(resolved, file_format)
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # readers raise anything on a damaged file (meshio: SystemExit)
        detail = _reader_detail(exc, said.getvalue())
        raise InputError(f"mesh file {resolved} could not be read as {a_fmt} file ({detail}): it is damaged, "
                         f"truncated or in another format. Fix: {_EXPORT_HINT}") from None
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise InputError(f"mesh file {resolved}: vertex array has shape {pts.shape}, expected (n, 3). Fix: "
                         f"{_EXPORT_HINT}")
    if tris.shape[0] == 0:
        raise InputError(f"mesh file {resolved} has no faces (it holds {pts.shape[0]} vertices): "
                         + (hint or f"it is truncated, holds only points or lines, or is not {a_fmt} file. Fix: "
                            f"{_EXPORT_HINT}, as a surface of triangles or polygons"))
    if pts.shape[1] == 2:
        raise InputError(f"mesh file {resolved} is two-dimensional (vertices have 2 coordinates). Fix: export a "
                         "closed 3-D surface")
    if tris.min() < 0 or tris.max() >= pts.shape[0]:
        bad = int(tris.max()) if tris.max() >= pts.shape[0] else int(tris.min())
        raise InputError(f"mesh file {resolved}: a face refers to vertex {bad} (0-based) but the file has "
                         f"{pts.shape[0]} vertices. Fix: {_EXPORT_HINT}")
    used = np.unique(tris)
    bad = used[~np.all(np.isfinite(pts[used]), axis=1)]
    if bad.size:
        raise InputError(f"mesh file {resolved}: {bad.size} vertices have NaN or infinite coordinates (e.g. vertex "
                         f"{int(bad[0])}, 0-based). Fix: {_EXPORT_HINT}")
    return pts, tris


def _reader_detail(exc: BaseException, printed: str) -> str:
    """A reader's exception in a few words (an out-of-range face index in plain terms); for one that printed its
    reason and ended the process, the first line it printed."""
    if isinstance(exc, SystemExit):
        return printed.strip().splitlines()[0] if printed.strip() else "the reader gave up"
    if isinstance(exc, MemoryError):
        return "it asks for more memory than there is: a count or an index in it is absurdly large"
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    m = re.search(r"index (-?\d+) is out of bounds for axis 0 with size (\d+)", text)
    if m:
        return f"a face refers to vertex {m.group(1)} (0-based) but the file has {m.group(2)} vertices"
    text = text if len(text) <= 120 else text[:117] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


@contextlib.contextmanager
def _quiet_logger(name: str):
    """Keep a library's log records (a missing material file, ...) off the user's terminal while it reads."""
    log = logging.getLogger(name)
    handler, propagate = logging.NullHandler(), log.propagate
    log.addHandler(handler)
    log.propagate = False
    try:
        yield
    finally:
        log.removeHandler(handler)
        log.propagate = propagate


def _compact(V: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop unused vertices and renumber."""
    used, inv = np.unique(T, return_inverse=True)
    return V[used], inv.reshape(T.shape).astype(np.int64)


def _weld(V: np.ndarray, T: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Merge vertices closer than ``tol`` (transitively). Returns (V, T, n_merged)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    nv = V.shape[0]
    pairs = cKDTree(V).query_pairs(tol, output_type="ndarray")
    if pairs.shape[0] == 0:
        return V, T, 0
    g = coo_matrix((np.ones(pairs.shape[0], dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(nv, nv))
    ncomp, labels = connected_components(g, directed=False)
    first = np.full(ncomp, nv, dtype=np.int64)
    np.minimum.at(first, labels, np.arange(nv))
    return V[first], labels[T].astype(np.int64), nv - ncomp


#: a boundary vertex this close to another vertex, relative to the median edge length, is an unmerged duplicate
NEAR_DUPLICATE = 0.01


def _unmerged(V, T, boundary_keys, nv) -> str:
    """Advice when most boundary vertices have another vertex much closer than the edges are long: the surface
    is closed but stored with duplicate vertices a little apart (beyond the weld tolerance); '' otherwise."""
    from scipy.spatial import cKDTree

    verts = np.unique(np.concatenate([boundary_keys // nv, boundary_keys % nv]))
    edge = float(np.median(np.linalg.norm(V[T[:, 1]] - V[T[:, 0]], axis=1)))
    d, _ = cKDTree(V).query(V[verts], k=2)
    near = d[:, 1] < NEAR_DUPLICATE * edge
    if near.sum() < 0.5 * verts.size:
        return ""
    gap = float(d[near, 1].max())
    return (f"{int(near.sum())} of its {verts.size} boundary vertices lie within {gap:.2g} m of another vertex: it is "
            f"probably closed, stored with each corner repeated a little apart. Fix: {_FIX_UNMERGED} (a distance of "
            f"{2 * gap:.2g} m)")


def _edge_examples(V, edges, k=2) -> str:
    return "; ".join(f"{_fmt_point(V[u])} - {_fmt_point(V[v])}" for u, v in edges[:k])


def validate_surface(
    V: np.ndarray, T: np.ndarray, where: str, *, allow_open: bool = False
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Check/repair a triangle surface (see module doc). Returns (V, T, repairs).

    ``where`` names the source in error messages (e.g. "mesh file /abs/path.stl").
    ``allow_open`` accepts boundary edges (a cloth); use :func:`is_closed` on the result to
    know whether there were any.
    """
    repairs: list[str] = []
    V = np.ascontiguousarray(V, dtype=np.float64)
    T = np.ascontiguousarray(T, dtype=np.int64)
    if T.shape[0] == 0:
        raise InputError(f"{where} has no triangles")
    V, T = _compact(V, T)
    diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    if not diag > 0.0:
        raise InputError(f"{where}: all vertices coincide; the mesh has no extent. Fix: export the mesh again")

    # --- weld duplicate vertices (STL stores every triangle separately)
    V, T, n_merged = _weld(V, T, WELD_TOLERANCE * diag)
    if n_merged:
        repairs.append(f"merged {n_merged} duplicate vertices")

    # --- degenerate faces
    collapsed = (T[:, 0] == T[:, 1]) | (T[:, 1] == T[:, 2]) | (T[:, 2] == T[:, 0])
    a, b, c = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    dbl_area = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    zero_area = (dbl_area <= DEGENERATE_AREA * diag * diag) & ~collapsed
    n_deg = int(collapsed.sum() + zero_area.sum())
    allowed = max(DEGENERATE_MAX_COUNT, int(DEGENERATE_MAX_FRACTION * T.shape[0]))
    if n_deg > allowed:
        k = int(np.flatnonzero(collapsed | zero_area)[0])
        raise InputError(
            f"{where}: {n_deg} of {T.shape[0]} faces are degenerate (zero area; at most "
            f"{allowed} are tolerated), e.g. the face with corners {_fmt_point(V[T[k, 0]])}, "
            f"{_fmt_point(V[T[k, 1]])}, {_fmt_point(V[T[k, 2]])}. Fix: {_FIX_DEGENERATE}"
        )
    if collapsed.any():
        T = T[~collapsed]
        repairs.append(f"dropped {int(collapsed.sum())} collapsed (zero-area) faces")
        if T.shape[0] == 0:
            raise InputError(f"{where}: every face is degenerate (zero area). Fix: {_FIX_DEGENERATE}")
        V, T = _compact(V, T)
    if zero_area.any():
        repairs.append(f"kept {int(zero_area.sum())} zero-area faces (harmless)")

    # --- edge topology: closed, manifold, consistently oriented
    nv = V.shape[0]
    u = T.reshape(-1)
    v = T[:, [1, 2, 0]].reshape(-1)
    lo_, hi_ = np.minimum(u, v), np.maximum(u, v)
    key = lo_ * nv + hi_
    forward = (u < v).astype(np.int64)
    uniq, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    problems = []
    boundary = counts == 1
    unmerged = _unmerged(V, T, uniq[boundary], nv) if boundary.any() else ""
    if boundary.any() and not allow_open:
        e = uniq[boundary]
        edges = np.stack([e // nv, e % nv], axis=1)
        problems.append(
            f"the surface is not closed: {int(boundary.sum())} boundary edges (edges used by "
            f"only one triangle), e.g. {_edge_examples(V, edges)}"
            + (f", but {unmerged}" if unmerged else f". Fix: {_FIX_HOLES}")
        )
    elif unmerged:
        repairs.append(f"the surface has {int(boundary.sum())} boundary edges, but {unmerged}")
    nonmanifold = counts > 2
    if nonmanifold.any():
        e = uniq[nonmanifold]
        edges = np.stack([e // nv, e % nv], axis=1)
        problems.append(
            f"{int(nonmanifold.sum())} non-manifold edges (shared by more than two triangles), "
            f"e.g. {_edge_examples(V, edges)}. Fix: {_FIX_NONMANIFOLD}"
        )
    n_fwd = np.bincount(inv, weights=forward, minlength=uniq.shape[0])
    bad_orient = (counts == 2) & (n_fwd != 1)
    if bad_orient.any():
        e = uniq[bad_orient]
        edges = np.stack([e // nv, e % nv], axis=1)
        problems.append(
            f"inconsistent orientation: at {int(bad_orient.sum())} edges the two adjacent "
            f"triangles traverse the shared edge in the same direction (some faces are flipped), "
            f"e.g. {_edge_examples(V, edges)}. Fix: {_FIX_ORIENT}"
        )
    if problems:
        kind = "surface" if allow_open else "closed surface"
        raise InputError(f"{where} is not a valid {kind}: " + " Also: ".join(problems))
    if boundary.any():  # open (allowed): no inside, so no volume check and no flip
        return V, np.ascontiguousarray(T), repairs

    # --- orientation sign
    vol = mesh_volume(SurfaceMesh(V, T))
    if not abs(vol) > 1e-12 * diag**3:
        raise InputError(
            f"{where}: the closed surface encloses zero volume (flat or self-cancelling). Fix: model a solid, a "
            "surface around a volume; a flat sheet can be a shell body (mode: shell, layers: 1)"
        )
    if vol < 0.0:
        T = T[:, [0, 2, 1]].copy()
        repairs.append("flipped all faces: the surface was inverted (normals pointing inwards)")
    return V, np.ascontiguousarray(T), repairs


def is_closed(T: np.ndarray) -> bool:
    """True if every edge of the triangles ``T`` is used by at least two of them (no boundary)."""
    T = np.asarray(T, dtype=np.int64)
    if T.shape[0] == 0:
        return False
    u = T.reshape(-1)
    v = T[:, [1, 2, 0]].reshape(-1)
    lo_, hi_ = np.minimum(u, v), np.maximum(u, v)
    _, counts = np.unique(lo_ * (int(T.max()) + 1) + hi_, return_counts=True)
    return bool(np.all(counts >= 2))


def place(points: np.ndarray, *, units: str = "m", scale=1.0, R=None, translate=(0.0, 0.0, 0.0), fit=None,
          where: str = "mesh") -> np.ndarray:
    """A mesh file's coordinates in metres: ``x = R (units * scale * x_file) + translate`` (``scale`` one factor or
    one per axis, the rotation about the file's origin). With ``fit = (size, axis, center)`` the rotated mesh is
    instead scaled uniformly so that its bounding box is ``size`` metres long along ``axis`` ("x", "y", "z" or
    "longest") and moved so that the box's centre is ``center``, as the built-in bunny's height and center."""
    from pdmpm_cli.geometry.shapes import _rotation, _vec3

    if units not in UNITS:
        raise InputError(f"{where}: units must be one of {', '.join(UNITS)}, got {units!r}")
    s = np.asarray(scale, dtype=np.float64)
    if s.shape not in ((), (3,)) or not np.all(np.isfinite(s)) or np.any(s <= 0.0):
        raise InputError(f"{where}: scale must be a positive number or 3 positive numbers, got {scale!r}")
    V = (points * (UNITS[units] * s)) @ _rotation(R).T
    if fit is None:
        return V + _vec3(translate, "translate")
    size, axis, center = fit
    lo, hi = V.min(axis=0), V.max(axis=0)
    extent = hi - lo
    a = int(np.argmax(extent)) if axis == "longest" else "xyz".index(axis)
    if not extent[a] > 0.0:
        raise InputError(f"{where}: the mesh has no extent along {'xyz'[a]}, so it cannot be fitted to a size "
                         f"along it. Fix: fit along another axis (fit.axis)")
    k = float(size) / extent[a]
    return k * (V - 0.5 * (lo + hi)) + _vec3(center, "fit.center")


def load_surface_mesh(
    path, scale=1.0, translate=(0.0, 0.0, 0.0), R=None, *, units: str = "m", fit=None, allow_open: bool = False
) -> SurfaceMesh:
    """Read, place, weld, validate and (if inverted) flip a closed triangle surface.

    Placement as :func:`place` (``units``, ``scale``, rotation matrix ``R``, ``translate`` or ``fit``).
    ``allow_open`` also accepts a surface with holes / boundary (a cloth): ``closed`` is then
    False and its orientation is kept as in the file.
    Raises :class:`InputError` naming the (resolved) path and the fix for any problem.
    """
    resolved = Path(os.path.expanduser(str(path))).resolve()
    where = f"mesh file {resolved}"
    pts, tris = read_mesh_file(resolved)
    pts, tris = _compact(pts, tris)
    V = place(pts, units=units, scale=scale, R=R, translate=translate, fit=fit, where=where)
    V, T, repairs = validate_surface(V, tris, where, allow_open=allow_open)
    return SurfaceMesh(V, T, str(resolved), repairs, closed=is_closed(T))
