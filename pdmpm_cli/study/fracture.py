"""Fracture energy of a bar pulled apart slowly: the energy balance against G_c times the crack's area.

Grips (pins) at both ends of a notched bar move apart at a constant speed until it breaks at the notch. The energy
the crack absorbed is what the grips put in minus what is still there, D = W - (strain + kinetic energy), and a
body with `fracture.energy` G_c should absorb G_c A over the ligament's area A at every resolution (Griffith).

The grips' work: a pinned particle is held at its velocity v_g whatever its forces, so in each step its grip gives
it the impulse J_p = m_p (v_g - v*_p) - dt f_p, with v*_p the velocity G2P would have given it (the grid's, at its
position at the start of the step) and f_p its bond force, which pins do not scatter (docs/method.md). This is
exact: APIC transfers conserve momentum, so the free particles gain exactly sum_p J_p over a step. The grip does
the work v_g . J_p.
"""

import time
from dataclasses import dataclass

import numpy as np
from numba import njit

from pdmpm_cli.engine.fracture import pieces
from pdmpm_cli.engine.transfer import stencil
from pdmpm_cli.study.sim import Sim

RHO = 1000.0
LAM = MU = 1e5  # M = 3e5 Pa, E = 2.5e5 Pa, wave speed 17.3 m/s
SPEED = 0.02  # each grip [m/s]: 0.1 % of the wave speed
LARGE = 0.05  # a piece is large above this share of the body's mass
GRIP = 0.1  # the plate's grips hold this share of its height at the top and at the bottom


@dataclass(frozen=True)
class Bar:
    """Geometry of the bar [m]: length along x, square section, grips at both ends, a notch from the top."""

    length: float = 0.48
    section: float = 0.12
    grip: float = 0.06  # length of each grip
    notch_depth: float = 0.06  # from the top face (y), through the whole width (z)

    def ligament(self) -> float:
        """Area the crack must cross [m^2]."""
        return self.section * (self.section - self.notch_depth)


def bar_scene(cell: float, energy: float, bar: Bar = Bar(), duration: float = 0.6, fps: float = 200.0,
              sampling: str = "relaxed", cracks: str = "auto") -> dict:
    """The pulled bar at grid cell `cell` (particle spacing cell / 2, horizon 2 spacings) with G_c = `energy`.
    The notch is one spacing wide, on the bar's middle."""
    pad = 4 * cell
    c = np.array([bar.length / 2 + pad, bar.section / 2 + pad, bar.section / 2 + pad])
    hi = [bar.length + 2 * pad, bar.section + 2 * pad, bar.section + 2 * pad]
    grip_x = bar.length / 2 - bar.grip / 2
    grip = lambda sign: {"region": {"type": "box", "center": [c[0] + sign * grip_x, c[1], c[2]],
                                    "size": [bar.grip, 2 * bar.section, 2 * bar.section]},
                         "velocity": [sign * SPEED, 0.0, 0.0]}
    notch = {"type": "box", "center": [c[0], c[1] + bar.section / 2, c[2]],
             "size": [cell / 2, 2 * bar.notch_depth, 2 * bar.section]}
    return {
        "simulation": {"duration": duration, "fps": fps},
        "grid": {"cell_size": cell, "domain": {"min": [0, 0, 0], "max": hi}},
        "gravity": [0, 0, 0],
        "contact": {"cracks": cracks},
        "bodies": [{
            "name": "bar",
            "geometry": {"mode": "cloud", "sampling": sampling,
                         "shape": {"type": "box", "center": c.tolist(), "size": [bar.length, bar.section, bar.section]},
                         "cutouts": [notch]},
            "material": {"model": "elastic", "density": RHO, "lam": LAM, "mu": MU},
            "fracture": {"energy": energy},
            "pins": [grip(-1.0), grip(1.0)],
        }],
    }


