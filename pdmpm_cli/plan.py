"""The Plan: what a scene will run and allocate, decided once before any step.

It lists the phases of a step (a phase a scene does not need is absent, not skipped at run time), the
arrays each one needs, the time-step bounds and the counts. `pdmpm validate --explain` prints it and the
HDF5 output stores it.
"""

import math
from dataclasses import asdict, dataclass

import numba
import numpy as np

from pdmpm_cli.engine.bonds import bond_time_steps
from pdmpm_cli.engine.discretize import Discretization
from pdmpm_cli.engine.materials import MATERIALS, kind_of
from pdmpm_cli.engine.model import Model
from pdmpm_cli.errors import InputError
from pdmpm_cli.scene.schema import Scene


@dataclass(frozen=True)
class BodyPlan:
    name: str
    model: str  # registry entry the body runs (a plastic body that cannot yield runs as elastic)
    particles: int
    bonds: int
    spacing: float  # h [m]
    horizon: float  # delta [m]
    effective: dict  # effective isotropic constants of the calibration [Pa, -, m/s]
    dt_bond: float  # bond bound, before the safety factor [s]


@dataclass(frozen=True)
class Plan:
    phases: tuple[str, ...]
    fields: dict  # name -> (shape, dtype) of every per-particle, per-bond or grid array the run allocates
    bodies: tuple[BodyPlan, ...]
    particles: int
    bonds: int
    grid_nodes: tuple[int, int, int]
    cell_size: float
    frames: int
    frame_dt: float
    dt_user: float | None
    dt_cfl: float  # cfl dx / wave speed, at rest [s]
    dt_bond: float  # bond_safety * min over particles of the bond bound [s]
    dt_max: float  # the largest step the solver will take [s]
    binding: str  # which bound sets dt_max: user, cfl, bonds or frame
    dt_reduced: bool  # the user's dt was above a bound and was reduced
    wave_speed: float  # fastest P-wave speed over bodies [m/s]
    memory_bytes: int
    notes: tuple[str, ...] = ()  # what loading changed in the input (a flipped mesh, welded vertices)
    backend: str = "cpu"  # simulation.backend: cpu or cuda

    def to_dict(self) -> dict:
        return asdict(self)

    def warnings(self) -> list[str]:
        out = list(self.notes)
        if self.dt_reduced:
            out.append(f"simulation.dt = {self.dt_user:.3g} s is above the stability bound; using {self.dt_max:.3g} s "
                       f"(CFL bound {self.dt_cfl:.3g} s, bond bound {self.dt_bond:.3g} s)")
        return out


def cuda_unsupported(scene: Scene) -> list[str]:
    """What in the scene the CUDA backend does not run (fracture with its crack particles, viscoelastic bodies)."""
    out = []
    for i, body in enumerate(scene.bodies):
        if body.material.model == "viscoelastic":
            out.append(f"bodies.{i}.material.model = viscoelastic")
        if body.fracture is not None:
            out.append(f"bodies.{i}.fracture")
    return out


