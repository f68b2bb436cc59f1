"""Scene -> material points and bonds: sampling each body's shape, families, pins, initial velocity."""

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from pdmpm_cli.engine.bonds import build_families, drop_bonds
from pdmpm_cli.errors import InputError
from pdmpm_cli.geometry import mesh as meshes
from pdmpm_cli.geometry import sampling, shapes
from pdmpm_cli.scene.schema import Scene


@dataclass
class Region:
    """A closed shape as an inside test plus its axis-aligned bounds [m]."""

    inside: Callable[[np.ndarray], np.ndarray]
    lo: np.ndarray
    hi: np.ndarray


def shape_region(shape, base_dir: Path) -> Region:
    """Inside test and bounds of a scene shape (primitive or closed mesh)."""
    if shape.type == "mesh":
        path = Path(shape.path)
        path = path if path.is_absolute() else base_dir / path
        mesh = meshes.load_surface_mesh(path, scale=shape.scale, translate=shape.translate,
                                        R=shapes.rotation_matrix(shape.rotation))
        lo, hi = meshes.mesh_bounds(mesh)
        return Region(lambda p: meshes.inside_mesh(mesh, p), lo, hi)
    c = np.asarray(shape.center, dtype=np.float64)
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
    pin_velocity: np.ndarray  # (n, 3), or (0, 3)

    @property
    def n_particles(self) -> int:
        return len(self.rest_x)

    @property
    def n_bonds(self) -> int:
        return len(self.bond_nbr)


def discretize(scene: Scene, base_dir: Path) -> Discretization:
    """Sample every body, check it fits the domain, and build its bonds."""
    rng = np.random.default_rng(scene.simulation.seed)
    dx = scene.grid.cell_size
    inner_lo = np.asarray(scene.grid.domain.min) + 3.5 * dx
    inner_hi = np.asarray(scene.grid.domain.max) - 3.5 * dx
    xs, vs, grads, masses, vols, ranges, spacing, horizon = [], [], [], [], [], [], [], []
    pinned, pin_v = [], []
    start = 0
    for body in scene.bodies:
        geo, mat = body.geometry, body.material
        h = geo.spacing or 0.5 * dx
        region = shape_region(geo.shape, base_dir)
        x = sampling.fill_shape(region.inside, region.lo, region.hi, h, sampling=geo.sampling, rng=rng)
        for cut in geo.cutouts:
            x = x[~shape_region(cut, base_dir).inside(x)]
        if not len(x):
            raise InputError(f"body '{body.name}': no particles: its shape is empty after the cutouts, or smaller "
                             f"than the spacing {h:.4g} m; enlarge the shape or lower geometry.spacing")
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
        for pin in body.pins:
            inside = shape_region(pin.region, base_dir).inside(x) & ~mask
            mask |= inside
            pv[inside] = pin.velocity
            v[inside] = pin.velocity
            grad[inside] = 0.0
        xs.append(x)
        vs.append(v)
        grads.append(grad)
        vols.append(np.full(n, h**3))
        masses.append(np.full(n, mat.density * h**3))
        pinned.append(mask)
        pin_v.append(pv)
        ranges.append((start, start + n))
        spacing.append(h)
        horizon.append(geo.horizon * h)
        start += n
    rest_x = np.concatenate(xs)
    body_ids = np.concatenate([np.full(e - s, i, dtype=np.int32) for i, (s, e) in enumerate(ranges)])
    bond_start, bond_nbr = build_families(rest_x, ranges, horizon)
    bond_start, bond_nbr = cut_bonds_through(scene, base_dir, rest_x, ranges, bond_start, bond_nbr)
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
    )


def cut_bonds_through(scene: Scene, base_dir: Path, rest_x, ranges, bond_start, bond_nbr):
    """Remove bonds whose segment passes through a cutout (tested at 1/4, 1/2 and 3/4 of its length), so a
    notch narrower than the horizon is still a real notch."""
    keep = np.ones(len(bond_nbr), dtype=bool)
    for body, (start, end) in zip(scene.bodies, ranges):
        cuts = [shape_region(c, base_dir) for c in body.geometry.cutouts]
        if not cuts:
            continue
        b0, b1 = bond_start[start], bond_start[end]
        p = np.repeat(np.arange(start, end), np.diff(bond_start[start:end + 1]))
        q = bond_nbr[b0:b1]
        for t in (0.25, 0.5, 0.75):
            mid = rest_x[p] + t * (rest_x[q] - rest_x[p])
            for cut in cuts:
                keep[b0:b1] &= ~cut.inside(mid)
    if keep.all():
        return bond_start, bond_nbr
    return drop_bonds(bond_start, bond_nbr, keep)
