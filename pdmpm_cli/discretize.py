"""Scene -> material points and bonds: sampling each body in its geometry mode (cloud, shell, Voronoi), families,
pins, initial velocity, and the meshes that ride along with the points (shell surfaces, Voronoi cells)."""

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from numba import njit
from pydantic import BaseModel
from scipy.spatial import cKDTree

from pdmpm_cli.engine.bonds import build_families, drop_bonds
from pdmpm_cli.errors import InputError, SceneValueError
from pdmpm_cli.geometry import bunny, bvh, embed, primitive_surfaces, sampling, shapes, shell, voronoi
from pdmpm_cli.geometry import mesh as meshes
from pdmpm_cli.geometry.sdf import distance_samples
from pdmpm_cli.scene.schema import Scene


@dataclass
class Region:
    """A closed shape as an inside test plus its axis-aligned bounds [m]."""

    inside: Callable[[np.ndarray], np.ndarray]
    lo: np.ndarray
    hi: np.ndarray
    repairs: list[str] = field(default_factory=list)  # what loading changed in a mesh file
    volume: float = 0.0  # enclosed volume of a mesh [m^3] (0: not computed)


#: a mesh body whose particles fill less than 1 - this of its volume is reported (features thinner than h are lost)
FILL_DEFICIT = 0.05


@functools.lru_cache(maxsize=8)
def _load_mesh(path: Path, stamp: tuple, shape, allow_open: bool) -> meshes.SurfaceMesh:
    """One load per file, placement and version (`stamp`: mtime and size): the size check before sampling and the
    sampler read the same mesh."""
    fit = None if shape.fit is None else (shape.fit.size, shape.fit.axis, shape.fit.center)
    return meshes.load_surface_mesh(path, scale=shape.scale, translate=shape.translate,
                                    R=shapes.rotation_matrix(shape.rotation), units=shape.units, fit=fit,
                                    allow_open=allow_open)


def load_mesh_shape(shape, base_dir: Path, allow_open: bool = False) -> meshes.SurfaceMesh:
    """A scene's `type: mesh` shape, its path relative to the scene file, placed. A problem with the file is a
    SceneValueError about the shape's `path` key."""
    path = Path(shape.path).expanduser()
    path = (path if path.is_absolute() else base_dir / path).resolve()
    try:
        st = path.stat()
        stamp = (st.st_mtime_ns, st.st_size)
    except OSError:
        stamp = None
    try:
        return _load_mesh(path, stamp, shape, allow_open)
    except SceneValueError:
        raise
    except InputError as e:
        raise SceneValueError(str(e), subject=shape, field="path") from None


def shape_region(shape, base_dir: Path) -> Region:
    """Inside test and bounds of a scene shape (primitive, bunny or closed mesh)."""
    if shape.type == "mesh":
        mesh = load_mesh_shape(shape, base_dir)
        lo, hi = meshes.mesh_bounds(mesh)
        return Region(lambda p: bvh.inside_mesh(mesh, p), lo, hi, list(mesh.repairs), meshes.mesh_volume(mesh))
    if shape.type == "sheet":
        raise InputError("a sheet has no inside: use it as the surface of a `mode: shell` body")
    c = np.asarray(shape.center, dtype=np.float64)
    if shape.type == "bunny":
        R = shapes.rotation_matrix(shape.rotation)
        return Region(lambda p: bunny.bunny_inside(p, c, shape.height, R), *bunny.bunny_bounds(c, shape.height, R))
    if shape.type == "sphere":
        return Region(lambda p: shapes.sphere_inside(p, c, shape.radius), *shapes.sphere_bounds(c, shape.radius))
    R = shapes.rotation_matrix(shape.rotation)
    if shape.type == "box":
        size = np.asarray(shape.size)
        return Region(lambda p: shapes.box_inside(p, c, size, R), *shapes.box_bounds(c, size, R))
    if shape.type == "cylinder":
        return Region(lambda p: shapes.cylinder_inside(p, c, shape.radius, shape.height, R),
                      *shapes.cylinder_bounds(c, shape.radius, shape.height, R))
    return Region(lambda p: shapes.capsule_inside(p, c, shape.radius, shape.length, R),
                  *shapes.capsule_bounds(c, shape.radius, shape.length, R))


