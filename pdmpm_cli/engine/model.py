"""Model (arrays fixed for a run) and State (arrays advanced every step), allocated from the Plan."""

from dataclasses import dataclass

import numba
import numpy as np

from pdmpm_cli.engine.bonds import calibration_coefficients, reference_family_terms
from pdmpm_cli.engine.colliders import BOUNDARY_CODES, collider_table
from pdmpm_cli.engine.discretize import Discretization
from pdmpm_cli.scene.schema import Scene


@dataclass
class Model:
    """Static arrays: reference configuration, families and their reference terms, materials, grid, colliders."""

    rest_x: np.ndarray
    particle_volume: np.ndarray
    particle_mass: np.ndarray
    particle_body: np.ndarray
    bond_start: np.ndarray
    bond_nbr: np.ndarray
    particle_Kinv: np.ndarray  # (n, 3, 3) inverse shape tensor, eq. 4
    particle_coef: np.ndarray  # (n,) calibration c_p = 5 / omega_p
    particle_omega: np.ndarray  # (n,) weighted volume sum_q w V_q [m^3]
    pin_mask: np.ndarray
    pin_velocity: np.ndarray
    body_ranges: list
    body_horizon: np.ndarray
    materials: list  # validated material section of each body
    colliders: np.ndarray  # (n_colliders, ROW) table, see engine.colliders
    gravity: np.ndarray
    origin: np.ndarray
    dx: float
    grid_shape: tuple[int, int, int]  # nodes per axis
    wall_boundary: int
    wall_friction: float

    @classmethod
    def build(cls, scene: Scene, disc: Discretization) -> "Model":
        n = disc.n_particles
        omega = np.zeros(n)
        kinv = np.zeros((n, 3, 3))
        reference_family_terms(disc.rest_x, disc.volume, disc.bond_start, disc.bond_nbr, disc.body,
                               disc.body_horizon, omega, kinv)
        g = scene.grid
        lo, hi = np.asarray(g.domain.min, dtype=np.float64), np.asarray(g.domain.max, dtype=np.float64)
        cells = np.ceil((hi - lo) / g.cell_size - 1e-9).astype(int)
        return cls(
            rest_x=disc.rest_x, particle_volume=disc.volume, particle_mass=disc.mass, particle_body=disc.body,
            bond_start=disc.bond_start, bond_nbr=disc.bond_nbr, particle_Kinv=kinv,
            particle_coef=calibration_coefficients(omega, disc.body, disc.body_horizon), particle_omega=omega,
            pin_mask=disc.pin_mask, pin_velocity=disc.pin_velocity, body_ranges=disc.body_ranges,
            body_horizon=disc.body_horizon, materials=[b.material for b in scene.bodies],
            colliders=collider_table(scene.colliders), gravity=np.asarray(scene.gravity, dtype=np.float64),
            origin=lo, dx=g.cell_size, grid_shape=tuple(int(c) + 1 for c in cells),
            wall_boundary=BOUNDARY_CODES[g.boundary], wall_friction=g.friction,
        )

    @property
    def n_particles(self) -> int:
        return len(self.rest_x)


@dataclass
class State:
    """Per-step arrays. Only the fields the Plan lists exist (e.g. no Fbar when no body has mu > 0)."""

    time: float
    step: int
    particle_x: np.ndarray
    particle_v: np.ndarray
    particle_C: np.ndarray  # APIC affine velocity matrix [1/s]
    particle_force: np.ndarray  # bond force f_p [N]
    particle_Fbar: np.ndarray  # (n, 3, 3), or (0, 3, 3) when no phase needs it
    grid: np.ndarray  # (nx, ny, nz, 4): mass, then momentum / velocity
    grid_private: np.ndarray  # (threads, nx, ny, nz, 4) P2G scatter targets

    @classmethod
    def allocate(cls, model: Model, disc: Discretization, need_fbar: bool) -> "State":
        n = model.n_particles
        nodes = model.grid_shape
        return cls(
            time=0.0, step=0,
            particle_x=disc.rest_x.copy(), particle_v=disc.velocity.copy(),
            particle_C=disc.velocity_gradient.copy(), particle_force=np.zeros((n, 3)),
            particle_Fbar=np.zeros((n if need_fbar else 0, 3, 3)),
            grid=np.zeros(nodes + (4,)),
            grid_private=np.zeros((numba.get_num_threads(),) + nodes + (4,)),
        )
