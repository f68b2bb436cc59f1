"""Contact between bodies, with answers from outside the code: two identical elastic spheres meeting head-on
(momentum conserved, an elastic impact keeps its kinetic energy and starts when the surfaces touch), a block
sliding on another body (Coulomb friction decelerates it at mu g), two bodies passing half a cell apart (no force).
Scenes as dicts, measures from particle positions and velocities. Used by tests/test_contact.py (reduced and slow
versions) and bench/contact.py (the figures in docs/results.md)."""

import math
import time

import numpy as np

from pdmpm_cli.study.sim import Sim

G = 9.81  # m/s^2
RHO = 1000.0  # kg/m^3


def elastic(E: float = 1e5) -> dict:
    """An elastic material of effective Young's modulus E (P-wave modulus M = 6 E / 5, lam = mu = M / 3)."""
    M = 6 * E / 5
    return {"model": "elastic", "density": RHO, "lam": M / 3, "mu": M / 3}


def wave_speed(E: float = 1e5) -> float:
    return float(np.sqrt(6 * E / 5 / RHO))


def hertz_time(radius: float, closing_speed: float, E: float = 1e5, nu: float = 0.25) -> float:
    """Duration of the elastic impact of two identical spheres (Hertz; Johnson, Contact Mechanics, 1985, eq. 11.24)
    [s]: 2.87 (m*^2 / (R* E*^2 v))^(1/5), m* = m / 2, R* = radius / 2, E* = E / (2 (1 - nu^2))."""
    m = RHO * 4 / 3 * np.pi * radius**3
    e_star = E / (2 * (1 - nu**2))
    return float(2.87 * ((m / 2) ** 2 / (radius / 2 * e_star**2 * closing_speed)) ** 0.2)


def contact(mode: str, **extra) -> dict:
    """The scene's contact section for `mode`: separate (a field per body, the default contact model) or shared
    (contact.mode), or penalty or projection (a field per body with that contact.model)."""
    model = {"penalty": "penalty", "projection": "projection"}.get(mode)
    return ({"mode": "separate", "model": model} if model else {"mode": mode}) | extra


def sphere_pair(spacings: float, closing: float = 0.05, mode: str = "separate", radius: float = 0.1,
                stiffness: float | None = None) -> dict:
    """Two identical elastic spheres of `spacings` particle spacings in radius (spacing half a cell, relaxed
    sampling), closing along x at `closing` x the P-wave speed c (each at half of it), released one cell apart,
    without gravity: the approach, the contact (Hertz's duration) and a flight apart of half that. `stiffness`
    sets contact.stiffness (the penalty's; None: the default)."""
    h = radius / spacings
    cell = 2 * h
    c = wave_speed()
    v = 0.5 * closing * c
    gap = cell
    x = radius + gap / 2
    duration = gap / (2 * v) + 1.6 * hertz_time(radius, 2 * v)
    pad = 6 * cell
    return {
        "simulation": {"duration": duration, "fps": 40 / duration},
        "grid": {"cell_size": cell, "domain": {"min": [-x - 2 * radius - pad, -radius - pad, -radius - pad],
                                               "max": [x + 2 * radius + pad, radius + pad, radius + pad]}},
        "gravity": [0, 0, 0],
        "contact": contact(mode, **({} if stiffness is None else {"stiffness": stiffness})),
        "bodies": [{"name": name, "velocity": [s * v, 0, 0],
                    "geometry": {"mode": "cloud", "spacing": h,
                                 "shape": {"type": "sphere", "center": [-s * x, 0, 0], "radius": radius}},
                    "material": elastic()}
                   for name, s in (("left", 1.0), ("right", -1.0))],
    }


def body_velocity(sim: Sim, body: int) -> np.ndarray:
    b, m = sim.model.bodies[body], sim.model.particle_mass
    return m[b.start:b.end] @ sim.state.particle_v[b.start:b.end] / m[b.start:b.end].sum()