def make_plan(scene: Scene, disc: Discretization, model: Model) -> Plan:
    """Decide phases, arrays and time-step bounds for a discretised scene."""
    sim = scene.simulation
    if sim.backend == "cuda" and (unsupported := cuda_unsupported(scene)):
        raise InputError(f"simulation.backend = cuda does not run {', '.join(unsupported)} (the GPU step has no "
                         f"fracture and no viscoelastic bodies yet); use the cpu backend for this scene "
                         f"(simulation.backend: cpu, or pdmpm run --backend cpu)")
    mats = [b.material for b in scene.bodies]
    kinds = [kind_of(m) for m in mats]
    need_fbar = any(MATERIALS[k].needs_fbar(m) for k, m in zip(kinds, mats))
    fracture = any(b.fracture is not None for b in scene.bodies)
    modulus = np.array([m.lam + 2 * m.mu for m in mats])
    density = np.array([m.density for m in mats])
    dt_p = np.empty(disc.n_particles)
    bond_time_steps(disc.rest_x, disc.volume, disc.bond_start, disc.bond_nbr, disc.body, disc.body_horizon,
                    modulus, density, model.particle_coef, dt_p)
    bodies = []
    for i, (body, (s, e)) in enumerate(zip(scene.bodies, disc.body_ranges)):
        m = body.material
        bodies.append(BodyPlan(
            name=body.name, model=kinds[i], particles=e - s,
            bonds=int(disc.bond_start[e] - disc.bond_start[s]),
            spacing=float(disc.body_spacing[i]), horizon=float(disc.body_horizon[i]),
            effective=MATERIALS[kinds[i]].effective_constants(m.lam, m.mu, m.density),
            dt_bond=float(dt_p[s:e].min()) if e > s else math.inf,
        ))
    wave = max(b.effective["wave_speed"] for b in bodies)
    dt_cfl = sim.cfl * scene.grid.cell_size / wave
    # The step stays 4.5-30x below the predicted stability limit (engine.spectrum, `validate --limits`): the bond
    # bound is kept as an accuracy control, since the CFL step alone (about 3x larger) costs accuracy the
    # verification tests guard (docs/method.md, 'Time step').
    dt_bond = sim.bond_safety * min(b.dt_bond for b in bodies)
    frame_dt = 1.0 / sim.fps
    bounds = {"cfl": dt_cfl, "bonds": dt_bond, "frame": frame_dt}
    binding = min(bounds, key=bounds.get)
    dt_max = bounds[binding]
    reduced = sim.dt is not None and sim.dt > dt_max * (1 + 1e-12)
    if sim.dt is not None and sim.dt < dt_max:
        dt_max, binding = sim.dt, "user"
    used = list(dict.fromkeys(kinds))
    phases = ["fbar"] if need_fbar else []
    for stage in ("return_map", "bonds", "families"):
        phases += [f"{stage}:{k}" for k in used if stage in MATERIALS[k].phases]
    # Crack particles meet the grid's material after its update and before intact particles read it back.
    phases += ["p2g", "grid_update", *(["crack"] if fracture else []), "g2p", *(["fracture"] if fracture else [])]
    n, nb, nodes = disc.n_particles, disc.n_bonds, model.grid_shape
    threads = numba.get_num_threads() if sim.backend == "cpu" else 0  # per-thread scatter targets (CPU only)
    fields = {
        "particle_x": ((n, 3), "f8"), "particle_v": ((n, 3), "f8"), "particle_C": ((n, 3, 3), "f8"),
        "particle_force": ((n, 3), "f8"), "rest_x": ((n, 3), "f8"), "particle_volume": ((n,), "f8"),
        "particle_mass": ((n,), "f8"), "particle_body": ((n,), "i4"), "particle_Kinv": ((n, 3, 3), "f8"),
        "particle_coef": ((n,), "f8"), "particle_omega": ((n,), "f8"),
        "bond_start": ((n + 1,), "i8"), "bond_nbr": ((nb,), "i4"),
        # Per-thread P2G grids keep the CPU race-free; the GPU adds into the one grid with atomics.
        "grid": (nodes + (4,), "f8"),
        "grid_private": ((threads,) + nodes + (4,), "f8"),
    }
    pair_forces = any(MATERIALS[k].pair_forces for k in used)
    if pair_forces:  # the elastic pair forces scatter into one force array per thread (CPU)
        fields["particle_force_private"] = ((threads, n, 3), "f8")
    if pair_forces or need_fbar:  # reference bond factors, computed once
        fields["bond_wv"] = ((nb,), "f8")
        fields["bond_inv_len"] = ((nb,), "f8")
    if need_fbar:
        fields["particle_Fbar"] = ((n, 3, 3), "f8")
    for k in used:
        fields.update({name: ((nb,), dt) for name, dt in MATERIALS[k].bond_fields.items()})
        fields.update({name: ((n,) + tail, dt) for name, (tail, dt) in MATERIALS[k].particle_fields.items()})
    if fracture:
        fields.update({
            "bond_active": ((nb,), "u1"), "particle_damage": ((n,), "f8"), "particle_crack": ((n,), "u1"),
            "particle_inactive": ((n,), "f8"), "particle_lmax": ((n,), "f8"), "particle_bmax": ((n,), "i8"),
        })
    if len(disc.pin_mask):
        fields["pin_mask"] = ((n,), "u1")
        fields["pin_velocity"] = ((n, 3), "f8")
        fields["pin_stop"] = ((n,), "f8")
    memory = sum(int(np.prod(shape)) * np.dtype(dt).itemsize for shape, dt in fields.values())
    return Plan(
        phases=tuple(phases), fields=fields, bodies=tuple(bodies), particles=n, bonds=nb,
        grid_nodes=nodes, cell_size=scene.grid.cell_size,
        frames=max(1, int(round(sim.duration * sim.fps))), frame_dt=frame_dt, dt_user=sim.dt,
        dt_cfl=dt_cfl, dt_bond=dt_bond, dt_max=dt_max, binding=binding, dt_reduced=reduced, wave_speed=wave,
        memory_bytes=memory,
        notes=tuple(disc.notes), backend=sim.backend,
    )