@njit(cache=True)
def grip_work(grid, origin, inv_dx, dt, held, particle_x, pin_velocity, particle_mass, particle_force):
    """Work [J] the pins do on particles `held` over the step just taken: sum_p v_g . J_p, with J_p = m_p (v_g - v*_p)
    - dt f_p and v*_p the grid velocity at p's position at the start of the step, x_p - dt v_g."""
    wx, wy, wz = np.empty(4), np.empty(4), np.empty(4)
    x0 = np.empty((1, 3))
    work = 0.0
    for i in range(held.shape[0]):
        p = held[i]
        for a in range(3):
            x0[0, a] = particle_x[p, a] - dt * pin_velocity[p, a]
        fx, fy, fz, bx, by, bz = stencil(x0, 0, origin, inv_dx, wx, wy, wz)
        for a in range(3):
            v = 0.0
            for ii in range(4):
                for jj in range(4):
                    for kk in range(4):
                        v += wx[ii] * wy[jj] * wz[kk] * grid[bx + ii, by + jj, bz + kk, 1 + a]
            impulse = particle_mass[p] * (pin_velocity[p, a] - v) - dt * particle_force[p, a]
            work += pin_velocity[p, a] * impulse
    return work


@dataclass
class Result:
    cell: float
    spacing: float
    horizon: float
    particles: int
    threshold: float
    expected: float  # G_c A [J]
    large: int  # pieces over 5 % of the mass at the end
    separation: float  # time the bar first came apart in two large pieces [s] (nan: never)
    dissipated: float  # W - strain - kinetic at the end [J]
    before: float  # the same just before the first bond broke [J]: the balance's own error while nothing breaks
    stored: float  # strain energy then [J]: what an unstable crack releases as motion, which the transfers damp
    work_before: float  # W then [J]
    cut_energy: float  # energy the bonds held when they were cut, (M/2) s^2 per direction [J]
    plane_energy: float  # the part of it in bonds across the notch's mid-plane (the crack's own) [J]
    plane_area: float  # broken bonds across that plane, as bond_area below [m^2]
    bond_area: float  # sum over broken bonds of their energy at the threshold, / G_c [m^2]
    area: float  # the ligament [m^2]
    seconds: float


def critical_bond_energy(model, body: int, modulus: float, threshold: float) -> np.ndarray:
    """Per directed bond, the energy it holds at stretch `threshold` under a homogeneous stretch [J]:
    c_p w V_p V_q M s^2 / 2 (docs/method.md, 'Fracture energy')."""
    b = model.bodies[body]
    own = np.repeat(np.arange(len(model.bond_start) - 1), np.diff(model.bond_start))
    q = model.bond_nbr
    r = np.linalg.norm(model.rest_x[q] - model.rest_x[own], axis=1)
    v = model.particle_volume
    return model.particle_coef[own] * (1.0 - r / b.horizon) * v[own] * v[q] * 0.5 * modulus * threshold**2


def crossing_energy(model, body: int, modulus: float, plane: float, lo, hi) -> float:
    """Energy per unit area [J/m^2] of the bonds crossing the plane x = `plane` within the square lo <= (y, z) < hi,
    all at the body's threshold: the discrete counterpart of the integral that sets the threshold from G_c."""
    own = np.repeat(np.arange(len(model.bond_start) - 1), np.diff(model.bond_start))
    x = model.rest_x
    q = model.bond_nbr
    cross = (x[own, 0] < plane) != (x[q, 0] < plane)
    xi = x[q] - x[own]
    t = (plane - x[own, 0]) / np.where(cross, xi[:, 0], 1.0)
    yz = x[own, 1:] + t[:, None] * xi[:, 1:]
    inside = cross & np.all((yz >= lo) & (yz < hi), axis=1)
    energy = critical_bond_energy(model, body, modulus, model.bodies[body].fracture.threshold)
    return float(energy[inside].sum()) / float(np.prod(np.asarray(hi) - np.asarray(lo)))


def large_pieces(state, model, body: int = 0) -> int:
    """Pieces of the body over LARGE of its mass."""
    b = model.bodies[body]
    labels = pieces(state.bond_start, state.bond_nbr, state.bond_active == 1, b.start, b.end)
    mass = model.particle_mass[b.start:b.end]
    return int(np.count_nonzero(np.bincount(labels, weights=mass) > LARGE * mass.sum()))


