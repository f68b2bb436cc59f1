"""Deciding the Plan (engine.plan) of a scene: what it will run and allocate, decided once before any step.

It lists the phases of a step (a phase a scene does not need is absent, not skipped at run time), the
arrays each one needs, the time-step bounds and the counts. `pdmpm validate --explain` prints it and the
HDF5 output stores it.
"""

import math

import numba
import numpy as np

from pdmpm_cli.discretize import Discretization
from pdmpm_cli.engine import fields as F
from pdmpm_cli.engine.bonds import bond_time_steps
from pdmpm_cli.engine.contact import SURFACE
from pdmpm_cli.engine.materials import MATERIALS
from pdmpm_cli.engine.model import Model
from pdmpm_cli.engine.plan import BodyPlan, Plan
from pdmpm_cli.engine.state import shape_of
from pdmpm_cli.engine.transfer import CHANNELS, FLIP_CHANNELS
from pdmpm_cli.errors import InputError, SceneValueError
from pdmpm_cli.scene.schema import CFL, Scene

# Static arrays of the Model, listed with the State's so the Plan's inventory (and memory) is complete.
MODEL_FIELDS = {
    "rest_x": ((3,), "f8"), "particle_volume": ((), "f8"), "particle_mass": ((), "f8"), "particle_body": ((), "i4"),
    "particle_Kinv": ((3, 3), "f8"), "particle_coef": ((), "f8"), "particle_omega": ((), "f8"),
}
PIN_FIELDS = {"pin_mask": ((), "u1"), "pin_velocity": ((3,), "f8"), "pin_stop": ((), "f8")}


def state_fields(model: Model, backend: str) -> tuple[F.Field, ...]:
    """The declarations of every State array the scene needs: the core ones, then those of what it uses."""
    kinds = [MATERIALS[b.kind] for b in model.bodies]
    out = list(F.CORE + F.GRIDS)
    if len(model.contact_friction):  # a field per body replaces the one grid
        out = [f for f in out if f.name != "grid"] + list(F.CONTACT)
    if model.crack_bodies:
        out += F.CRACK_SIDES
    if any(k.uses_fbar(b.params) for k, b in zip(kinds, model.bodies)):
        out += F.FBAR
    if any(k.reads_grid_density(b.params) for k, b in zip(kinds, model.bodies)):
        out += F.GRID_DENSITY
    for kind in dict.fromkeys(kinds):
        out += kind.fields
    if any(b.fracture is not None for b in model.bodies):
        out += F.FRACTURE + F.FRACTURE_CELLS
    return tuple(dict.fromkeys(out))


def array_shapes(declared, model: Model, n_bonds: int, threads: int, precision: str = "float64") -> dict:
    """name -> (shape, dtype) of the declared arrays: per particle, per bond, or on the grid; the dtype follows
    simulation.precision (engine.fields: Field.dtype_for)."""
    n, nodes = model.n_particles, tuple(model.grid_shape)
    q = FLIP_CHANNELS if model.flip > 0.0 else CHANNELS
    grid = {
        "grid": nodes + (q,),
        "grid_private": (threads,) + nodes + (q,),  # per-thread P2G grids keep the CPU race-free (GPU: atomics)
        "grid_field": (len(model.contact_friction),) + nodes + (q,),
        "grid_surface": (len(model.contact_friction),) + nodes + (SURFACE,),
        "grid_owner": (len(model.crack_bodies),) + nodes,
        "grid_surface_private": (threads,) + nodes + (SURFACE,),
        "particle_force_private": (threads, n, 3),  # per-thread pair-force arrays (CPU)
        "cell_bonds": (math.prod(c - 1 for c in nodes),), "cell_broken": (math.prod(c - 1 for c in nodes),),
    }
    return {f.name: (shape_of(f, n, n_bonds, grid.get(f.name, ())), f.dtype_for(precision)) for f in declared}