@dataclass
class EmbeddedMesh:
    """A triangle mesh carried by the material points: vertex v sits at sum_i w_vi (x_i + F_i (X_v - X_i)) over
    its particles i (exact for any affine motion of them); F_i is the particle's local deformation."""

    name: str
    body: int
    kind: str  # "surface" (shell mode) or "cells" (Voronoi polyhedra)
    vertices: np.ndarray  # (nv, 3) rest positions X_v [m]
    triangles: np.ndarray  # (nt, 3) int64, outward
    particles: np.ndarray  # (nv, k) int64 global particle indices
    weights: np.ndarray  # (nv, k) float64, rows sum to 1
    triangle_cell: np.ndarray  # (nt,) int64 global particle index of the Voronoi cell, or (0,)


@dataclass
class Discretization:
    """Material points of every body, sorted by body, with their CSR families."""

    rest_x: np.ndarray  # (n, 3) reference positions X_p [m]
    velocity: np.ndarray  # (n, 3) initial velocity [m/s]
    velocity_gradient: np.ndarray  # (n, 3, 3) initial APIC matrix: the gradient of the initial velocity [1/s]
    volume: np.ndarray  # (n,) V_p [m^3]
    mass: np.ndarray  # (n,) m_p = rho V_p [kg]
    body: np.ndarray  # (n,) int32 body index
    body_ranges: list[tuple[int, int]]
    body_spacing: np.ndarray  # (n_bodies,) h [m]
    body_horizon: np.ndarray  # (n_bodies,) delta [m]
    bond_start: np.ndarray  # (n + 1,) int64
    bond_nbr: np.ndarray  # (n_bonds,) int32
    pin_mask: np.ndarray  # (n,) bool, or (0,) when the scene has no pins
    pin_velocity: np.ndarray  # (n, 3), or (0, 3) [m/s]
    pin_stop: np.ndarray  # (n,) time each pin stops [s] (inf: never), or (0,)
    meshes: list[EmbeddedMesh]  # shell surfaces and Voronoi cells, in body order
    notes: list[str]  # repairs made to input meshes, reported as warnings
    collider_samples: dict = field(default_factory=dict)  # scene collider index -> DistanceSamples of a mesh collider
    collider_meshes: dict = field(default_factory=dict)  # scene collider index -> its SurfaceMesh, placed, at t = 0
    emitter_layer: np.ndarray | None = None  # (N, 3) one layer of the last body's emitter: its lattice in the nozzle
    cut: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))  # (n, 4) sum of X_q - X_p over the bonds a
    # cutout removed [m], pointing from each particle into the notch, and their count (crack fields, engine.crack);
    # (0, 4): no cutouts

    @property
    def n_particles(self) -> int:
        return len(self.rest_x)

    @property
    def n_bonds(self) -> int:
        return len(self.bond_nbr)


@dataclass
class BodySample:
    """One body's material points before they are merged: positions, volumes, spacing, horizon."""

    x: np.ndarray
    volume: np.ndarray
    h: float
    delta: float
    pairs: np.ndarray | None = None  # explicit bonds (Voronoi: cells sharing a face), local indices
    mesh: EmbeddedMesh | None = None  # particle indices local to the body until merged
    repairs: list[str] = field(default_factory=list)  # what loading changed in an input mesh


def primitive_kwargs(shape) -> dict:
    """Size parameters of a primitive shape, as primitive_surfaces.primitive_surface takes them."""
    names = {"box": ("size",), "sheet": ("size",), "sphere": ("radius",), "cylinder": ("radius", "height"),
             "capsule": ("radius", "length")}[shape.type]
    return {k: getattr(shape, k) for k in names}


