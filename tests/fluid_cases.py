"""Liquid test cases with answers from outside the code: a column at rest in a tank (hydrostatics), a dam break
(volume), start-up Couette flow (the analytic series). Scenes as dicts, measures from particle positions alone.
Used by tests/test_fluids.py (reduced and slow versions) and bench/fluids.py (the figures in docs/results.md)."""

import math

import numpy as np
from scipy.spatial import ConvexHull, Voronoi, cKDTree

G = 9.81  # m/s^2


def liquid(density, mu, tau, **extra) -> dict:
    """A viscoelastic liquid whose shear relaxes fully: viscosity mu tau [Pa s]; no bond bulk part (lam 0)."""
    return {"model": "viscoelastic", "density": density, "lam": 0.0, "mu": mu, "relaxation_time": tau,
            "relaxing_fraction": 1.0} | extra


def planes(*pairs, boundary="slip") -> list:
    return [{"type": "plane", "point": list(p), "normal": list(n), "boundary": boundary} for p, n in pairs]


def column(density, duration, dx=0.02, size=(0.08, 0.12, 0.08), mu=1000.0, tau=0.002) -> dict:
    """A liquid column at rest in a tank of its own cross-section (slip walls), on the floor at y = 0.1 m."""
    sx, sy, sz = size
    c = 0.15
    return {
        "simulation": {"duration": duration, "fps": 20},
        "grid": {"cell_size": dx, "domain": {"min": [0, 0, 0], "max": [0.3, 0.1 + sy + 0.1, 0.3]}},
        "gravity": [0, -G, 0],
        "bodies": [{"name": "column", "geometry": {"mode": "cloud", "sampling": "lattice", "shape": {
            "type": "box", "center": [c, 0.1 + sy / 2, c], "size": [sx, sy, sz]}},
            "material": liquid(density, mu, tau)}],
        "colliders": planes(([0, 0.1, 0], [0, 1, 0]), ([c - sx / 2, 0, 0], [1, 0, 0]), ([c + sx / 2, 0, 0], [-1, 0, 0]),
                            ([0, 0, c - sz / 2], [0, 0, 1]), ([0, 0, c + sz / 2], [0, 0, -1])),
    }


def dam_break(duration, dx=0.02, block=(0.08, 0.12, 0.06), tank=0.32, mu=1000.0, tau=0.002, **extra) -> dict:
    """A block of liquid released in the corner of a tank (slip walls; its depth in z between walls)."""
    bx, by, bz = block
    x0, y0, z0 = 0.1, 0.1, 0.1
    return {
        "simulation": {"duration": duration, "fps": 20},
        "grid": {"cell_size": dx, "domain": {"min": [0, 0, 0], "max": [x0 + tank + 0.1, y0 + by + 0.1, z0 + bz + 0.1]}},
        "gravity": [0, -G, 0],
        "bodies": [{"name": "dam", "geometry": {"mode": "cloud", "sampling": "lattice", "shape": {
            "type": "box", "center": [x0 + bx / 2, y0 + by / 2, z0 + bz / 2], "size": [bx, by, bz]}},
            "material": liquid(1000.0, mu, tau, **extra)}],
        "colliders": planes(([0, y0, 0], [0, 1, 0]), ([x0, 0, 0], [1, 0, 0]), ([x0 + tank, 0, 0], [-1, 0, 0]),
                            ([0, 0, z0], [0, 0, 1]), ([0, 0, z0 + bz], [0, 0, -1])),
    }


def couette(duration, dx=0.01, depth=0.1, length=0.2, width=0.04, speed=0.1, density=1000.0, mu=1e4,
            tau=0.001) -> dict:
    """A liquid layer (depth H) between a sticky floor and a sticky plate that starts moving at `speed` along x at
    t = 0; slip walls in z, free ends in x, no gravity. Viscosity mu tau, kinematic mu tau / density (tau short
    against the diffusion time depth^2 / nu, so the Maxwell liquid is nearly Newtonian). The walls lie half a cell
    between grid nodes, so the nodes on either side are unambiguously free or held: the grid's no-slip planes are
    the held node rows, depth + dx apart."""
    y0, z0 = 0.105, 0.105
    return {
        "simulation": {"duration": duration, "fps": 20},
        "grid": {"cell_size": dx, "domain": {"min": [0, 0, 0], "max": [length + 0.2, y0 + depth + 0.1,
                                                                       z0 + width + 0.1]}},
        "gravity": [0, 0, 0],
        "bodies": [{"name": "layer", "geometry": {"mode": "cloud", "sampling": "lattice", "shape": {
            "type": "box", "center": [0.1 + length / 2, y0 + depth / 2, z0 + width / 2],
            "size": [length, depth, width]}},
            "material": liquid(density, mu, tau)}],
        "colliders": planes(([0, y0, 0], [0, 1, 0]), boundary="sticky")
        + [{"type": "plane", "point": [0, y0 + depth, 0], "normal": [0, -1, 0], "boundary": "sticky",
            "velocity": [speed, 0, 0]}]
        + planes(([0, 0, z0], [0, 0, 1]), ([0, 0, z0 + width], [0, 0, -1])),
    }


