"""Offscreen pictures of a finished run, from its exported files only (used by `pdmpm render`).

The run is read from ``OUT/run.h5`` or, when a scene turned HDF5 off, from the ParaView series
(``OUT/vtk/particles.pvd``) and ``OUT/meshes/*.ply``; the scene's inputs are never needed. Each body is
drawn the way it reads best: shells as their smooth surface, Voronoi bodies as solid cell polyhedra (so
fragments show as pieces), viscoelastic fluids as a surface reconstructed from the particles, everything
else as spheres. All frames share one colour range and one Plotter (a fresh one per frame costs seconds).
Library code: progress goes to a callback, nothing is printed.
"""

from __future__ import annotations

import importlib.util
import os
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from pydantic import TypeAdapter, ValidationError

from pdmpm_cli.engine.transfer import WALL
from pdmpm_cli.errors import InputError
from pdmpm_cli.scene.schema import Camera, Collider, RenderSettings

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")  # headless: no X server needed
import pyvista as pv  # noqa: E402  (needs the window class chosen above)

pv.OFF_SCREEN = True

# --field -> (run field, scalar-bar title)
FIELDS = {
    "speed": ("particle_speed", "speed [m/s]"),
    "damage": ("particle_damage", "damage [-]"),
    "plastic": ("particle_plastic_strain", "plastic strain [-]"),
    "body": ("particle_body", "body"),
}
FLOOR_CELLS = WALL - 1  # material rests on the domain walls this many cells inside grid.domain
BODY_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
               "#17becf")  # matplotlib's tab10, in order: body 0 blue, body 1 orange, ...
FLUID_GRID_CELLS = 2e7  # cap on the splatting grid of a fluid surface (memory, marching-cubes time)
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

    def __len__(self) -> int:
        return len(self.times)


@dataclass
class RenderResult:
    images: list[Path]
    video: Path | None
    seconds_per_frame: float


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


def _nearest(points: np.ndarray, queries: np.ndarray, k: int = 1) -> np.ndarray:
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

    return RunSource(folder, run.times, bodies, s["particle_body"], s["particle_volume"], meshes,
                     set(run.field_names) | {"particle_body"}, run.plan.get("scene") or _scene_dict(run.scene_text),
                     read)


def _h5_mesh(s: dict, m: int, bodies: list[BodyInfo]) -> MeshPart:
    """Mesh m of run.h5; a shell vertex takes the colour of the particle nearest to it at rest."""
    v0, v1 = s["mesh_vertex_start"][m:m + 2]
    t0, t1 = s["mesh_triangle_start"][m:m + 2]
    body, is_cells = int(s["mesh_body"][m]), bool(s["mesh_is_cells"][m])
    if is_cells:
        owner = s["triangle_cell"][t0:t1]
    else:
        mine = np.flatnonzero(s["particle_body"] == body)
        owner = mine[_nearest(s["particle_X"][mine], s["vertex_X"][v0:v1])]
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
    body, volume = data["particle_body"].astype(int), data["particle_volume"]
    plys = _ply_series(folder / "meshes", entries[0][1])
    meshes = [_ply_mesh(name, path, x0, body) for name, path in plys]
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
        owner = _nearest(x0, centres)[piece[tri[:, 0]]]
    else:
        owner = _nearest(x0, points)
    return MeshPart(name, int(np.bincount(body[owner]).argmax()), n_pieces > 1, _faces(tri), owner)


# ---------------------------------------------------------------- options


def parse_frames(text: str | None, n: int) -> list[int]:
    """Frame indices from a python-style slice 'START:STOP[:STEP]' (or one index); None: all frames."""
    if text is None:
        return list(range(n))
    try:
        parts = [int(p) if p.strip() else None for p in text.split(":")]
        if len(parts) > 3:
            raise ValueError
        chosen = slice(*parts) if len(parts) > 1 else slice(parts[0], parts[0] + 1 or None)
        indices = list(range(n))[chosen]
    except (ValueError, TypeError):
        raise InputError(f"--frames {text!r}: expected START:STOP[:STEP] like python slicing, e.g. 0:100:2 or -1")
    if not indices:
        raise InputError(f"--frames {text!r} selects no frame: the run has {n} frames (0 to {n - 1})")
    return indices