def sample_cloud(body, base_dir: Path, dx: float, rng) -> BodySample:
    """Cloud mode: fill the shape minus the cutouts with a relaxed, jittered or regular lattice (the relaxed points
    settle against the cutouts' faces as against the shape's)."""
    geo = body.geometry
    h = geo.spacing or 0.5 * dx
    region = shape_region(geo.shape, base_dir)
    cuts = [shape_region(cut, base_dir) for cut in geo.cutouts]

    def inside(p):
        keep = np.asarray(region.inside(p), dtype=bool)
        for cut in cuts:
            keep &= ~np.asarray(cut.inside(p), dtype=bool)
        return keep

    try:
        x = sampling.fill_shape(inside, region.lo, region.hi, h, sampling=geo.sampling, rng=rng,
                                what=f"body '{body.name}'")
    except InputError:
        if not cuts:
            raise
        raise InputError(f"body '{body.name}': no particles: its shape is empty after the cutouts, or smaller "
                         f"than the spacing {h:.4g} m; enlarge the shape or lower geometry.spacing")
    repairs = region.repairs + [r for cut in cuts for r in cut.repairs]
    if region.volume and not cuts and len(x) * h**3 < (1.0 - FILL_DEFICIT) * region.volume:
        repairs.append(f"its {len(x)} particles fill only {100 * len(x) * h**3 / region.volume:.0f} % of the mesh's "
                       f"volume: parts thinner than the spacing h = {h:.3g} m got no particles. Use a smaller "
                       f"geometry.spacing to keep them")
    return BodySample(x, np.full(len(x), h**3), h, geo.horizon * h, repairs=repairs)


def body_surface(shape, base_dir: Path, edge: float, allow_open: bool) -> meshes.SurfaceMesh:
    """The triangle surface of a shape: a mesh file as it is, a primitive or the bunny triangulated."""
    if shape.type == "mesh":
        return load_mesh_shape(shape, base_dir, allow_open=allow_open)
    c = np.asarray(shape.center, dtype=np.float64)
    R = shapes.rotation_matrix(getattr(shape, "rotation", (0.0, 0.0, 0.0)))
    if shape.type == "bunny":
        return bunny.bunny_surface(c, shape.height, R, edge)
    return primitive_surfaces.primitive_surface(shape.type, center=c, R=R, edge=edge, **primitive_kwargs(shape))


def shown_surface(surface, shape, edge: float) -> tuple[np.ndarray, np.ndarray]:
    """The triangles that ride along with a shell: a mesh file's refined to `edge` (a coarse file's flat triangles
    could not bend with the particles under them), a built-in shape's as triangulated at that edge already."""
    if shape.type != "mesh":
        return surface.vertices, surface.triangles
    try:
        return embed.refine_surface(surface.vertices, surface.triangles, edge)
    except ValueError as e:
        raise SceneValueError(f"{e}; set a larger geometry.edge", subject=shape) from None


def sample_shell(body, base_dir: Path, dx: float, rng) -> BodySample:
    """Shell mode: points on the surface and in layers under it; the surface's vertices ride along."""
    geo = body.geometry
    h = geo.spacing or 0.5 * dx
    surface = body_surface(geo.surface, base_dir, geo.edge or h, allow_open=True)
    sample = shell.shell_particles(surface, h, geo.layers, rng, what=f"body '{body.name}'",
                                   first_depth=0.5 if geo.layers > 1 else 0.0)
    sample = shell.thin_crowded(sample, h)
    V, T = shown_surface(surface, geo.surface, geo.edge or h)
    idx, w = embed.embed_points(V, sample.points)
    mesh = EmbeddedMesh(body.name, -1, "surface", V, T, idx, w, np.zeros(0, np.int64))
    repairs = list(surface.repairs) + sample.notes
    if not surface.closed and geo.layers > 1:
        repairs.append(f"the surface is open (it has holes or edges), so its {geo.layers} layers go against its "
                       f"normals; if it should be closed, fill its holes (Blender: Select > All by Trait > Non "
                       f"Manifold, then Face > Fill)")
    return BodySample(sample.points, sample.volumes, h, geo.horizon * h, mesh=mesh, repairs=repairs)