def pour(duration, dx=0.02, radius=0.02, speed=0.5, fill=1.0, height=0.25, tank=0.16, density=1400.0, mu=1000.0,
         tau=0.002, stop=None, plate_velocity=None) -> dict:
    """A liquid poured from a nozzle (a disc one spacing h = dx / 2 thick, axis y) at `height` above the floor of a
    square tank (slip walls) at y = 0.1 m: rate = fill x (nozzle lattice area N h^2) x speed, so fill 1 is a
    continuous stream. A short plug of the same liquid below the nozzle is the stream's head at t = 0. With
    `plate_velocity` the floor is a sticky plate moving at that velocity [m/s] instead."""
    h = dx / 2
    c, y0 = 0.1 + tank / 2, 0.1
    ny = y0 + height
    n = sum(1 for i in range(-10, 10) for k in range(-10, 10) if (i + 0.5) ** 2 + (k + 0.5) ** 2 <= (radius / h) ** 2)
    emitter = {"shape": {"type": "cylinder", "center": [c, ny, c], "radius": radius, "height": h,
                         "rotation": [90, 0, 0]},
               "velocity": [0, -speed, 0], "rate": fill * n * h * h * speed}
    if stop is not None:
        emitter["stop"] = stop
    floor = ([{"type": "plane", "point": [0, y0, 0], "normal": [0, 1, 0], "boundary": "sticky",
               "velocity": list(plate_velocity)}] if plate_velocity is not None else planes(([0, y0, 0], [0, 1, 0])))
    return {
        "simulation": {"duration": duration, "fps": 20},
        "grid": {"cell_size": dx, "domain": {"min": [0, 0, 0], "max": [tank + 0.2, ny + 0.1, tank + 0.2]}},
        "gravity": [0, -G, 0],
        "bodies": [{"name": "pour", "geometry": {"mode": "cloud", "sampling": "lattice", "shape": {
            "type": "cylinder", "center": [c, ny - 2 * h, c], "radius": radius, "height": 2 * h,
            "rotation": [90, 0, 0]}},
            "material": liquid(density, mu, tau), "velocity": [0, -speed, 0], "emitter": emitter}],
        "colliders": floor + planes(([0.1, 0, 0], [1, 0, 0]), ([0.1 + tank, 0, 0], [-1, 0, 0]),
                                    ([0, 0, 0.1], [0, 0, 1]), ([0, 0, 0.1 + tank], [0, 0, -1])),
    }


def mid_layer_velocity(x, v, h, centre, depth) -> float:
    """Mean x velocity of the particles within h of mid-depth, within a depth of the layer's middle in x [m/s]."""
    sel = (np.abs(x[:, 1] - centre[1]) < h) & (np.abs(x[:, 0] - centre[0]) < 0.5 * depth)
    return float(v[sel, 0].mean())


def couette_mid_velocity(t, depth, nu, speed, terms=200) -> float:
    """Start-up plane Couette flow at mid-depth (Batchelor 1967, sec. 4.3; separation of variables):
    u(H/2, t) = U/2 - (2 U / pi) sum_{n odd} (-1)^((n-1)/2) / n exp(-n^2 pi^2 nu t / H^2) [m/s]."""
    n = np.arange(1, 2 * terms, 2)
    return float(speed / 2 - 2 * speed / math.pi * np.sum((-1.0) ** ((n - 1) // 2) / n
                                                           * np.exp(-(n * math.pi) ** 2 * nu * t / depth**2)))


def nearest_spacing(x) -> float:
    """Mean distance from each particle to its nearest neighbour [m]."""
    d, _ = cKDTree(x).query(x, 2)
    return float(d[:, 1].mean())


def cubic_kernel(r, h):
    """Cubic B-spline smoothing kernel W(r, h) in 3D, support 2h, unit integral (Monaghan 1992) [1/m^3]."""
    q = r / h
    w = np.where(q < 1.0, 1.0 - 1.5 * q**2 + 0.75 * q**3, np.where(q < 2.0, 0.25 * (2.0 - q) ** 3, 0.0))
    return w / (math.pi * h**3)


def occupied_volume(x, h) -> float:
    """N times the mean Voronoi cell volume of the bulk particles [m^3]: a liquid keeps its volume when its bulk
    keeps its particle density, and Voronoi cells tile space, so disorder does not bias the mean. The bulk: the
    particles whose cell and whose Voronoi neighbours' cells lie within 2 h of their particles (at a free surface
    or a wall, cells reach far or are unbounded; the second layer's cells take what the surface's leave)."""
    vor = Voronoi(x)
    volume = np.full(len(x), np.nan)
    for i, r in enumerate(vor.point_region):
        region = vor.regions[r]
        if region and -1 not in region:
            verts = vor.vertices[region]
            if np.linalg.norm(verts - x[i], axis=1).max() < 2.0 * h:
                volume[i] = ConvexHull(verts).volume
    bulk = np.isfinite(volume)
    a, b = vor.ridge_points[:, 0], vor.ridge_points[:, 1]
    inner = bulk.copy()
    inner[a[~bulk[b]]] = False
    inner[b[~bulk[a]]] = False
    return float(len(x) * volume[inner].mean())


def surface_height(x, h, floor) -> float:
    """Mean height of the free surface above `floor` [m]: the highest particle in each 2h x 2h column of the x-z
    plane, plus the half spacing it owns above its centre."""
    keys = np.floor(x[:, [0, 2]] / (2 * h)).astype(np.int64)
    _, inverse = np.unique(keys, axis=0, return_inverse=True)
    top = np.full(inverse.max() + 1, -np.inf)
    np.maximum.at(top, inverse.ravel(), x[:, 1])
    return float(top.mean() + 0.5 * h - floor)