def parse_resolution(text: str) -> tuple[int, int]:
    """'1280x720' -> (1280, 720)."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    try:
        return RenderSettings(resolution=(int(match[1]), int(match[2]))).resolution  # the schema's size check
    except (TypeError, ValidationError):  # no match, or too small
        raise InputError(f"--resolution {text!r}: expected WIDTHxHEIGHT in pixels, each >= 16, e.g. 1280x720") from None


def parse_camera(text: str) -> Camera:
    """'px,py,pz;fx,fy,fz[;ux,uy,uz]' (position; focus; up) in metres -> Camera."""
    try:
        vectors = [tuple(float(c) for c in part.split(",")) for part in text.split(";")]
        if len(vectors) not in (2, 3) or any(len(v) != 3 for v in vectors):
            raise ValueError
        return Camera(**dict(zip(("position", "focus", "up"), vectors)))
    except ValueError:
        raise InputError(f"--camera {text!r}: expected 'px,py,pz;fx,fy,fz[;ux,uy,uz]' (position; focus; up) in m, "
                         f"e.g. '1.5,1.2,2.5;0.5,0.4,0.5'") from None


def scene_settings(source: RunSource) -> RenderSettings:
    """The scene's `render` section (defaults when absent or when only the VTK series is there)."""
    try:
        return RenderSettings.model_validate(source.scene.get("render") or {})
    except ValidationError as error:
        raise InputError(f"{source.folder}: the scene's render section is invalid: {error}") from None


# ---------------------------------------------------------------- colour field


def check_field(source: RunSource, name: str) -> None:
    """InputError naming what is there and how to get the missing field."""
    available = [f for f, (run_name, _) in FIELDS.items() if f == "speed" or run_name in source.field_names]
    if name in available:
        return
    if name not in FIELDS:
        raise InputError(f"field {name!r}: unknown; choose one of {', '.join(FIELDS)}")
    run_name = FIELDS[name][0]
    note = {"damage": " (only bodies with `fracture` have damage)",
            "plastic": " (only `model: plastic` bodies have plastic strain)"}[name]
    raise InputError(f"field {name!r}: this run has no {run_name}{note}; available: {', '.join(available)}. "
                     f"Add {run_name} to output.fields in the scene and run it again")


def field_values(source: RunSource, name: str, frame: Frame) -> np.ndarray:
    """Per-particle values of --field `name`; speed falls back to |v|, then to the motion between frames."""
    if name == "body":
        return source.particle_body.astype(float)
    if name != "speed":
        return np.asarray(frame.fields[FIELDS[name][0]], dtype=float)
    if "particle_speed" in frame.fields:
        return np.asarray(frame.fields["particle_speed"], dtype=float)
    if "particle_v" in frame.fields:
        return np.linalg.norm(frame.fields["particle_v"], axis=1)
    if len(source) < 2:
        return np.zeros(len(frame.x))
    other = source.read(frame.index - 1 if frame.index > 0 else 1)
    return np.linalg.norm(frame.x - other.x, axis=1) / abs(frame.time - other.time)


def _color_range(name: str, highs: list[float]) -> tuple[float, float]:
    """Fixed over all frames so the animation does not flicker; damage is 0..1 by definition."""
    if name == "damage":
        return 0.0, 1.0
    return 0.0, max(max(highs), 1e-9)


