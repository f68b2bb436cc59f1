"""Model: what is fixed for a run. The reference configuration and families with their reference terms, each body's
typed parameters, the grid, walls and colliders. Built from a scene by pdmpm_cli.assemble; the engine never sees the
scene itself."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class FractureParams:
    threshold: float  # critical bond strain of eq. 21 [-]
    damage_resistance: float  # weight k of p_inactive in eq. 21 [-]
    energy: float | None = None  # fracture energy G_c the threshold was derived from [J/m^2]; None: given directly


@dataclass(frozen=True)
class BodyParams:
    """One body: its particle range, its material (registry entry and that material's typed parameters)."""

    name: str
    kind: str  # registry entry the body runs
    params: Any  # the material's own frozen parameter dataclass
    start: int
    end: int
    spacing: float  # particle spacing h [m]
    horizon: float  # delta [m]
    fracture: FractureParams | None = None


@dataclass
class Model:
    """Static arrays and settings."""

    rest_x: np.ndarray
    particle_volume: np.ndarray
    particle_mass: np.ndarray
    particle_body: np.ndarray
    bond_start: np.ndarray  # reference families (a flowing body's State carries its own)
    bond_nbr: np.ndarray
    particle_Kinv: np.ndarray  # (n, 3, 3) inverse shape tensor, eq. 4
    particle_coef: np.ndarray  # (n,) calibration c_p = 5 / omega_p
    particle_omega: np.ndarray  # (n,) weighted volume sum_q w V_q [m^3]
    pin_mask: np.ndarray  # (n,) bool, or (0,) without pins
    pin_velocity: np.ndarray  # (n, 3) [m/s], or (0, 3)
    pin_stop: np.ndarray  # (n,) time each pin stops [s] (inf: never), or (0,)
    bodies: tuple[BodyParams, ...]
    colliders: np.ndarray  # (rows, ROW) packed table: header rows and mesh samples, see engine.colliders
    gravity: np.ndarray  # (3,) [m/s^2]
    wind_velocity: np.ndarray  # (3,) [m/s]
    wind_drag: float  # [1/s], 0 without wind
    origin: np.ndarray  # (3,) lowest node [m]
    dx: float  # cell size [m]
    grid_shape: tuple[int, int, int]  # nodes per axis
    wall_boundary: int  # colliders.STICKY, SLIP or SEPARATE
    wall_friction: float
    contact_friction: np.ndarray  # (fields, fields) Coulomb coefficients of contact between grid fields [-]: one
    # field per body, then the crack side of each of crack_bodies; (0, 0): the bodies share one grid field
    contact_stiffness: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # (fields, fields) penalty
    # coefficients [m^2/s^2]; 0 for a pair: the projection, -1 the projection between a crack's sides (engine.contact)
    collider_penalty: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (bodies,) c^2 / dx^2 [1/s^2], which
    # a penalty collider's stiffness scales; (0,) without a penalty collider (engine.colliders.penalties)
    crack_bodies: tuple[int, ...] = ()  # bodies whose cracks and notches split their field in two (engine.crack)
    particle_cut: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))  # (n, 4) sum of X_q - X_p over the
    # bonds cutouts removed, those to the material they removed included [m], and their count (fractional: the
    # removed material counts in eighths; discretize.cut_bonds_through); (0, 4) without cutouts
    emitter: Any = None  # engine.emitter.Emitter of the last body, or None
    flip: float = 0.0  # FLIP share of the G2P update [-]; 0: APIC alone, > 0: FLIP grid and MUSL (transfer.advect_at)

    @property
    def final(self) -> Model:
        """The Model with every particle an emitter will bear over the run (itself without an emitter)."""
        if self.emitter is None:
            return self
        from pdmpm_cli.engine.emitter import grown

        return grown(self, self.emitter.layers)

    @property
    def n_particles(self) -> int:
        return len(self.rest_x)

    @property
    def body_ranges(self) -> list[tuple[int, int]]:
        return [(b.start, b.end) for b in self.bodies]

    @property
    def body_horizon(self) -> np.ndarray:
        return np.array([b.horizon for b in self.bodies])

    @property
    def body_spacing(self) -> np.ndarray:
        return np.array([b.spacing for b in self.bodies])

    @property
    def materials(self) -> list:
        """Each body's typed material parameters."""
        return [b.params for b in self.bodies]

    @property
    def fracture(self) -> list:
        return [b.fracture for b in self.bodies]