def pull(cell: float, energy: float, bar: Bar = Bar(), duration: float = 0.4, after: float = 0.1,
         sampling: str = "relaxed", damage_resistance: float | None = None, cracks: str = "auto",
         flip: float = 0.0, seed: int = 0, trace: list | None = None) -> Result:
    """Pull the bar at `cell` until `after` seconds past its first separation (or `duration`); the energy balance.
    `seed` is the particle sampling's (simulation.seed). `trace` (a list) receives per frame (t [s], W, strain,
    kinetic, cut bonds' energy, of it across the plane [J], bonds cut)."""
    t0 = time.perf_counter()
    scene = bar_scene(cell, energy, bar, duration, sampling=sampling, cracks=cracks)
    scene["simulation"]["flip"] = flip
    scene["simulation"]["seed"] = seed
    if damage_resistance is not None:
        scene["bodies"][0]["fracture"]["damage_resistance"] = damage_resistance
    sim = Sim(scene)
    model, state, solver = sim.model, sim.state, sim.solver
    b = model.bodies[0]
    modulus = LAM + 2.0 * MU
    held = np.flatnonzero(model.pin_mask).astype(np.int64)
    own = np.repeat(np.arange(len(model.bond_start) - 1), np.diff(model.bond_start))
    rest = np.linalg.norm(model.rest_x[model.bond_nbr] - model.rest_x[own], axis=1)
    weight = critical_bond_energy(model, 0, modulus, 1.0)  # energy per directed bond / s^2
    mid = model.rest_x[b.start:b.end, 0].mean()
    across = (model.rest_x[own, 0] < mid) != (model.rest_x[model.bond_nbr, 0] < mid)
    tally = {"work": 0.0, "cut": 0.0, "plane": 0.0, "bonds_cut": 0, "x": state.particle_x.copy(),
             "active": state.bond_active.copy()}

    def on_substep(st, dt):
        grid = st.grid if st.has("grid") else st.grid_field[0]  # crack fields: the grips' nodes are not split
        tally["work"] += grip_work(grid, model.origin, 1.0 / model.dx, dt, held, st.particle_x,
                                   model.pin_velocity, model.particle_mass, st.particle_force)
        if st.bonds_cut != tally["bonds_cut"]:  # bonds cut this step: the energy they held (positions before it)
            new = (tally["active"] == 1) & (st.bond_active == 0)
            x = tally["x"]
            s = np.linalg.norm(x[model.bond_nbr[new]] - x[own[new]], axis=1) / rest[new] - 1.0
            tally["cut"] += float(weight[new] @ s**2)
            tally["plane"] += float(weight[new] @ (s**2 * across[new]))
            tally["active"][:] = st.bond_active
            tally["bonds_cut"] = st.bonds_cut
        tally["x"][:] = st.particle_x

    def balance() -> float:
        return tally["work"] - solver.strain_energy(state) - solver.kinetic_energy(state)

    before = work_before = stored = separation = np.nan
    end = duration
    while state.time < end - 1e-12:
        last = (balance(), tally["work"], solver.strain_energy(state)) if state.bonds_cut == 0 else None
        solver.advance(state, min(state.time + sim.plan.frame_dt, end), on_substep)
        if last is not None and state.bonds_cut > 0:
            before, work_before, stored = last
        if trace is not None:
            trace.append((state.time, tally["work"], solver.strain_energy(state), solver.kinetic_energy(state),
                          tally["cut"], tally["plane"], state.bonds_cut))
        if np.isnan(separation) and state.bonds_cut > 0 and large_pieces(state, model) >= 2:
            separation = state.time
            end = min(duration, state.time + after)
    crit = critical_bond_energy(model, 0, modulus, b.fracture.threshold)
    broken = state.bond_active == 0
    return Result(cell=cell, spacing=b.spacing, horizon=b.horizon, particles=b.end - b.start,
                  threshold=b.fracture.threshold, expected=energy * bar.ligament(), large=large_pieces(state, model),
                  separation=separation, dissipated=balance(), before=before, work_before=work_before, stored=stored,
                  cut_energy=tally["cut"], plane_energy=tally["plane"], bond_area=float(crit[broken].sum()) / energy,
                  plane_area=float(crit[broken & across].sum()) / energy,
                  area=bar.ligament(), seconds=time.perf_counter() - t0)