def sphere_collision(spacings: float, closing: float = 0.05, mode: str = "separate",
                     stiffness: float | None = None, step: float | None = None) -> dict:
    """Run the sphere pair. Returns: contact_gap, the distance between the surfaces (outermost particle centres plus
    half a spacing each) when the approach speed has fallen by 0.1 % [cells] (0: the geometric touch; None: no
    contact); smallest_gap, that distance at its smallest over the run [cells]; ke, the bodies' translational kinetic
    energy after over before; energy, kinetic + strain energy after over before; momentum, the largest change of the
    total momentum over one body's m v; apart, the surface gap at the end [cells] and the speeds of the two bodies'
    centres of mass [m/s]."""
    sim = Sim(sphere_pair(spacings, closing, mode, stiffness=stiffness))
    if step is not None:  # forced: step dx / c (bench/contact.py --step)
        sim.force_step(step)
    m, s = sim.model, sim.state
    (a0, a1), (b0, b1) = m.body_ranges
    mass = m.particle_mass[a0:a1].sum()
    h, v = m.bodies[0].spacing, float(s.particle_v[0, 0])

    def translational():
        return 0.5 * mass * (np.sum(body_velocity(sim, 0) ** 2) + np.sum(body_velocity(sim, 1) ** 2))

    def surface_gap():
        return (s.particle_x[b0:b1, 0].min() - s.particle_x[a0:a1, 0].max() - h) / m.dx

    e0 = sim.solver.kinetic_energy(s) + sim.solver.strain_energy(s)
    k0, p0 = translational(), sim.momentum()
    out = {"contact_gap": None, "momentum": 0.0, "smallest_gap": math.inf}

    def watch(state, dt):
        out["smallest_gap"] = min(out["smallest_gap"], surface_gap())
        if out["contact_gap"] is None and body_velocity(sim, 0)[0] - body_velocity(sim, 1)[0] < (1 - 1e-3) * 2 * v:
            out["contact_gap"] = surface_gap()
        out["momentum"] = max(out["momentum"], float(np.abs(sim.momentum() - p0).max() / (mass * v)))

    t0 = time.perf_counter()
    sim.advance(sim.scene.simulation.duration, watch)
    return out | {"particles": m.n_particles, "steps": s.step, "ke": translational() / k0,
                  "energy": (sim.solver.kinetic_energy(s) + sim.solver.strain_energy(s)) / e0,
                  "apart": surface_gap(), "v_left": float(body_velocity(sim, 0)[0]),
                  "v_right": float(body_velocity(sim, 1)[0]), "seconds": time.perf_counter() - t0}


def sliding_block(friction: float, v0: float = 1.0, duration: float = 0.2, cell: float = 0.02,
                  mode: str = "separate") -> dict:
    """A block (4 x 2 x 4 cells) sliding at v0 along x on a slab (20 x 3 x 8 cells) that rests on the sticky floor
    (a plane collider), under gravity, with Coulomb friction `friction` between them. The block starts on the slab
    (surfaces touching), so its weight presses on it from the first step."""
    h = cell / 2
    slab = (20 * cell, 3 * cell, 8 * cell)
    block = (4 * cell, 2 * cell, 4 * cell)
    floor = 4 * cell  # a sticky plane collider: particles must stay 3.5 cells inside the domain
    width = (slab[0] + 8 * cell, floor + slab[1] + block[1] + 8 * cell, slab[2] + 8 * cell)

    def box(center, size):
        return {"mode": "cloud", "sampling": "lattice", "spacing": h,
                "shape": {"type": "box", "center": list(center), "size": list(size)}}

    cx, cz = width[0] / 2, width[2] / 2
    return {
        "simulation": {"duration": duration, "fps": 100},
        "grid": {"cell_size": cell, "domain": {"min": [0, 0, 0], "max": list(width)}},
        "gravity": [0, -G, 0],
        "colliders": [{"type": "plane", "point": [0, floor, 0], "normal": [0, 1, 0], "boundary": "sticky"}],
        "contact": contact(mode, friction=friction),
        "bodies": [
            {"name": "slab", "geometry": box((cx, floor + slab[1] / 2, cz), slab), "material": elastic()},
            {"name": "block", "geometry": box((cx - slab[0] / 4, floor + slab[1] + block[1] / 2, cz), block),
             "material": elastic(), "velocity": [v0, 0, 0]},
        ],
    }


