"""The pyvista scene: one layer per body (spheres, shell surface, Voronoi cells, fluid surface), the floor and
colliders, the camera and the colour bar, updated frame by frame offscreen."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import TypeAdapter, ValidationError

from pdmpm_cli.io.surface import fluid_surface
from pdmpm_cli.render.fields import FIELDS
from pdmpm_cli.render.source import Frame, MeshPart, RunSource, nearest
from pdmpm_cli.scene.schema import Camera, Collider

os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")  # headless: no X server needed
import pyvista as pv  # noqa: E402  (needs the window class chosen above)

pv.OFF_SCREEN = True

BODY_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
               "#17becf")  # matplotlib's tab10, in order: body 0 blue, body 1 orange, ...


def up_direction(scene: dict) -> np.ndarray:
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
    """A box, sphere or cylinder collider at time 0 (a mesh collider's surface is a file of the run)."""
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


def _floor(scene: dict, focus: np.ndarray, size: float, cells: int | None) -> pv.PolyData | None:
    """The domain wall that gravity pushes towards, `cells` cells inside the domain where material rests on it, for
    scenes without a ground plane collider."""
    grid = scene.get("grid") or {}
    g = np.asarray(scene.get("gravity", (0.0, -9.81, 0.0)), dtype=float)
    if not grid.get("domain") or not g.any() or cells is None:
        return None
    axis = int(np.argmax(np.abs(g)))
    inset = cells * float(grid["cell_size"])
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


def present(idx: np.ndarray, frame: Frame) -> np.ndarray:
    """The body's particles this frame holds: with an emitter, a frame has the first of the run's particles."""
    return idx[:np.searchsorted(idx, len(frame.x))]


def _spheres(idx: np.ndarray, radius: float) -> _Layer:
    def build(frame: Frame, values: np.ndarray) -> pv.PolyData:
        idx_now = present(idx, frame)
        cloud = pv.PolyData(frame.x[idx_now])
        cloud.point_data["value"] = values[idx_now]
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
        idx_now = present(idx, frame)
        x = frame.x[idx_now]
        surface = fluid_surface(x, volume[:len(idx_now)], spacing)
        if surface.n_points:  # the mean of a few neighbours: single particles' values would look blotchy
            near = nearest(x, surface.points, k=8).reshape(surface.n_points, -1)
            surface.point_data["value"] = values[idx_now][near].mean(axis=1)
        return surface

    return _Layer(build, dict(interpolation="phong", specular=0.4))


def body_layers(source: RunSource) -> list[_Layer]:
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


def font_size(resolution: tuple[int, int]) -> int:
    """Text in proportion to the image, readable in a small contact-sheet tile."""
    return max(10, round(resolution[1] / 45))


def color_style(source: RunSource, name: str, clim: tuple[float, float], font: int) -> dict:
    """Colour mapping shared by every body, with one scalar bar at the right edge (clear of centred bodies)."""
    bar = dict(title=FIELDS[name][1], vertical=True, position_x=0.86, position_y=0.15, width=0.05, height=0.7,
               title_font_size=font, label_font_size=font, unconstrained_font_size=True)
    if name != "body":
        return dict(scalars="value", cmap="viridis", clim=clim, scalar_bar_args=bar)
    n = len(source.bodies)
    return dict(scalars="value", cmap=[BODY_COLORS[b % len(BODY_COLORS)] for b in range(n)], clim=(-0.5, n - 0.5),
                annotations={i: b.name for i, b in enumerate(source.bodies)}, scalar_bar_args=bar | {"n_labels": 0})


class RenderScene:
    """The plotter with its static props (floor, colliders) and the bodies, updated frame by frame."""

    def __init__(self, source: RunSource, resolution: tuple[int, int], camera: Camera, color: dict,
                 lo: np.ndarray, hi: np.ndarray):
        self.source, self.color, self.font = source, color, font_size(resolution)
        self.layers = body_layers(source)
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
        for i, c in enumerate(colliders):
            if c.type == "plane":
                actor = self.plotter.add_mesh(_ground(_plane_center(c, focus), c.normal, size), texture=_checker())
            elif c.type == "mesh":
                surface = self.source.folder / "colliders" / f"collider_{i}.ply"
                if not surface.is_file():  # a run folder copied without it: the collider is not drawn
                    continue
                actor = self.plotter.add_mesh(pv.read(surface), color="#8c8c8c", opacity=0.15 if c.inside_out else
                                              0.35)
            else:
                actor = self.plotter.add_mesh(_collider_mesh(c), color="#8c8c8c", smooth_shading=True,
                                              opacity=0.15 if c.inside_out else 0.35)
            if any(c.velocity):
                moving.append((actor, np.asarray(c.velocity)))
        plane = any(c.type == "plane" for c in colliders)
        floor = None if plane else _floor(scene, focus, size, self.source.floor_cells)
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