def convex_planes(shape, base_dir: Path, resolution: int, name: str) -> np.ndarray:
    """The half-spaces of a convex shape; curved primitives become inscribed polytopes."""
    if shape.type == "box":
        return voronoi.box_planes(shape.center, shape.size, shapes.rotation_matrix(shape.rotation))
    if shape.type == "bunny":
        raise InputError(f"body '{name}': Voronoi mode needs a convex shape and the bunny is not convex; use "
                         f"mode: cloud or mode: shell for it")
    if shape.type == "mesh":
        surface = load_mesh_shape(shape, base_dir)
        planes = voronoi.polytope_from_points(surface.vertices)
        hull, vol = voronoi.polytope_volume(planes), meshes.mesh_volume(surface)
        if hull > vol * (1.0 + 1e-3):
            raise InputError(f"body '{name}': Voronoi mode needs a convex shape, and {shape.path} is not convex (its "
                             f"convex hull is {100 * (hull / vol - 1):.2g} % larger than it); use mode: cloud, or "
                             f"split the mesh into convex parts as separate bodies")
        return planes
    surface = body_surface(shape, base_dir, 2.0 * np.pi * shape.radius / resolution, allow_open=False)
    return voronoi.polytope_from_points(surface.vertices)


def sample_voronoi(body, base_dir: Path, dx: float, rng) -> BodySample:
    """Voronoi mode: clipped cells; their centroids are the points, bonds join cells that share a face.

    The influence w = 1 - |xi| / delta needs delta beyond the longest bond: delta = max(2 h, 1.05 max |xi|)."""
    geo = body.geometry
    spacing = geo.spacing or (None if geo.count else 0.5 * dx)
    planes = convex_planes(geo.shape, base_dir, geo.resolution, body.name)
    cells = voronoi.voronoi_cells(planes, spacing, geo.count, rng, what=f"body '{body.name}'")
    x = cells.centroids
    h = spacing or float(np.mean(cells.volumes) ** (1.0 / 3.0))
    longest = float(np.linalg.norm(x[cells.pairs[:, 1]] - x[cells.pairs[:, 0]], axis=1).max()) if len(cells.pairs) else h
    mesh = EmbeddedMesh(body.name, -1, "cells", cells.poly_vertices, cells.poly_triangles,
                        cells.vertex_cell.reshape(-1, 1).astype(np.int64), np.ones((len(cells.vertex_cell), 1)),
                        cells.poly_cell.astype(np.int64))
    return BodySample(x, cells.volumes, h, max(2.0 * h, 1.05 * longest), pairs=cells.pairs, mesh=mesh)


SAMPLERS = {"cloud": sample_cloud, "shell": sample_shell, "voronoi": sample_voronoi}


def pin_particles(pin, body, sample: BodySample, base_dir: Path) -> np.ndarray:
    """Mask of the body's particles a pin holds: inside its region, or within one spacing of its vertices."""
    if pin.region is not None:
        return shape_region(pin.region, base_dir).inside(sample.x)
    verts = sample.mesh.vertices
    bad = [v for v in pin.vertices if not 0 <= v < len(verts)]
    if bad:
        raise InputError(f"body '{body.name}': pin vertices {bad[:5]} do not exist; the surface mesh has "
                         f"{len(verts)} vertices (indices 0 to {len(verts) - 1})")
    tree = cKDTree(sample.x)
    near = tree.query_ball_point(verts[pin.vertices], sample.h)
    nearest = tree.query(verts[pin.vertices])[1]  # a vertex farther than h from every point holds its nearest
    mask = np.zeros(len(sample.x), dtype=bool)
    for found, first in zip(near, nearest):
        mask[found or [first]] = True
    return mask


