"""Emitter: particles born over time from a nozzle, a layer at a time, joining the last body.

A layer is the body's lattice points inside the nozzle (N points of volume h^3); layer k is due at start + k T with
T = N h^3 / rate, so the emitted volume is rate x time at every layer's time, by construction. Births run on the
host after a step's force hooks (where the viscoelastic material rebuilds its families: the positions the bonds
measure from, particle_x_prev, equal particle_x there), so a layer due during the step is born then, at the nozzle
point advanced by v (t - t_k), and the step's P2G and G2P carry it along. Each layer is the nozzle's lattice turned
by one more golden angle about the stream's axis.

Arrays grow with each layer (exact sizes, reallocated on the host): every kernel, diagnostic and writer takes its
count from the arrays, so nothing else needs an active count. Born particles are appended: the emitting body is the
last one, and its range end moves. The Model's per-particle arrays grow the same way and depend only on the number
of layers born (rest position: the nozzle point), so a checkpoint needs only the State and its `emitted` count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pdmpm_cli.engine.fields import CSR, PARTICLE
from pdmpm_cli.engine.materials import MATERIALS
from pdmpm_cli.engine.model import Model

TIME_TOLERANCE = 1e-9  # a layer due within this fraction of the interval after the step's start is born with it
GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))  # [rad] turn of each layer about the stream's axis


@dataclass(frozen=True)
class Emitter:
    body: int  # index of the emitting body (the last)
    layer: np.ndarray  # (N, 3) nozzle points of one layer [m]
    velocity: np.ndarray  # (3,) [m/s]
    interval: float  # T = N h^3 / rate between layers [s]
    start: float  # time of layer 0 [s]
    layers: int  # layers born over the run
    volume: float  # h^3 [m^3]
    mass: float  # rho h^3 [kg]
    first: int  # particles before the first born one (the initial count)

    def points(self, k: int) -> np.ndarray:
        """Nozzle points of layer k: the layer turned by k golden angles about the stream's axis through its centre.
        The turn keeps each layer's spacing and volume; without it every stream line would sit on the same lattice
        column, and the pile would spread in fingers along the lattice directions."""
        axis = self.velocity / np.linalg.norm(self.velocity)
        c = self.layer.mean(axis=0)
        r = self.layer - c
        a = k * GOLDEN_ANGLE
        cross = np.cross(axis, r)
        return c + r * math.cos(a) + cross * math.sin(a) + np.outer(r @ axis, axis) * (1.0 - math.cos(a))

    @property
    def particles(self) -> int:
        """Particles born over the run."""
        return self.layers * len(self.layer)

    def due(self, time: float) -> int:
        """Layers due by `time` [s] (layer k at start + k T)."""
        if time < self.start - TIME_TOLERANCE * self.interval:
            return 0
        return min(self.layers, int(np.floor((time - self.start) / self.interval + TIME_TOLERANCE)) + 1)


def grown(model: Model, layers: int) -> Model:
    """The Model with `layers` more layers of born particles appended to its emitting body: rest position the nozzle
    point, volume h^3, mass rho h^3, no reference family (a flowing body's State carries its own families), and the
    Fbar and calibration terms zero (viscoelastic bodies read neither)."""
    em = model.emitter
    k = layers * len(em.layer)
    if k == 0:
        return model
    n = model.n_particles
    k0 = (n - em.first) // len(em.layer)

    def more(a, fill=0):
        return np.concatenate([a, np.full((k,) + a.shape[1:], fill, dtype=a.dtype)])

    bodies = list(model.bodies)
    bodies[em.body] = replace(bodies[em.body], end=bodies[em.body].end + k)
    extra = {}
    if len(model.pin_mask):
        extra = {"pin_mask": more(model.pin_mask), "pin_velocity": more(model.pin_velocity),
                 "pin_stop": more(model.pin_stop, np.inf)}
    if len(model.particle_cut):
        extra["particle_cut"] = more(model.particle_cut)
    return replace(
        model, rest_x=np.concatenate([model.rest_x, *(em.points(k0 + j) for j in range(layers))]),
        particle_volume=more(model.particle_volume, em.volume), particle_mass=more(model.particle_mass, em.mass),
        particle_body=more(model.particle_body, em.body),
        bond_start=np.concatenate([model.bond_start, np.full(k, model.bond_start[n], dtype=model.bond_start.dtype)]),
        particle_Kinv=more(model.particle_Kinv), particle_coef=more(model.particle_coef),
        particle_omega=more(model.particle_omega), bodies=tuple(bodies), **extra)


def grow_state(state, first: int, k: int) -> None:
    """Append k particles to every per-particle array of the State (their declared fill; families empty)."""
    for name, a in list(state.arrays.items()):
        where = state.declared[name].where
        if where == PARTICLE:
            f = state.declared[name]
            setattr(state, name, np.concatenate([a, np.full((k,) + a.shape[1:], f.fill, dtype=a.dtype)]))
        elif where == CSR:
            setattr(state, name, np.concatenate([a, np.full(k, a[first], dtype=a.dtype)]))


def grow(solver, state, layers: int) -> int:
    """Append `layers` layers to the solver's Model and State (fill values, nozzle rest positions); returns the
    index of the first new particle. The caller binds the solver to the State afterwards."""
    first = solver.model.n_particles
    solver.model = grown(solver.model, layers)
    grow_state(state, first, solver.model.n_particles - first)
    return first


def emit(solver, state) -> None:
    """The layers due by state.time (the start of the step whose forces were just evaluated): positions (the nozzle
    points moved on by v since each layer was due), velocity, the material's `born` hook (its families with the
    particles around), and the energy budget of the blow-up check raised by what the born particles bring and can
    gain (their kinetic energy, a fall over the domain). Then the solver is bound to the grown State."""
    em = solver.model.emitter
    k0 = state.emitted
    k1 = em.due(state.time)
    if k1 <= k0:
        return
    solver.sync(state)
    first = grow(solver, state, k1 - k0)
    n_layer = len(em.layer)
    for j, k in enumerate(range(k0, k1)):
        lag = state.time - (em.start + k * em.interval)
        rows = slice(first + j * n_layer, first + (j + 1) * n_layer)
        state.particle_x[rows] = em.points(k) + lag * em.velocity
        state.particle_v[rows] = em.velocity
    state.emitted = k1
    m = solver.model
    kind = MATERIALS[m.bodies[em.body].kind]
    kind.born(solver, state, em.body, first)
    extent = float(np.max(np.asarray(m.grid_shape) - 1) * m.dx)
    born = slice(first, m.n_particles)
    mass = m.particle_mass[born]
    state.energy_budget += float(mass.sum()) * (0.5 * float(em.velocity @ em.velocity) + np.linalg.norm(m.gravity)
                                                * extent)
    solver.bind(state)
