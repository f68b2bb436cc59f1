"""What a scene will cost, known before it is sampled: particles, bonds, memory and output bytes.

Counts come from the shapes alone: a cloud body has about volume / h^3 particles, a shell body area / h^2 per
layer, a Voronoi body `count` or volume / spacing^3 cells; a particle has about the lattice points within its
horizon as bonds. The memory model adds the largest of the three peaks a run passes through (sampling, building
the families, stepping) to the grid. `check_memory` refuses a scene that cannot fit in the memory this machine has
free, before any array is allocated; `check_output` refuses a run whose frames cannot fit on the output disk.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pdmpm_cli.errors import InputError

# Bytes per particle and per bond, read off the arrays each phase holds (and checked against peak RSS of
# `pdmpm run`, see docs/results.md): relaxed sampling keeps 32 samples of 3 float64 per point with their cells
# and random draws; families hold pairs, both directions, a lexsort order and the CSR (int64 temporaries);
# stepping holds the State and Model arrays (positions, velocities, APIC and shape matrices, Fbar, ...), the
# Discretization they came from and the frames waiting to be written.
SAMPLING_PER_PARTICLE = 2600
VORONOI_PER_CELL = 8000  # clipped cell polyhedra with their vertices and triangles
FAMILIES_PER_BOND = 64
STEP_PER_PARTICLE = 800
STEP_PER_PARTICLE_THREAD = 24  # per-thread force arrays of the elastic pair pass
STEP_PER_BOND = 40
GRID_NODE = 4 * 8  # mass and momentum, float64, once per grid plus once per thread
FLIP_NODE = 7 * 8  # with a FLIP share (simulation.flip > 0): the impulse / the velocity before the update too
VORONOI_BONDS = 16  # face neighbours of a random Voronoi cell (about 15.5)
TINY_BODY = 32  # fewer particles than this: warned
OUTPUT_WARNING = 2 << 30  # planned output above this many bytes: warned


@dataclass(frozen=True)
class BodyCount:
    name: str
    key: str  # dotted key of the body's spacing, for messages
    spacing: float  # h [m]
    particles: float
    bonds: float
    sampling_bytes: float


@dataclass(frozen=True)
class Estimate:
    bodies: tuple[BodyCount, ...]
    grid_nodes: float
    threads: int
    node_bytes: int = GRID_NODE

    @property
    def particles(self) -> float:
        return sum(b.particles for b in self.bodies)

    @property
    def bonds(self) -> float:
        return sum(b.bonds for b in self.bodies)

    @property
    def grid_bytes(self) -> float:
        return self.grid_nodes * self.node_bytes * (1 + self.threads)

    @property
    def memory_bytes(self) -> float:
        """Peak bytes of a run: the grid plus the largest of sampling, family building and stepping."""
        sampling = max((b.sampling_bytes for b in self.bodies), default=0.0)
        families = FAMILIES_PER_BOND * self.bonds + STEP_PER_PARTICLE / 4 * self.particles
        step = ((STEP_PER_PARTICLE + STEP_PER_PARTICLE_THREAD * self.threads) * self.particles
                + STEP_PER_BOND * self.bonds)
        return self.grid_bytes + max(sampling, families, step)


def _volume(shape, base_dir: Path) -> float:
    """Enclosed volume of a scene shape [m^3]."""
    if shape.type == "box":
        return math.prod(shape.size)
    if shape.type == "sphere":
        return 4 / 3 * math.pi * shape.radius**3
    if shape.type == "cylinder":
        return math.pi * shape.radius**2 * shape.height
    if shape.type == "capsule":
        return math.pi * shape.radius**2 * (shape.length + 4 / 3 * shape.radius)
    if shape.type == "bunny":
        from pdmpm_cli.geometry.bunny import bunny_volume

        return bunny_volume(shape.height)
    from pdmpm_cli.discretize import load_mesh_shape
    from pdmpm_cli.geometry.mesh import mesh_volume

    return abs(mesh_volume(load_mesh_shape(shape, base_dir)))


def _area(shape, base_dir: Path) -> float:
    """Surface area of a scene shape [m^2] (a sheet: one side)."""
    if shape.type == "sheet":
        return math.prod(shape.size)
    if shape.type == "box":
        a, b, c = shape.size
        return 2 * (a * b + b * c + c * a)
    if shape.type == "sphere":
        return 4 * math.pi * shape.radius**2
    if shape.type == "cylinder":
        return 2 * math.pi * shape.radius * (shape.radius + shape.height)
    if shape.type == "capsule":
        return 2 * math.pi * shape.radius * (2 * shape.radius + shape.length)
    if shape.type == "bunny":  # the surface of a sphere of its volume, times the bunny's extra from ears and legs
        return 1.5 * (36 * math.pi) ** (1 / 3) * _volume(shape, base_dir) ** (2 / 3)
    import numpy as np

    from pdmpm_cli.discretize import load_mesh_shape

    mesh = load_mesh_shape(shape, base_dir, allow_open=True)
    v = mesh.vertices[mesh.triangles]
    return float(0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum())


def _body(i: int, body, dx: float, base_dir: Path, duration: float = 0.0) -> BodyCount:
    geo = body.geometry
    key = f"bodies.{i}.geometry.spacing"
    if geo.mode == "voronoi":
        h = geo.spacing or (None if geo.count else 0.5 * dx)
        n = float(geo.count) if geo.count else _volume(geo.shape, base_dir) / h**3
        h = h or (_volume(geo.shape, base_dir) / n) ** (1 / 3)
        return BodyCount(body.name, key, h, n, VORONOI_BONDS * n, VORONOI_PER_CELL * n)
    h, ratio = geo.spacing or 0.5 * dx, geo.horizon
    if geo.mode == "cloud":
        n = _volume(geo.shape, base_dir) / h**3
        if body.emitter is not None:  # and what its emitter bears: rate x time / h^3
            stop = min(body.emitter.stop or duration, duration)
            n += max(0.0, stop - body.emitter.start) * body.emitter.rate / h**3
        family = 4 / 3 * math.pi * ratio**3 - 1
    else:  # shell: layers under the surface, bonds to the layers within the horizon
        n = _area(geo.surface, base_dir) / h**2 * geo.layers
        family = math.pi * ratio**2 * min(geo.layers, 2 * ratio + 1) - 1
    return BodyCount(body.name, key, h, n, max(family, 0.0) * n, SAMPLING_PER_PARTICLE * n)


def estimate(scene, base_dir: Path, threads: int | None = None) -> Estimate:
    """Particles, bonds and grid of a validated scene, from its shapes (no sampling)."""
    if threads is None:
        import numba

        threads = numba.get_num_threads() if scene.simulation.backend == "cpu" else 0
    dx = scene.grid.cell_size
    nodes = math.prod(round((b - a) / dx) + 1 for a, b in zip(scene.grid.domain.min, scene.grid.domain.max))
    bodies = tuple(_body(i, b, dx, base_dir, scene.simulation.duration) for i, b in enumerate(scene.bodies))
    return Estimate(bodies, float(nodes), threads, FLIP_NODE if scene.simulation.flip > 0 else GRID_NODE)


def available_memory() -> int | None:
    """Bytes this process can still allocate: the kernel's MemAvailable, lowered by a cgroup (container) limit;
    None where neither can be read."""
    found = []
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    found.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        pass
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            used = int(Path("/sys/fs/cgroup/memory.current").read_text())
            found.append(int(limit) - used)
    except (OSError, ValueError):
        pass
    return min(found) if found else None


def gib(n: float) -> str:
    return f"{n / 2**30:.3g} GiB" if n >= 2**30 else f"{n / 2**20:.3g} MiB"


def check_memory(scene, base_dir: Path, where: str, available: int | None = None) -> Estimate:
    """The estimate; InputError when its peak is above the memory available, saying what to change."""
    est = estimate(scene, base_dir)
    available = available_memory() if available is None else available
    need = est.memory_bytes
    if available is None or need <= available:
        return est
    biggest = max(est.bodies, key=lambda b: b.particles)
    factor = (need / (0.8 * available)) ** (1 / 3)  # memory falls about as 1/h^3
    raise InputError(
        f"{where}: the scene needs about {gib(need)} of memory ({est.particles:.3g} particles, {est.bonds:.3g} bonds, "
        f"grid {gib(est.grid_bytes)}), but this machine has {gib(available)} available; raise the particle "
        f"spacing ({biggest.key} = {biggest.spacing * factor:.3g} m instead of {biggest.spacing:.3g} m, or the same "
        f"factor {factor:.3g} on every body), lower geometry.horizon, or shrink the bodies")


def field_bytes(name: str) -> int:
    """Bytes per particle of an output field: from its declaration (engine.fields, a material's fields), else one
    float64 (particle_speed and the materials' computed outputs are one value per particle)."""
    from pdmpm_cli.engine.materials import declared_fields

    field = declared_fields().get(name)
    return 8 if field is None else int(np.prod(field.tail, dtype=int)) * np.dtype(field.dtype).itemsize


def output_bytes(prep, frames: int | None = None) -> float:
    """Bytes the run writes in `frames` frames (all of the plan's by default), before compression: positions and
    the scene's fields in run.h5, the same with the static fields in each VTU, and the moving meshes in run.h5 and
    as PLY files."""
    scene, plan = prep.scene, prep.plan
    frames = plan.frames + 1 if frames is None else frames
    fields = 24 + sum(field_bytes(f) for f in scene.output.fields)
    vertices = sum(len(m.vertices) for m in prep.disc.meshes)
    h5 = (fields * plan.capacity + 24 * vertices) if scene.output.hdf5 else 0
    vtk = (fields + 44) * plan.capacity if scene.output.vtk else 0  # + body, volume, mass, bonds, X
    ply = 48 * vertices if scene.output.meshes else 0  # float32 vertices and their share of the triangles
    return float(frames * (h5 + vtk + ply))


def warnings(prep) -> list[str]:
    """Tiny bodies (a spacing close to the body's size) and a large planned output."""
    out = []
    for i, (body, planned) in enumerate(zip(prep.scene.bodies, prep.plan.bodies)):
        if body.geometry.mode != "voronoi" and planned.particles < TINY_BODY:
            out.append(f"body '{body.name}' has only {planned.particles} particles (spacing {planned.spacing:.3g} m): "
                       f"too few to bend or vibrate like a solid; lower bodies.{i}.geometry.spacing")
    total = output_bytes(prep)
    if total > OUTPUT_WARNING:
        out.append(f"the run writes {prep.plan.frames + 1} frames of {prep.plan.particles} particles, about "
                   f"{gib(total)} before compression; lower simulation.fps or output.fields, or set output.vtk: false")
    return out


def check_output(prep, out: Path, frames: int | None = None, reclaim: bool = False) -> None:
    """InputError when the frames still to write cannot fit on the disk holding `out` (with `reclaim`, the files
    already in `out` count as free: --overwrite deletes them)."""
    need = output_bytes(prep, frames)
    if reclaim and Path(out).is_dir():
        need -= sum(f.stat().st_size for f in Path(out).rglob("*") if f.is_file())
    folder = Path(out).absolute()
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        stat = os.statvfs(folder)
    except OSError:
        return
    free = stat.f_bavail * stat.f_frsize
    if need > free:
        raise InputError(f"{out}: the run writes about {gib(need)} ({prep.plan.frames} frames of "
                         f"{prep.plan.particles} particles, before compression), but its disk has {gib(free)} free; "
                         f"free some space, choose another --out, or lower simulation.fps or output.fields")