def emitter_layer(scene: Scene, base_dir: Path, disc: Discretization) -> np.ndarray | None:
    """One layer of the last body's emitter (engine.emitter): the lattice points of the body's spacing inside the
    nozzle shape, or None without an emitter."""
    i = len(scene.bodies) - 1
    em = scene.bodies[i].emitter
    if em is None:
        return None
    region, key = shape_region(em.shape, base_dir), ("bodies", i, "emitter", "shape")
    try:
        layer = sampling.fill_shape(region.inside, region.lo, region.hi, float(disc.body_spacing[i]),
                                    sampling="lattice", rng=None, what=f"body '{scene.bodies[i].name}' emitter")
    except InputError as e:
        raise SceneValueError(str(e), key) from None
    dx = scene.grid.cell_size  # the particles' valid region, 3.5 cells inside the walls (check_sizes)
    lo, hi = np.asarray(scene.grid.domain.min) + 3.5 * dx, np.asarray(scene.grid.domain.max) - 3.5 * dx
    if np.any(layer < lo) or np.any(layer > hi):
        raise SceneValueError(f"the nozzle's particles span {np.round(layer.min(axis=0), 4).tolist()} to "
                              f"{np.round(layer.max(axis=0), 4).tolist()} m, but they must keep 3.5 cells from the "
                              f"domain's walls ({lo.tolist()} to {hi.tolist()} m); move the nozzle inside", key)
    return layer


def discretize(scene: Scene, base_dir: Path) -> Discretization:
    """Sample every body (its size already checked by `check_sizes`), build its bonds, sample the mesh colliders'
    distances, and note where the particles will not behave as the body was drawn. A problem with a shape is a
    SceneValueError naming its scene key."""
    try:
        surfaces = {i: load_mesh_shape(c, base_dir) for i, c in enumerate(scene.colliders) if c.type == "mesh"}
        samples = {i: distance_samples(m, 0.5 * scene.grid.cell_size) for i, m in surfaces.items()}
        disc = sample_bodies(scene, base_dir)
        disc.collider_samples, disc.collider_meshes = samples, surfaces
        disc.emitter_layer = emitter_layer(scene, base_dir, disc)
    except SceneValueError as e:
        raise keyed(e, scene) from None
    disc.notes += family_notes(scene, disc)
    return disc


def keyed(error: SceneValueError, scene: Scene) -> SceneValueError:
    """The error with its scene key: the path to the object it is about (found by identity) and its field."""
    if error.key or error.subject is None:
        return error
    path = _path_to(scene, error.subject)
    if path is None:
        return error
    return SceneValueError(error.message, key=path + ((error.field,) if error.field else ()))


def _path_to(node, target, path=()):
    if node is target:
        return path
    if isinstance(node, BaseModel):
        items = ((name, getattr(node, name)) for name in type(node).model_fields)
    elif isinstance(node, (list, tuple)):
        items = enumerate(node)
    else:
        return None
    for key, child in items:
        if (found := _path_to(child, target, path + (key,))) is not None:
            return found
    return None


_EXTENT_WORDS = ("wide (along x)", "tall (along y)", "deep (along z)")


def shape_bounds(shape, base_dir: Path, allow_open: bool) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds [m] of a body's shape or surface, without sampling it (a mesh file is loaded)."""
    if shape.type == "sheet":
        R = shapes.rotation_matrix(shape.rotation)
        corners = np.array([[sx * shape.size[0], sy * shape.size[1], 0.0] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5)])
        x = np.asarray(shape.center) + corners @ R.T
        return x.min(axis=0), x.max(axis=0)
    if shape.type == "mesh":
        return meshes.mesh_bounds(load_mesh_shape(shape, base_dir, allow_open=allow_open))
    region = shape_region(shape, base_dir)
    return region.lo, region.hi


def check_sizes(scene: Scene, base_dir: Path) -> None:
    """Refuse a body wider than the domain's usable part (3.5 cells inside the walls) or wholly outside the domain,
    from its bounding box, before any sampling: a mesh in millimetres read as metres would otherwise be sampled in
    full (minutes) before the particle check refuses it."""
    dx = scene.grid.cell_size
    dom_lo, dom_hi = np.asarray(scene.grid.domain.min), np.asarray(scene.grid.domain.max)
    room = dom_hi - dom_lo - 7.0 * dx
    for body in scene.bodies:
        geo = body.geometry
        shape = geo.surface if geo.mode == "shell" else geo.shape
        lo, hi = shape_bounds(shape, base_dir, allow_open=geo.mode == "shell")
        ext = hi - lo
        a = int(np.argmax(ext - room))
        size = " x ".join(f"{e:.3g}" for e in ext)
        if ext[a] > room[a] + dx:
            raise SceneValueError(
                f"body '{body.name}' is {ext[a]:.3g} m {_EXTENT_WORDS[a]}, but the domain is "
                f"{dom_hi[a] - dom_lo[a]:.3g} m "
                f"(particles must keep 3.5 cells from its walls: {room[a]:.3g} m usable); the body's bounding box is "
                f"{size} m. Fix: {_size_fix(shape, ext, room)}", subject=shape)
        if np.any(hi < dom_lo) or np.any(lo > dom_hi):
            raise SceneValueError(
                f"body '{body.name}' lies outside the domain: its bounding box spans {np.round(lo, 4).tolist()} to "
                f"{np.round(hi, 4).tolist()} m, the domain {dom_lo.tolist()} to {dom_hi.tolist()} m. Fix: move the "
                f"body into the domain" + (" (translate, or fit.center)" if shape.type == "mesh" else ""),
                subject=shape)