def _survey(source: RunSource, indices: list[int], name: str) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Bounding box of the particles over the frames (for the camera) and each frame's colour maximum (the
    99.5th percentile: a few stray fast particles must not wash out the colours of the rest)."""
    lo, hi, highs = np.full(3, np.inf), np.full(3, -np.inf), []
    for i in indices:
        frame = source.read(i)
        lo, hi = np.minimum(lo, frame.x.min(axis=0)), np.maximum(hi, frame.x.max(axis=0))
        highs.append(float(np.percentile(field_values(source, name, frame), 99.5)))
    return lo, hi, highs


# ---------------------------------------------------------------- geometry


def fluid_surface(x: np.ndarray, volume: np.ndarray, spacing: float) -> pv.PolyData:
    """A smooth surface around fluid particles: volumes splatted on a grid of about h/2, Gaussian-smoothed over
    h, contoured at the level whose enclosed volume matches the particles' volume (a fixed level loses thin
    streams), then lightly smoothed. Particles alone read as sand, not honey."""
    from scipy.ndimage import gaussian_filter

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


def _up(scene: dict) -> np.ndarray:
    """Against gravity; +y when there is none."""
    g = np.asarray(scene.get("gravity", (0.0, -9.81, 0.0)), dtype=float)
    return -g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.array([0.0, 1.0, 0.0])


def auto_camera(lo: np.ndarray, hi: np.ndarray, up: np.ndarray, aspect: float, view_angle: float = 30.0) -> Camera:
    """A 3/4 view from the front, right and above, far enough to frame the box (lo, hi) at this aspect."""
    front = np.array([0.0, 0.0, 1.0]) if abs(up[2]) < 0.9 else np.array([0.0, -1.0, 0.0])
    front = front - (front @ up) * up
    front /= np.linalg.norm(front)
    direction = 1.0 * front + 0.6 * np.cross(up, front) + 0.5 * up
    direction /= np.linalg.norm(direction)
    radius = max(np.linalg.norm(hi - lo) / 2, 1e-3)
    half = np.radians(view_angle) / 2
    half = min(half, np.arctan(aspect * np.tan(half)))  # the narrower of the two image axes
    distance = 1.05 * radius / np.sin(half)
    focus = (lo + hi) / 2
    return Camera(position=tuple(focus + distance * direction), focus=tuple(focus), up=tuple(up),
                  view_angle=view_angle)


def _colliders(scene: dict) -> list:
    try:
        return TypeAdapter(list[Collider]).validate_python(scene.get("colliders") or [])
    except ValidationError:
        return []  # the run validated them; a scene text this version cannot read just loses its colliders


def _collider_mesh(c) -> pv.PolyData:
    """A box, sphere or cylinder collider at time 0."""
    if c.type == "box":
        lo, hi = np.subtract(c.center, np.divide(c.size, 2)), np.add(c.center, np.divide(c.size, 2))
        return pv.Box(bounds=(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))
    if c.type == "sphere":
        return pv.Sphere(radius=c.radius, center=c.center, theta_resolution=48, phi_resolution=24)
    return pv.Cylinder(center=c.center, direction=c.axis, radius=c.radius, height=c.height, resolution=48)


def _ground(center: np.ndarray, normal, size: float) -> pv.PolyData:
    """A square of `size` with checker texture coordinates: tiles of a round size (1, 10, 100 cm ...) give scale
    and make sliding visible."""
    tile = 10 ** np.round(np.log10(size / 120))
    plane = pv.Plane(center=center, direction=normal, i_size=size, j_size=size)
    plane.texture_map_to_plane(inplace=True)
    plane.active_texture_coordinates *= size / (2 * tile)  # the texture holds 2 x 2 tiles
    return plane


def _checker() -> pv.Texture:
    light, dark = 222, 196
    tiles = np.where(np.add.outer(np.arange(64) // 32, np.arange(64) // 32) % 2, dark, light).astype(np.uint8)
    texture = pv.Texture(np.repeat(tiles[:, :, None], 3, axis=2))
    texture.repeat, texture.mipmap, texture.interpolate = True, True, True
    return texture


def _plane_center(c, focus: np.ndarray) -> np.ndarray:
    """`focus` projected onto the plane collider, so the ground square lies under the bodies."""
    n = np.asarray(c.normal) / np.linalg.norm(c.normal)
    return focus - ((focus - np.asarray(c.point)) @ n) * n


def _floor(scene: dict, focus: np.ndarray, size: float) -> pv.PolyData | None:
    """The domain wall that gravity pushes towards, for scenes without a ground plane collider."""
    grid = scene.get("grid") or {}
    g = np.asarray(scene.get("gravity", (0.0, -9.81, 0.0)), dtype=float)
    if not grid.get("domain") or not g.any():
        return None
    axis = int(np.argmax(np.abs(g)))
    inset = FLOOR_CELLS * float(grid["cell_size"])
    center = focus.copy()
    center[axis] = grid["domain"]["min"][axis] + inset if g[axis] < 0 else grid["domain"]["max"][axis] - inset
    return _ground(center, -np.sign(g[axis]) * np.eye(3)[axis], size)


# ---------------------------------------------------------------- drawing


@dataclass
class _Layer:
    """One body's drawing: `build` makes this frame's mesh, copied into the mesh the plotter shows."""

    build: Callable[[Frame, np.ndarray], pv.PolyData]
    style: dict
    sphere_radius: float | None = None
    shown: pv.PolyData | None = None


def _spheres(idx: np.ndarray, radius: float) -> _Layer:
    def build(frame: Frame, values: np.ndarray) -> pv.PolyData:
        cloud = pv.PolyData(frame.x[idx])
        cloud.point_data["value"] = values[idx]
        return cloud

    return _Layer(build, dict(style="points", render_points_as_spheres=True), sphere_radius=radius)


def _mesh(part: MeshPart, k: int) -> _Layer:
    """Voronoi cells flat-shaded per cell (pieces read as solid fragments); shells smooth-shaded."""
    def build(frame: Frame, values: np.ndarray) -> pv.PolyData:
        mesh = pv.PolyData(frame.vertices[k], part.faces)
        if part.is_cells:
            mesh.cell_data["value"] = values[part.owner]
            return mesh
        mesh.point_data["value"] = values[part.owner]
        return mesh.compute_normals(split_vertices=False)

    return _Layer(build, {} if part.is_cells else dict(interpolation="phong"))


def _fluid(idx: np.ndarray, volume: np.ndarray, spacing: float) -> _Layer:
    def build(frame: Frame, values: np.ndarray) -> pv.PolyData:
        x = frame.x[idx]
        surface = fluid_surface(x, volume, spacing)
        if surface.n_points:  # the mean of a few neighbours: single particles' values would look blotchy
            near = _nearest(x, surface.points, k=8).reshape(surface.n_points, -1)
            surface.point_data["value"] = values[idx][near].mean(axis=1)
        return surface

    return _Layer(build, dict(interpolation="phong", specular=0.4))


def _layers(source: RunSource) -> list[_Layer]:
    layers = []
    for b, body in enumerate(source.bodies):
        parts = [(k, m) for k, m in enumerate(source.meshes) if m.body == b]
        idx = np.flatnonzero(source.particle_body == b)
        if parts:
            layers += [_mesh(m, k) for k, m in parts]
        elif body.model == "viscoelastic":
            layers.append(_fluid(idx, source.particle_volume[idx], body.spacing))
        else:
            layers.append(_spheres(idx, body.spacing / 2))
    return layers


def _font_size(resolution: tuple[int, int]) -> int:
    """Text in proportion to the image, readable in a small contact-sheet tile."""
    return max(10, round(resolution[1] / 45))


def _color_style(source: RunSource, name: str, clim: tuple[float, float], font: int) -> dict:
    """Colour mapping shared by every body, with one scalar bar at the right edge (clear of centred bodies)."""
    bar = dict(title=FIELDS[name][1], vertical=True, position_x=0.86, position_y=0.15, width=0.05, height=0.7,
               title_font_size=font, label_font_size=font, unconstrained_font_size=True)
    if name != "body":
        return dict(scalars="value", cmap="viridis", clim=clim, scalar_bar_args=bar)
    n = len(source.bodies)
    return dict(scalars="value", cmap=[BODY_COLORS[b % len(BODY_COLORS)] for b in range(n)], clim=(-0.5, n - 0.5),
                annotations={i: b.name for i, b in enumerate(source.bodies)}, scalar_bar_args=bar | {"n_labels": 0})


class _Scene:
    """The plotter with its static props (floor, colliders) and the bodies, updated frame by frame."""

    def __init__(self, source: RunSource, resolution: tuple[int, int], camera: Camera, color: dict,
                 lo: np.ndarray, hi: np.ndarray):
        self.source, self.color, self.font = source, color, _font_size(resolution)
        self.layers = _layers(source)
        self.plotter = pv.Plotter(off_screen=True, window_size=list(resolution), theme=pv.themes.DocumentTheme())
        self.plotter.set_background("white", top="#c8d4e6")
        self.plotter.enable_anti_aliasing("msaa")
        self.moving = self._add_props(lo, hi)
        self.clock = self.plotter.add_text("", position=(0.015, 0.93), viewport=True, font_size=self.font)
        cam = self.plotter.camera
        cam.position, cam.focal_point, cam.up = camera.position, camera.focus, camera.up
        cam.view_angle = camera.view_angle
        distance = np.linalg.norm(np.subtract(camera.position, camera.focus))
        # points are drawn as spheres of a size in pixels: right at the focus, close elsewhere
        self.pixels_per_metre = resolution[1] / (2 * distance * np.tan(np.radians(camera.view_angle) / 2))

    def _add_props(self, lo: np.ndarray, hi: np.ndarray) -> list[tuple]:
        """Ground and colliders (translucent, so contact stays visible); returns (actor, velocity) of moving ones."""
        scene, focus, size = self.source.scene, (lo + hi) / 2, 40 * max(float(np.max(hi - lo)), 1e-3)
        colliders = _colliders(scene)
        moving = []
        for c in colliders:
            if c.type == "plane":
                actor = self.plotter.add_mesh(_ground(_plane_center(c, focus), c.normal, size), texture=_checker())
            else:
                actor = self.plotter.add_mesh(_collider_mesh(c), color="#8c8c8c", smooth_shading=True,
                                              opacity=0.15 if c.inside_out else 0.35)
            if any(c.velocity):
                moving.append((actor, np.asarray(c.velocity)))
        floor = None if any(c.type == "plane" for c in colliders) else _floor(scene, focus, size)
        if floor is not None:
            self.plotter.add_mesh(floor, texture=_checker())
        return moving

    def draw(self, frame: Frame, values: np.ndarray, path: Path) -> None:
        for layer in self.layers:
            mesh = layer.build(frame, values)
            if layer.shown is None:
                layer.shown = mesh
                actor = self.plotter.add_mesh(mesh, **self.color, **layer.style)
                if layer.sphere_radius:
                    actor.prop.point_size = 2 * layer.sphere_radius * self.pixels_per_metre
            else:
                layer.shown.copy_from(mesh, deep=False)
        for actor, velocity in self.moving:
            actor.position = velocity * frame.time
        self.clock.SetInput(f"t = {frame.time:.3f} s")
        self.plotter.renderer.ResetCameraClippingRange()
        self.plotter.render()  # without it the screenshot may repeat the previous frame
        self.plotter.screenshot(str(path))

    def close(self) -> None:
        self.plotter.close()


# ---------------------------------------------------------------- video


def write_video(images: list[Path], folder: Path, fps: float) -> Path:
    """animation.mp4 when imageio and imageio-ffmpeg are installed, else animation.gif (pillow, which pyvista
    brings)."""
    if importlib.util.find_spec("imageio") is not None and importlib.util.find_spec("imageio_ffmpeg") is not None:
        import imageio.v2 as imageio

        path = folder / "animation.mp4"
        with imageio.get_writer(path, fps=fps, codec="libx264", quality=8) as writer:
            for image in images:
                writer.append_data(imageio.imread(image))
        return path
    from PIL import Image

    path = folder / "animation.gif"
    first, *rest = [Image.open(image).convert("RGB") for image in images]
    first.save(path, save_all=True, append_images=rest, duration=round(1000 / fps), loop=0)
    return path


def _frame_rate(times: np.ndarray) -> float:
    return float(1 / np.median(np.diff(times))) if len(times) > 1 else 24.0


# ---------------------------------------------------------------- entry points


def render_run(folder: Path, *, field: str | None = None, frames: str | None = None,
               resolution: tuple[int, int] | None = None, camera: Camera | None = None, out: Path | None = None,
               fps: float | None = None, video: bool = True,
               progress: Callable[[int, int], None] | None = None) -> RenderResult:
    """Render frames of the run in `folder` to PNGs (and a video); arguments left None come from the scene's
    `render` section, then from the defaults. `progress(done, total)` is called before the first frame and after
    each one."""
    source = open_run(folder)
    settings = scene_settings(source)
    field = field or settings.field
    check_field(source, field)
    indices = parse_frames(frames, len(source))
    resolution = resolution or settings.resolution
    lo, hi, highs = _survey(source, indices, field)
    camera = camera or settings.camera or auto_camera(lo, hi, _up(source.scene), resolution[0] / resolution[1])
    out = Path(out) if out else Path(folder) / "frames"
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.glob("frame_*.png"):  # a new render replaces the frames of an earlier one
        stale.unlink()
    color = _color_style(source, field, _color_range(field, highs), _font_size(resolution))
    scene = _Scene(source, resolution, camera, color, lo, hi)
    images, start = [], time.perf_counter()
    progress = progress or (lambda done, total: None)
    try:
        progress(0, len(indices))
        for done, i in enumerate(indices, 1):
            frame = source.read(i)
            images.append(out / f"frame_{i:05d}.png")
            scene.draw(frame, field_values(source, field, frame), images[-1])
            progress(done, len(indices))
    finally:
        scene.close()
    per_frame = (time.perf_counter() - start) / len(indices)
    movie = write_video(images, Path(folder), fps or _frame_rate(source.times)) if video else None
    return RenderResult(images, movie, per_frame)


def contact_sheet(images: list[Path], labels: list[str], out: Path, columns: int = 3) -> Path:
    """Tile PNGs in a grid, each captioned, into one PNG (a figure comparing runs)."""
    from PIL import Image, ImageDraw, ImageFont

    if len(images) != len(labels) or not images:
        raise ValueError(f"need one label per image and at least one image ({len(images)} images, "
                         f"{len(labels)} labels)")
    tiles = [Image.open(p).convert("RGB") for p in images]
    width, height = max(t.width for t in tiles), max(t.height for t in tiles)
    caption = max(24, height // 12)
    font = ImageFont.load_default(size=int(caption * 0.6))
    columns = min(columns, len(tiles))
    rows = -(-len(tiles) // columns)
    sheet = Image.new("RGB", (columns * width, rows * (height + caption)), "white")
    draw = ImageDraw.Draw(sheet)
    for k, (tile, label) in enumerate(zip(tiles, labels)):
        x, y = (k % columns) * width, (k // columns) * (height + caption)
        sheet.paste(tile, (x + (width - tile.width) // 2, y))
        draw.text((x + width / 2, y + height + caption / 2), label, fill="black", font=font, anchor="mm")
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    sheet.save(out)
    return Path(out)