def plate_scene(cell: float, energy: float, size: float = 0.48, thickness: float = 0.06, notch: float = 0.12,
                duration: float = 0.3, speed: float = SPEED) -> dict:
    """A single-edge-notched plate in mode I: grips along its top and bottom edges pull it apart in y; the notch,
    half a cell wide, runs in x from the left edge to `notch` at mid-height."""
    pad = 4 * cell
    c = [size / 2 + pad, size / 2 + pad, thickness / 2 + pad]
    grip = GRIP * size
    pins = [{"region": {"type": "box", "center": [c[0], c[1] + sign * (size - grip) / 2, c[2]],
                        "size": [2 * size, grip, 2 * thickness]}, "velocity": [0.0, sign * speed, 0.0]}
            for sign in (-1.0, 1.0)]
    cut = {"type": "box", "center": [c[0] - size / 2, c[1], c[2]], "size": [2 * notch, cell / 2, 2 * thickness]}
    return {
        "simulation": {"duration": duration, "fps": 200.0},
        "grid": {"cell_size": cell, "domain": {"min": [0, 0, 0], "max": [size + 2 * pad, size + 2 * pad,
                                                                           thickness + 2 * pad]}},
        "gravity": [0, 0, 0],
        "bodies": [{
            "name": "plate",
            "geometry": {"mode": "cloud", "shape": {"type": "box", "center": c, "size": [size, size, thickness]},
                         "cutouts": [cut]},
            "material": {"model": "elastic", "density": RHO, "lam": LAM, "mu": MU},
            "fracture": {"energy": energy},
            "pins": pins,
        }],
    }


def damage_band(model, state, body: int = 0, grip: float = 0.0, notch: float = 0.0) -> dict:
    """Where a mode-I crack's damage lies, among the particles more than `grip` + a horizon from the top and bottom
    faces (damage at the grips' edges is counted apart, as `at_grips`): the damaged particles' rest distance from
    the notch's plane (y) as percentiles 50 / 90 / 100 [m], how far in x the damage reached [m], and how many lie
    along the notch's faces, more than a horizon behind its tip (`notch` long from the left edge)."""
    b = model.bodies[body]
    x0 = model.rest_x[b.start:b.end]
    lo, hi = x0[:, 1].min(), x0[:, 1].max()
    mid = 0.5 * (lo + hi)
    damaged = state.particle_damage[b.start:b.end] > 0
    inner = np.abs(x0[:, 1] - mid) < 0.5 * (hi - lo) - grip - b.horizon
    hit = damaged & inner
    out = {"damaged": int(hit.sum()), "at_grips": int((damaged & ~inner).sum()),
           "at_faces": int((hit & (x0[:, 0] < x0[:, 0].min() + notch - b.horizon)).sum())}
    if not hit.any():
        return out | {"p50": 0.0, "p90": 0.0, "max": 0.0, "reach": 0.0}
    p50, p90, top = np.percentile(np.abs(x0[hit, 1] - mid), [50, 90, 100])
    return out | {"p50": float(p50), "p90": float(p90), "max": float(top),
                  "reach": float(x0[hit, 0].max() - x0[:, 0].min())}


def slit_drag(cell: float = 0.02, speed: float = 0.1, duration: float = 0.05,
              cracks: str = "auto") -> tuple[float, float]:
    """A bar cut through by a slit half a cell wide (no bond crosses it; the lattice's layers either side of it lie
    one spacing apart), its right end pulled away (pushed, for speed < 0) at `speed`: the left half's mean
    displacement over speed x duration, and the smallest gap between the halves at the end in spacings (1 at rest).
    Pulled, no force crosses the gap, so the first is 0; the grid couples material closer than its B-splines' reach
    (two cells either side)."""
    c = [0.2, 0.1, 0.1]
    body = {"name": "bar",
            "geometry": {"mode": "cloud", "sampling": "lattice",
                         "shape": {"type": "box", "center": c, "size": [0.24, 0.06, 0.06]},
                         "cutouts": [{"type": "box", "center": c, "size": [cell / 2, 0.2, 0.2]}]},
            "material": {"model": "elastic", "density": RHO, "lam": LAM, "mu": MU},
            "pins": [{"region": {"type": "box", "center": [c[0] + 0.1, c[1], c[2]], "size": [0.04, 0.2, 0.2]},
                      "velocity": [speed, 0.0, 0.0]}]}
    sim = Sim({"simulation": {"duration": duration, "fps": 100},
               "grid": {"cell_size": cell, "domain": {"min": [0, 0, 0], "max": [0.5, 0.2, 0.2]}},
               "gravity": [0, 0, 0], "bodies": [body], "contact": {"cracks": cracks}})
    sim.advance(duration)
    x = sim.state.particle_x
    left = sim.model.rest_x[:, 0] < c[0]
    gap = (x[~left, 0].min() - x[left, 0].max()) / sim.model.bodies[0].spacing
    return float((x - sim.model.rest_x)[left, 0].mean() / (speed * duration)), float(gap)