def _size_fix(shape, ext, room) -> str:
    if shape.type != "mesh":
        return "make the shape smaller or grid.domain larger"
    for unit, factor in (("mm", 1e-3), ("cm", 1e-2)):
        if shape.units == "m" and np.all(ext * factor <= room):
            return (f"if the file is in {'millimetres' if unit == 'mm' else 'centimetres'}, set units: {unit}; or fit "
                    f"it to a size (fit: {{size: ..., center: [...]}}), or scale it down")
    return "fit it to a size (fit: {size: ..., center: [...]}) or scale it down, or make grid.domain larger"


#: particles with fewer bonds than this are reported (a particle needs about 4 neighbours not to rotate freely)
MIN_BONDS = 4
#: loose or flat particles are reported when they are more than this fraction of a body (a cloth's corners are not)
REPORT_FRACTION = 0.005
#: a cloud particle whose family's smallest direction moment is below this fraction of its largest sits in a
#: layer about one particle thick
FLAT_FAMILY = 0.1


def family_notes(scene: Scene, disc) -> list[str]:
    """Warnings where the particles will not behave as the drawn body: particles with fewer than MIN_BONDS bonds
    (loose, or barely held), and cloud particles whose bonds lie in one plane or along one line: features thinner
    than the spacing, one particle thick, which bend and stretch far more easily than the material would."""
    notes = []
    count = np.diff(disc.bond_start)
    for body, (start, end), h in zip(scene.bodies, disc.body_ranges, disc.body_spacing):
        if body.geometry.mode == "voronoi" or end == start:
            continue
        n = count[start:end]
        few = int((n < MIN_BONDS).sum())
        if (n == 0).any() or few > REPORT_FRACTION * (end - start):
            none = int((n == 0).sum())
            at = disc.rest_x[start + int(np.argmin(n))]
            notes.append(f"body '{body.name}': {few} of {end - start} particles have fewer than {MIN_BONDS} bonds "
                         f"({none} have none), e.g. at {_fmt(at)}: they sit in features thinner than the spacing "
                         f"h = {h:.3g} m and will move loosely. Use a smaller geometry.spacing or thicken those parts")
        if body.geometry.mode != "cloud":
            continue
        flat = flat_families(disc.rest_x, disc.bond_start, disc.bond_nbr, start, end) & (n >= MIN_BONDS)
        if flat.sum() > REPORT_FRACTION * (end - start):
            at = disc.rest_x[start + int(np.flatnonzero(flat)[0])]
            notes.append(f"body '{body.name}': {int(flat.sum())} of {end - start} particles lie in features about "
                         f"one particle thick (thinner than about 2 h = {2 * h:.3g} m), e.g. at {_fmt(at)}: those "
                         f"parts will bend and stretch much more easily than the material. Use a smaller "
                         f"geometry.spacing to resolve them")
    return notes


def flat_families(x, bond_start, bond_nbr, start, end) -> np.ndarray:
    """Bool per particle of start..end: its bond directions span fewer than three dimensions (smallest eigenvalue
    of sum xi xi^T / |xi|^2 below FLAT_FAMILY times the largest)."""
    lam = np.linalg.eigvalsh(direction_moments(x, bond_start, bond_nbr, start, end))
    return lam[:, 0] < FLAT_FAMILY * np.maximum(lam[:, 2], 1e-300)