def sliding(friction: float, v0: float = 1.0, duration: float = 0.15, settle: float = 0.05, cell: float = 0.02,
            mode: str = "separate") -> dict:
    """Run the sliding block; its x velocity over time and the least-squares deceleration after `settle` s (while
    it still moves) [m/s^2]."""
    sim = Sim(sliding_block(friction, v0, duration, cell, mode))
    t, v = [0.0], [float(body_velocity(sim, 1)[0])]
    for frame in range(1, int(round(duration * 100)) + 1):
        sim.advance(frame / 100)
        t.append(sim.state.time)
        v.append(float(body_velocity(sim, 1)[0]))
    t, v = np.array(t), np.array(v)
    use = (t >= settle) & (v > 0.05 * v0)
    slope = -np.polyfit(t[use], v[use], 1)[0] if use.sum() >= 3 else float("nan")
    return {"t": t, "v": v, "deceleration": float(slope), "steps": sim.state.step}


def floor_slide(friction: float, v0: float = 1.0, duration: float = 0.15, settle: float = 0.05,
                cell: float = 0.02) -> dict:
    """A block (4 x 2 x 4 cells, lattice) set down touching a penalty floor (a plane collider, response penalty,
    Coulomb `friction`) and sliding along it at v0, under gravity. Returns its x velocity over time, the
    least-squares deceleration after `settle` s while it still moves [m/s^2], and the deepest any particle centre
    went below the floor over the run [cells]."""
    h = cell / 2
    block = (4 * cell, 2 * cell, 4 * cell)
    floor = 4 * cell
    width = (30 * cell, floor + block[1] + 8 * cell, block[2] + 8 * cell)
    sim = Sim({
        "simulation": {"duration": duration, "fps": 100},
        "grid": {"cell_size": cell, "domain": {"min": [0, 0, 0], "max": list(width)}},
        "gravity": [0, -G, 0],
        "colliders": [{"type": "plane", "point": [0, floor, 0], "normal": [0, 1, 0], "boundary": "separate",
                       "friction": friction, "response": "penalty"}],
        "bodies": [{"name": "block", "velocity": [v0, 0, 0], "material": elastic(),
                    "geometry": {"mode": "cloud", "sampling": "lattice", "spacing": h, "shape": {
                        "type": "box", "center": [6 * cell, floor + block[1] / 2, width[2] / 2],
                        "size": list(block)}}}],
    })
    t, v, deepest = [0.0], [float(body_velocity(sim, 0)[0])], [0.0]

    def watch(state, dt):
        deepest[0] = max(deepest[0], (floor - float(state.particle_x[:, 1].min())) / cell)

    for frame in range(1, int(round(duration * 100)) + 1):
        sim.advance(frame / 100, watch)
        t.append(sim.state.time)
        v.append(float(body_velocity(sim, 0)[0]))
    t, v = np.array(t), np.array(v)
    use = (t >= settle) & (v > 0.05 * v0)
    slope = -np.polyfit(t[use], v[use], 1)[0] if use.sum() >= 3 else float("nan")
    return {"t": t, "v": v, "deceleration": float(slope), "deepest": deepest[0],
            "vy": float(np.abs(sim.state.particle_v[:, 1]).max())}