def make_plan(scene: Scene, disc: Discretization, model: Model) -> Plan:
    """Decide phases, arrays and time-step bounds for a discretised scene."""
    sim = scene.simulation
    kinds = [MATERIALS[b.kind] for b in model.bodies]
    consts = [k.constants(b.params) for k, b in zip(kinds, model.bodies)]
    need_fbar = any(k.uses_fbar(b.params) for k, b in zip(kinds, model.bodies))
    fracture = any(b.fracture is not None for b in model.bodies)
    modulus = np.array([c["p_wave_modulus"] for c in consts])
    density = np.array([b.params.density for b in model.bodies])
    dt_p = np.empty(disc.n_particles)
    bond_time_steps(disc.rest_x, disc.volume, disc.bond_start, disc.bond_nbr, disc.body, disc.body_horizon,
                    modulus, density, model.particle_coef, dt_p)
    bodies = []
    for i, (b, c) in enumerate(zip(model.bodies, consts)):
        bodies.append(BodyPlan(
            name=b.name, model=b.kind, particles=b.end - b.start,
            bonds=int(disc.bond_start[b.end] - disc.bond_start[b.start]), spacing=b.spacing, horizon=b.horizon,
            effective=c, dt_bond=float(dt_p[b.start:b.end].min()) if b.end > b.start else math.inf,
            fracture_threshold=b.fracture.threshold if b.fracture else None,
            fracture_energy=b.fracture.energy if b.fracture else None,
            damage_resistance=b.fracture.damage_resistance if b.fracture else None,
            crack_fields=i in model.crack_bodies))
    wave = max(b.effective["wave_speed"] for b in bodies)
    dt_cfl = (CFL[sim.step] if sim.cfl is None else sim.cfl) * scene.grid.cell_size / wave
    # Grid-integrated particles move with B-spline grid velocities, which do not carry the particle-scale modes
    # dt_bond protects (stable to 1.4-2 dx / c, 3.7-13x dt_bond); crack particles integrate their own bonds, so
    # `auto` keeps the bond bound for fracture bodies only. `conservative` keeps it for all (docs/method.md,
    # 'Time step').
    bonded = [b for b, m in zip(bodies, model.bodies) if sim.step == "conservative" or m.fracture is not None]
    dt_bond = sim.bond_safety * min((b.dt_bond for b in bonded), default=math.inf)
    frame_dt = 1.0 / sim.fps
    bounds = {"cfl": dt_cfl, "bonds": dt_bond, "frame": frame_dt}
    binding = min(bounds, key=bounds.get)
    dt_max = bounds[binding]
    reduced = sim.dt is not None and sim.dt > dt_max * (1 + 1e-12)
    if sim.dt is not None and sim.dt < dt_max:
        dt_max, binding = sim.dt, "user"
    used = list(dict.fromkeys(kinds))
    phases = ["fbar"] if need_fbar else []
    for hook in ("before_forces", "forces", "after_forces"):  # each named by its function: dilatation:plastic
        phases += [f"{getattr(k, hook).__name__}:{k.name}" for k in used if getattr(k, hook) is not None]
    if model.collider_penalty.size:  # penalty colliders push the particles that touch them (engine.colliders)
        phases.append("collider_penalty")
    if model.emitter is not None:  # births after the force hooks (engine.emitter)
        phases.append("emit")
    # Crack particles meet the grid's material after its update and before intact particles read it back.
    contact = len(model.contact_friction) > 0
    remap = model.flip > 0.0
    moved = [k for k in used if k.after_move is not None
             and any(k.moves(b.params) for kb, b in zip(kinds, model.bodies) if kb is k)]  # e.g. shift:viscoelastic
    phases += ["p2g", "grid_update", *(["contact"] if contact else []), *(["crack"] if fracture else []), "g2p",
               *(["remap"] if remap else []), *(f"{k.after_move.__name__}:{k.name}" for k in moved),
               *(["fracture"] if fracture else [])]
    threads = numba.get_num_threads() if sim.backend == "cpu" else 0
    n, nb = disc.n_particles, disc.n_bonds
    fields = array_shapes(state_fields(model, sim.backend), model, nb, threads, sim.precision)
    fields.update({name: ((n,) + tail, dt) for name, (tail, dt) in MODEL_FIELDS.items()})
    if len(disc.pin_mask):
        fields.update({name: ((n,) + tail, dt) for name, (tail, dt) in PIN_FIELDS.items()})
    emitted = model.emitter.particles if model.emitter is not None else 0
    if emitted and sim.backend != "cpu":
        raise InputError("an emitter runs on the CPU backend only (its births grow the arrays on the host); run with "
                         "--backend cpu, or remove the emitter")
    clamped = [i for i, c in enumerate(scene.colliders) if c.boundary == "clamped"]
    if clamped and sim.backend != "cpu":
        raise SceneValueError("boundary clamped runs on the CPU backend only (its mirror pass after the grid update "
                              "is not on the GPU); run with --backend cpu, or use boundary: sticky",
                              ("colliders", clamped[0], "boundary"))
    if emitted and scene.output.usd:
        raise InputError("output.usd cannot hold a particle count that changes between frames yet; an emitter "
                         "scene writes run.h5, VTK and PLY: set output.usd: false")
    # Arrays grow with the births: the memory is the one at the final count (particle and bond arrays scaled).
    scale = (n + emitted) / n if n else 1.0
    memory = sum(int(np.prod(shape) * (scale if shape and shape[0] in (n, n + 1, nb) else 1.0))
                 * np.dtype(dt).itemsize for shape, dt in fields.values())
    return Plan(
        phases=tuple(phases), fields=fields, bodies=tuple(bodies), particles=n, bonds=nb,
        grid_nodes=tuple(model.grid_shape), cell_size=scene.grid.cell_size,
        frames=max(1, int(round(sim.duration * sim.fps))), frame_dt=frame_dt, dt_user=sim.dt,
        step=sim.step, dt_cfl=dt_cfl, dt_bond=dt_bond, dt_max=dt_max, binding=binding, dt_reduced=reduced,
        wave_speed=wave,
        memory_bytes=memory, notes=tuple(disc.notes), backend=sim.backend, fbar=need_fbar, fracture=fracture,
        contact=contact, remap=remap, emitted=emitted, precision=sim.precision,
    )