@njit(cache=True)
def direction_moments(x, bond_start, bond_nbr, start, end):
    """sum over the bonds of particle p of xi xi^T / |xi|^2, for p in start..end: one pass over the bonds, where
    the same sums in numpy build a 9-column array per bond (seconds and gigabytes at a million particles)."""
    K = np.zeros((end - start, 3, 3))
    for p in range(start, end):
        for b in range(bond_start[p], bond_start[p + 1]):
            q = bond_nbr[b]
            d0, d1, d2 = x[q, 0] - x[p, 0], x[q, 1] - x[p, 1], x[q, 2] - x[p, 2]
            r2 = d0 * d0 + d1 * d1 + d2 * d2
            if r2 > 0.0:
                d = (d0, d1, d2)
                for a in range(3):
                    for c in range(3):
                        K[p - start, a, c] += d[a] * d[c] / r2
    return K


def _fmt(x) -> str:
    return "(" + ", ".join(f"{v:.4g}" for v in x) + ")"


def sample_bodies(scene: Scene, base_dir: Path) -> Discretization:
    """Sample every body, check its particles keep clear of the walls, and build its bonds."""
    rng = np.random.default_rng(scene.simulation.seed)
    dx = scene.grid.cell_size
    inner_lo = np.asarray(scene.grid.domain.min) + 3.5 * dx
    inner_hi = np.asarray(scene.grid.domain.max) - 3.5 * dx
    xs, vs, grads, masses, vols, ranges, spacing, horizon, pairs, embedded = [], [], [], [], [], [], [], [], [], []
    pinned, pin_v, pin_t, notes = [], [], [], []
    start = 0
    for b, body in enumerate(scene.bodies):
        sample = SAMPLERS[body.geometry.mode](body, base_dir, dx, rng)
        notes += [f"body '{body.name}': {r}" for r in sample.repairs]
        x = sample.x
        bad = np.any((x < inner_lo) | (x > inner_hi), axis=1)
        if bad.any():
            raise InputError(
                f"body '{body.name}': {int(bad.sum())} of {len(x)} particles lie within 3.5 cells of the domain "
                f"boundary or outside it (e.g. at {np.round(x[bad][0], 4).tolist()}); enlarge grid.domain "
                f"(particles must stay inside [{inner_lo.round(4).tolist()}, {inner_hi.round(4).tolist()}])"
            )
        n = len(x)
        com = x.mean(axis=0)
        w = np.asarray(body.angular_velocity, dtype=np.float64)
        v = np.asarray(body.velocity) + np.cross(w, x - com)
        spin = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])  # v = spin @ (x - com)
        grad = np.broadcast_to(spin, (n, 3, 3)).copy()
        mask = np.zeros(n, dtype=bool)
        pv = np.zeros((n, 3))
        pt = np.full(n, np.inf)
        for pin in body.pins:
            inside = pin_particles(pin, body, sample, base_dir) & ~mask
            mask |= inside
            pv[inside] = pin.velocity
            pt[inside] = np.inf if pin.stop is None else pin.stop
            v[inside] = pin.velocity
            grad[inside] = 0.0
        if sample.mesh is not None:
            m = sample.mesh
            m.body = b
            m.particles = m.particles + start
            if len(m.triangle_cell):
                m.triangle_cell = m.triangle_cell + start
            embedded.append(m)
        xs.append(x)
        vs.append(v)
        grads.append(grad)
        vols.append(sample.volume)
        masses.append(body.material.density * sample.volume)
        pinned.append(mask)
        pin_v.append(pv)
        pin_t.append(pt)
        ranges.append((start, start + n))
        spacing.append(sample.h)
        horizon.append(sample.delta)
        pairs.append(sample.pairs)
        start += n
    rest_x = np.concatenate(xs)
    body_ids = np.concatenate([np.full(e - s, i, dtype=np.int32) for i, (s, e) in enumerate(ranges)])
    bond_start, bond_nbr = build_families(rest_x, ranges, horizon, pairs)
    bond_start, bond_nbr, cut = cut_bonds_through(scene, base_dir, rest_x, ranges, spacing, horizon, bond_start,
                                                  bond_nbr)
    has_pins = any(m.any() for m in pinned)
    return Discretization(
        rest_x=rest_x,
        velocity=np.concatenate(vs),
        velocity_gradient=np.concatenate(grads),
        volume=np.concatenate(vols),
        mass=np.concatenate(masses),
        body=body_ids,
        body_ranges=ranges,
        body_spacing=np.asarray(spacing),
        body_horizon=np.asarray(horizon),
        bond_start=bond_start,
        bond_nbr=bond_nbr,
        pin_mask=np.concatenate(pinned) if has_pins else np.zeros(0, dtype=bool),
        pin_velocity=np.concatenate(pin_v) if has_pins else np.zeros((0, 3)),
        pin_stop=np.concatenate(pin_t) if has_pins else np.zeros(0),
        meshes=embedded,
        notes=notes,
        cut=cut,
    )