def passing(mode: str = "separate", friction: float = 0.5, v0: float = 0.5, duration: float = 0.05) -> dict:
    """Two blocks (6 x 6 x 6 cells) half a cell apart across y, one at rest and one moving at v0 along x (parallel
    to the gap), without gravity: the momentum the resting block picks up over the moving one's m v0."""
    cell = 0.02
    size = 6 * cell

    def block(y):
        return {"mode": "cloud", "sampling": "lattice", "spacing": cell / 2,
                "shape": {"type": "box", "center": [0.3, y, 0.2], "size": [size, size, size]}}

    y0 = 0.2
    scene = {
        "simulation": {"duration": duration, "fps": 100},
        "grid": {"cell_size": cell, "domain": {"min": [0, 0, 0], "max": [0.6, 0.6, 0.4]}},
        "gravity": [0, 0, 0],
        "contact": contact(mode, friction=friction),
        "bodies": [{"name": "still", "geometry": block(y0), "material": elastic()},
                   {"name": "moving", "geometry": block(y0 + size + cell / 2), "material": elastic(),
                    "velocity": [v0, 0, 0]}],
    }
    sim = Sim(scene)
    sim.advance(duration)
    m = sim.model.particle_mass
    b = sim.model.bodies
    mv = m[b[1].start:b[1].end].sum() * v0
    return {"picked_up": float(np.linalg.norm(m[b[0].start:b[0].end] @ sim.state.particle_v[b[0].start:b[0].end]))
            / mv, "speed": float(body_velocity(sim, 1)[0]) / v0}


def ball_drop(spacings: float = 5, drop: float = 0.1, radius: float = 0.05, E: float = 1e6, flip: float = 0.0,
              response: str | None = None, stiffness: float | None = None) -> dict:
    """An elastic ball of `spacings` particle spacings in radius (spacing half a cell) released with its lowest
    point `drop` [m] above a rigid, frictionless floor collider (a plane, boundary separate, the collider's
    `response` and `stiffness`: None, the scene's default), under gravity.
    Rebound height over drop height is e^2 (coefficient of restitution e; an elastic impact: 1). Returns:
    rebound, the highest the ball's lowest point rises after the impact over `drop`; contact, the impact's duration
    [s] (Hertz against a rigid plane: 2.87 (m^2 / (R E*^2 v))^(1/5), E* = E / (1 - nu^2)); hertz, that prediction."""
    h = radius / spacings
    cell = 2 * h
    v_impact = float(np.sqrt(2 * G * drop))
    fall = v_impact / G
    duration = 2.2 * fall
    pad = 6 * cell
    floor = 0.0
    y0 = floor + drop + radius
    scene = {
        "simulation": {"duration": duration, "fps": 200, "flip": flip},
        "grid": {"cell_size": cell, "domain": {"min": [-radius - pad, floor - pad, -radius - pad],
                                               "max": [radius + pad, y0 + radius + pad, radius + pad]}},
        "gravity": [0, -G, 0],
        "colliders": [{"type": "plane", "point": [0, floor, 0], "normal": [0, 1, 0], "boundary": "separate",
                       "friction": 0.0, **({} if response is None else {"response": response}),
                       **({} if stiffness is None else {"stiffness": stiffness})}],
        "bodies": [{"name": "ball", "geometry": {"mode": "cloud", "spacing": h,
                                                  "shape": {"type": "sphere", "center": [0, y0, 0], "radius": radius}},
                    "material": elastic(E)}],
    }
    sim = Sim(scene)
    s = sim.state
    lowest0 = float(s.particle_x[:, 1].min()) - h / 2  # the surface: outermost centres plus half a spacing
    out = {"touch": None, "leave": None, "peak": -np.inf}

    def watch(state, dt):
        vy = body_velocity(sim, 0)[1]
        low = float(state.particle_x[:, 1].min()) - h / 2
        if out["touch"] is None and low <= floor + 1e-12 + 0.5 * cell:
            out["touch"] = state.time
        if out["touch"] is not None and out["leave"] is None and vy > 0 and low > floor + 0.5 * cell:
            out["leave"] = state.time
        if out["leave"] is not None:
            out["peak"] = max(out["peak"], low)

    t0 = time.perf_counter()
    sim.advance(duration, watch)
    m = RHO * 4 / 3 * np.pi * radius**3
    hertz = 2.87 * (m**2 / (radius * (E / (1 - 0.25**2)) ** 2 * v_impact)) ** 0.2
    return {"particles": sim.model.n_particles, "steps": s.step, "drop": lowest0 - floor,
            "rebound": (out["peak"] - floor) / (lowest0 - floor) if out["leave"] is not None else 0.0,
            "hertz": hertz, "seconds": time.perf_counter() - t0}
