"""Validated scene + discretisation -> the engine's Model: typed parameters and packed arrays, so the engine never
reads a pydantic object."""

import math

import numpy as np

from pdmpm_cli.engine.bonds import calibration_coefficients, reference_family_terms
from pdmpm_cli.engine.colliders import BOUNDARY_CODES, BOX, CYLINDER, MESH, PENALTY_BACKSTOP, PLANE, ROW, SPHERE
from pdmpm_cli.engine.fields import BOND_FACTORS
from pdmpm_cli.engine.fracture import critical_stretch
from pdmpm_cli.discretize import Discretization
from pdmpm_cli.engine.emitter import Emitter
from pdmpm_cli.errors import SceneValueError
from pdmpm_cli.engine.materials import MATERIALS, kind_of
from pdmpm_cli.engine.model import BodyParams, FractureParams, Model
from pdmpm_cli.scene.schema import Scene


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def penalized(collider, flip: float = 0.0) -> bool:
    """Whether a collider takes the penalty response: asked for, or `auto` on a separate boundary with APIC."""
    response = getattr(collider, "response", "projection")
    return response == "penalty" or (response == "auto" and collider.boundary == "separate" and flip == 0.0)


def collider_table(colliders, samples=None, dx: float = 0.0, flip: float = 0.0) -> np.ndarray:
    """Pack validated scene colliders into the table the kernels read (layout: engine.colliders): one header row
    each, and after a mesh collider's its signed distance samples (`samples`: collider index -> DistanceSamples).
    A penalty collider (`penalized` with the scene's FLIP share) gets its stiffness and a backstop depth of
    PENALTY_BACKSTOP cells of size `dx` [m]."""
    rows = []
    for i, c in enumerate(colliders):
        row = np.zeros(ROW)
        rows.append(row[None])
        row[15] = 1
        row[9] = -1.0 if getattr(c, "inside_out", False) else 1.0
        row[10:13] = c.velocity
        row[13] = BOUNDARY_CODES[c.boundary]
        row[14] = c.friction
        if penalized(c, flip):
            row[23], row[24] = PENALTY_BACKSTOP * dx, c.stiffness
        if c.type == "plane":
            row[0], row[1:4], row[4:7] = PLANE, c.point, _unit(c.normal)
        elif c.type == "box":
            row[0], row[1:4], row[4:7] = BOX, c.center, 0.5 * np.asarray(c.size)
        elif c.type == "sphere":
            row[0], row[1:4], row[7] = SPHERE, c.center, c.radius
        elif c.type == "cylinder":
            row[0], row[1:4], row[4:7] = CYLINDER, c.center, _unit(c.axis)
            row[7], row[8] = c.radius, 0.5 * c.height
        else:
            d = samples[i]
            data = np.zeros(-(-d.values.size // ROW) * ROW)
            data[:d.values.size] = d.values.ravel()
            rows.append(data.reshape(-1, ROW))
            row[0], row[15], row[16:19], row[19:22], row[22] = MESH, 1 + len(rows[-1]), d.values.shape, d.origin, \
                d.spacing
    return np.concatenate(rows) if rows else np.zeros((0, ROW))


def flow_speed(scene: Scene, x: np.ndarray, body) -> float:
    """Largest speed a body can be expected to reach [m/s]: its initial speed (spin included) raised by a fall from
    its highest particle to the domain's lowest point, or the colliders' or the wind's speed if larger."""
    g = np.asarray(scene.gravity, dtype=np.float64)
    centre = x.mean(axis=0) if len(x) else np.zeros(3)
    spin = np.linalg.norm(body.angular_velocity) * (np.linalg.norm(x - centre, axis=1).max() if len(x) else 0.0)
    v0 = float(np.linalg.norm(body.velocity)) + float(spin)
    if body.emitter is not None:  # born particles leave the nozzle at its velocity, from its height
        v0 = max(v0, float(np.linalg.norm(body.emitter.velocity)))
        if hasattr(body.emitter.shape, "center"):
            x = np.vstack([x, np.asarray(body.emitter.shape.center, dtype=np.float64)[None]])
    fall = 0.0
    if np.any(g) and len(x):
        down = g / np.linalg.norm(g)
        lo, hi = np.asarray(scene.grid.domain.min), np.asarray(scene.grid.domain.max)
        fall = max(0.0, float(np.where(down > 0, hi, lo) @ down - (x @ down).min()))
    speeds = [math.sqrt(v0 * v0 + 2.0 * float(np.linalg.norm(g)) * fall)]
    speeds += [float(np.linalg.norm(c.velocity)) for c in scene.colliders]
    speeds += [float(np.linalg.norm(scene.wind.velocity))] if scene.wind else []
    return max(speeds)


def fracture_params(frac, kind: str, params, horizon: float) -> FractureParams | None:
    """The body's eq. 21 threshold: as given, or from its fracture energy, P-wave modulus and horizon."""
    if frac is None:
        return None
    if frac.energy is None:
        return FractureParams(frac.threshold, 1.0 if frac.damage_resistance is None else frac.damage_resistance)
    modulus = MATERIALS[kind].constants(params)["p_wave_modulus"]
    return FractureParams(critical_stretch(frac.energy, modulus, horizon),
                          0.0 if frac.damage_resistance is None else frac.damage_resistance, frac.energy)


def body_params(scene: Scene, disc: Discretization) -> tuple[BodyParams, ...]:
    out = []
    for i, (body, (start, end)) in enumerate(zip(scene.bodies, disc.body_ranges)):
        kind = kind_of(body.material)
        params = MATERIALS[kind].params(body.material)
        if MATERIALS[kind].with_flow_speed is not None:
            params = MATERIALS[kind].with_flow_speed(params, flow_speed(scene, disc.rest_x[start:end], body))
        horizon = float(disc.body_horizon[i])
        out.append(BodyParams(
            name=body.name, kind=kind, params=params, start=start, end=end,
            spacing=float(disc.body_spacing[i]), horizon=horizon,
            fracture=fracture_params(body.fracture, kind, params, horizon)))
    return tuple(out)


def crack_bodies(scene: Scene) -> tuple[int, ...]:
    """Bodies whose cracks and notches get a second grid field (contact.cracks, engine/crack.py): those with
    `fracture` or `cutouts`, of a material that does not flow (a liquid's families are rebuilt, so its reference
    positions say nothing of where a notch now is). auto takes them where each body has its own field (or there is one body) on the CPU;
    separate asked of bodies sharing one field, or on the GPU, is refused."""
    out = tuple(i for i, b in enumerate(scene.bodies) if not MATERIALS[b.material.model].flows
                and (b.fracture is not None or getattr(b.geometry, "cutouts", None)))
    shared = len(scene.bodies) > 1 and scene.contact.mode == "shared"
    gpu = scene.simulation.backend != "cpu"
    if scene.contact.cracks == "shared" or not out:
        return ()
    if scene.contact.cracks == "auto":
        return () if shared or gpu else out
    if shared:
        raise SceneValueError("contact.cracks: separate needs a field per body (contact.mode: separate); with one "
                              "shared field set contact.cracks: shared", ("contact", "cracks"))
    if gpu:
        raise SceneValueError("contact.cracks: separate runs on the CPU backend only; run with --backend cpu, or "
                              "set contact.cracks: shared", ("contact", "cracks"))
    return out


def field_bodies(scene: Scene, cracks: tuple[int, ...]) -> list[int]:
    """The body of each grid field: one per body, then the crack side of each crack body; [] when all bodies share
    one field (one body without crack fields, or contact mode shared)."""
    n = len(scene.bodies)
    if not cracks and (n < 2 or scene.contact.mode == "shared"):
        return []
    return list(range(n)) + list(cracks)


def contact_friction(scene: Scene, cracks: tuple[int, ...] = ()) -> np.ndarray:
    """(fields, fields) Coulomb coefficients between grid fields (`field_bodies`; the two sides of a crack take
    contact.friction), or (0, 0) when all bodies share one field."""
    fb = field_bodies(scene, cracks)
    n = len(scene.bodies)
    out = np.full((n, n), scene.contact.friction)
    index = {b.name: i for i, b in enumerate(scene.bodies)}
    for pair in scene.contact.pairs:
        a, b = (index[name] for name in pair.bodies)
        out[a, b] = out[b, a] = pair.friction
    return out[np.ix_(fb, fb)]


def wave_speeds(bodies) -> np.ndarray:
    """(bodies,) each body's P-wave speed [m/s], which scales the penalty pushes of contact and colliders."""
    return np.array([MATERIALS[b.kind].constants(b.params)["wave_speed"] for b in bodies])


def contact_stiffness(scene: Scene, bodies, cracks: tuple[int, ...] = ()) -> np.ndarray:
    """(fields, fields) penalty coefficients stiffness x c^2 [m^2/s^2] (c the pair's larger P-wave speed), zero for
    the projection (contact.model projection, or auto with a FLIP share), -1 between the two sides of a crack (the
    projection, engine.contact); (0, 0) when the bodies share one field."""
    fb = field_bodies(scene, cracks)
    if not fb:
        return np.zeros((0, 0))
    sides = np.equal.outer(fb, fb) & ~np.eye(len(fb), dtype=bool)
    model = scene.contact.model
    if model == "projection" or (model == "auto" and scene.simulation.flip > 0.0):
        return np.where(sides, -1.0, 0.0)
    if scene.simulation.flip > 0.0:
        raise SceneValueError("the penalty contact runs with APIC only (simulation.flip 0): with a FLIP share two "
                              "colliding spheres gained energy (x1.2 at flip 0.95, x4 at 1); set simulation.flip: 0 "
                              "or contact.model: projection", ("contact", "model"))
    c = wave_speeds(bodies)[fb]
    # The faces of a crack lie at the rest spacing, where the penalty would already push them open: the two sides
    # of one body meet by the projection (-1: with the normal across the crack, engine.contact).
    return np.where(sides, -1.0, scene.contact.stiffness * np.maximum.outer(c, c) ** 2)


def collider_penalty(scene: Scene, bodies) -> np.ndarray:
    """(bodies,) c^2 / dx^2 of each body (c its P-wave speed) [1/s^2], which a penalty collider's stiffness scales
    (engine.colliders.penalty_at); (0,) when no collider takes the penalty."""
    flip = scene.simulation.flip
    if flip > 0.0 and any(c.response == "penalty" for c in scene.colliders):
        raise SceneValueError("a penalty collider runs with APIC only (simulation.flip 0), as the penalty contact "
                              "between bodies does; set simulation.flip: 0 or the collider's response: projection "
                              "(auto takes the projection with a FLIP share)", ("simulation", "flip"))
    if not any(penalized(c, flip) for c in scene.colliders):
        return np.zeros(0)
    return wave_speeds(bodies) ** 2 / scene.grid.cell_size**2


def emitter(scene: Scene, disc: Discretization, bodies) -> Emitter | None:
    """The last body's emitter: its layer (the body's lattice points inside the nozzle), the interval N h^3 / rate
    between layers and how many are due before the run ends. A rate the nozzle cannot pass at the given speed (a
    layer still in the nozzle when the next is due) is refused."""
    i = len(scene.bodies) - 1
    em = scene.bodies[i].emitter
    if em is None:
        return None
    h, key, layer = float(disc.body_spacing[i]), ("bodies", i, "emitter"), disc.emitter_layer
    if MATERIALS[bodies[i].kind].born is None:
        raise SceneValueError(f"material {bodies[i].kind} cannot be emitted (it has no `born` hook)", key)
    v = np.asarray(em.velocity, dtype=np.float64)
    speed = float(np.linalg.norm(v))
    along = layer @ (v / speed)
    thickness = float(along.max() - along.min()) + h
    volume = len(layer) * h**3
    interval = volume / em.rate
    if speed * interval < thickness * (1.0 - 1e-9):
        raise SceneValueError(
            f"rate {em.rate:.4g} m^3/s is more than the nozzle passes at {speed:.4g} m/s: each layer of {len(layer)} "
            f"particles ({volume:.4g} m^3, {thickness:.4g} m thick along the velocity) must leave the nozzle before "
            f"the next is due; use rate <= {volume * speed / thickness:.4g} m^3/s or a faster velocity",
            key + ("rate",))
    stop = min(em.stop if em.stop is not None else math.inf, scene.simulation.duration)
    layers = max(0, math.ceil((stop - em.start) / interval - 1e-9))
    density = bodies[i].params.density
    return Emitter(i, layer, v, interval, em.start, layers, h**3, density * h**3, disc.n_particles)


def build_model(scene: Scene, disc: Discretization) -> Model:
    n = disc.n_particles
    omega = np.zeros(n)
    kinv = np.zeros((n, 3, 3))
    single = BOND_FACTORS[0].dtype_for(scene.simulation.precision) == "f4"  # bond_wv as the State stores it
    reference_family_terms(disc.rest_x, disc.volume, disc.bond_start, disc.bond_nbr, disc.body,
                           disc.body_horizon, omega, kinv, single)
    g = scene.grid
    lo, hi = np.asarray(g.domain.min, dtype=np.float64), np.asarray(g.domain.max, dtype=np.float64)
    cells = np.ceil((hi - lo) / g.cell_size - 1e-9).astype(int)
    bodies = body_params(scene, disc)
    cracks = crack_bodies(scene)
    return Model(
        rest_x=disc.rest_x, particle_volume=disc.volume, particle_mass=disc.mass, particle_body=disc.body,
        bond_start=disc.bond_start, bond_nbr=disc.bond_nbr, particle_Kinv=kinv,
        particle_coef=calibration_coefficients(omega, disc.body, disc.body_horizon), particle_omega=omega,
        pin_mask=disc.pin_mask, pin_velocity=disc.pin_velocity, pin_stop=disc.pin_stop,
        bodies=bodies, emitter=emitter(scene, disc, bodies),
        colliders=collider_table(scene.colliders, disc.collider_samples, g.cell_size, scene.simulation.flip),
        collider_penalty=collider_penalty(scene, bodies), gravity=np.asarray(scene.gravity, dtype=np.float64),
        wind_velocity=np.asarray(scene.wind.velocity if scene.wind else (0.0, 0.0, 0.0), dtype=np.float64),
        wind_drag=scene.wind.drag if scene.wind else 0.0,
        origin=lo, dx=g.cell_size, grid_shape=tuple(int(c) + 1 for c in cells),
        wall_boundary=BOUNDARY_CODES[g.boundary], wall_friction=g.friction,
        contact_friction=contact_friction(scene, cracks), contact_stiffness=contact_stiffness(scene, bodies, cracks),
        crack_bodies=cracks, particle_cut=disc.cut,
        flip=scene.simulation.flip,
    )