def cut_bonds_through(scene: Scene, base_dir: Path, rest_x, ranges, spacing, horizon, bond_start, bond_nbr):
    """Remove bonds whose segment passes through a cutout (tested at 1/4, 1/2 and 3/4 of its length), so a
    notch narrower than the horizon is still a real notch. Also returns, per particle, the sum of X_q - X_p over the
    bonds the cutout took from it, the removed ones and those to the material it removed (`removed_material`), and
    their count, or (0, 4) when it took none: they point into the notch, for crack fields."""
    keep = np.ones(len(bond_nbr), dtype=bool)
    cut = np.zeros((len(rest_x), 4))
    for body, (start, end), h, delta in zip(scene.bodies, ranges, spacing, horizon):
        cuts = [shape_region(c, base_dir) for c in getattr(body.geometry, "cutouts", [])]
        if not cuts:
            continue
        b0, b1 = bond_start[start], bond_start[end]
        p = np.repeat(np.arange(start, end), np.diff(bond_start[start:end + 1]))
        q = bond_nbr[b0:b1]
        for t in (0.25, 0.5, 0.75):
            mid = rest_x[p] + t * (rest_x[q] - rest_x[p])
            for c in cuts:
                keep[b0:b1] &= ~c.inside(mid)
        removed_material(shape_region(body.geometry.shape, base_dir), cuts, rest_x, start, end, h, delta, cut)
    if keep.all() and not cut.any():
        return bond_start, bond_nbr, np.zeros((0, 4))
    p = np.repeat(np.arange(len(rest_x)), np.diff(bond_start))[~keep]
    np.add.at(cut, p, np.hstack([rest_x[bond_nbr[~keep]] - rest_x[p], np.ones((len(p), 1))]))
    return *drop_bonds(bond_start, bond_nbr, keep), cut


def removed_material(region: Region, cuts: list, rest_x, start: int, end: int, h: float, delta: float, cut):
    """Add to cut[p] (sum of X_q - X_p, count) the bonds p would have had to the body's material inside its cutouts:
    points h / 2 apart fill shape and cutouts, each an eighth of a bond. A cloud's particles settle up to a spacing
    off a cutout's faces, so a notch half a cell wide took bonds from only a quarter of its faces' particles at
    0.02 m cells: the others split no grid node, and the grid pulled the faces across the notch."""
    step = 0.5 * h
    for c in cuts:
        lo, hi = np.maximum(c.lo, region.lo), np.minimum(c.hi, region.hi)
        if np.any(hi <= lo):
            continue
        axes = [np.arange(a + 0.5 * step, b, step) for a, b in zip(lo, hi)]
        y = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        y = y[c.inside(y) & region.inside(y)]
        if not len(y):
            continue
        near = cKDTree(y).query_ball_point(rest_x[start:end], r=delta)
        count = np.fromiter((len(n) for n in near), dtype=np.int64, count=end - start)
        if not count.any():
            continue
        own = np.repeat(np.arange(start, end), count)
        np.add.at(cut, own, 0.125 * np.hstack([y[np.concatenate(near).astype(np.int64)] - rest_x[own],
                                               np.ones((len(own), 1))]))
