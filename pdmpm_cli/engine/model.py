"""Model (arrays fixed for a run) and State (arrays advanced every step), allocated from the Plan."""

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from pdmpm_cli.engine.bonds import bond_reference_terms, calibration_coefficients, reference_family_terms
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
    pin_velocity: np.ndarray  # (n, 3) [m/s], or (0, 3)
    pin_stop: np.ndarray  # (n,) time each pin stops [s] (inf: never), or (0,)
    body_ranges: list
    body_horizon: np.ndarray
    body_spacing: np.ndarray  # particle spacing h of each body [m]
    materials: list  # validated material section of each body
    fracture: list  # validated fracture section of each body, or None
    colliders: np.ndarray  # (n_colliders, ROW) table, see engine.colliders
    gravity: np.ndarray
    wind_velocity: np.ndarray  # (3,) [m/s]
    wind_drag: float  # [1/s], 0 without wind
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
            pin_mask=disc.pin_mask, pin_velocity=disc.pin_velocity, pin_stop=disc.pin_stop,
            body_ranges=disc.body_ranges,
            body_horizon=disc.body_horizon, body_spacing=disc.body_spacing, materials=[b.material for b in scene.bodies],
            fracture=[b.fracture for b in scene.bodies],
            colliders=collider_table(scene.colliders), gravity=np.asarray(scene.gravity, dtype=np.float64),
            wind_velocity=np.asarray(scene.wind.velocity if scene.wind else (0.0, 0.0, 0.0), dtype=np.float64),
            wind_drag=scene.wind.drag if scene.wind else 0.0,
            origin=lo, dx=g.cell_size, grid_shape=tuple(int(c) + 1 for c in cells),
            wall_boundary=BOUNDARY_CODES[g.boundary], wall_friction=g.friction,
        )

    @property
    def n_particles(self) -> int:
        return len(self.rest_x)


def _empty(*shape, dtype="f8"):
    return field(default_factory=lambda: np.zeros((0,) + shape, dtype=dtype))


@dataclass
class State:
    """Per-step arrays. Optional ones exist (non-empty) only when the Plan lists them: a scene without
    plasticity has an empty bond_ep, one without fracture an empty bond_active, and so on. Kernels test
    `array.shape[0] > 0` once, outside their loops."""

    time: float
    step: int
    particle_x: np.ndarray
    particle_v: np.ndarray
    particle_C: np.ndarray  # APIC affine velocity matrix [1/s]
    particle_force: np.ndarray  # bond force f_p [N]
    grid: np.ndarray  # (nx, ny, nz, 4): mass, then momentum / velocity
    grid_private: np.ndarray  # (threads, nx, ny, nz, 4) P2G scatter targets
    bond_start: np.ndarray  # CSR families: the Model's, replaced when viscoelastic families are rebuilt
    bond_nbr: np.ndarray
    particle_Fbar: np.ndarray = _empty(3, 3)  # eq. 4
    particle_force_private: np.ndarray = _empty(0, 3)  # (threads, n, 3) scatter targets of the elastic pair forces
    bond_wv: np.ndarray = _empty()  # w(|xi|) V_q per bond (eq. 4), for Fbar and the elastic forces [m^3]
    bond_inv_len: np.ndarray = _empty()  # 1 / |xi| per bond [1/m]
    bond_ep: np.ndarray = _empty()  # plastic strain per bond (eq. 9) [-]
    particle_theta: np.ndarray = _empty()  # dilatation for e_iso (eq. 9) [-]
    bond_active: np.ndarray = _empty(dtype="u1")  # 1 intact, 0 broken (section 6)
    particle_damage: np.ndarray = _empty()  # broken / initial bonds [-]
    particle_crack: np.ndarray = _empty(dtype="u1")  # 1: crack-surface particle, integrated off the grid
    particle_inactive: np.ndarray = _empty()  # p_inactive of eq. 21 [-]
    particle_lmax: np.ndarray = _empty()  # largest eq. 21 criterion over the particle's bonds [-]
    particle_bmax: np.ndarray = _empty(dtype="i8")  # its bond index
    bond_len0: np.ndarray = _empty()  # viscoelastic: formation length of each bond [m] (< 0: broken)
    bond_force_el: np.ndarray = _empty()  # viscoelastic: non-relaxing pair force [N/m^6]
    bond_force_visc: np.ndarray = _empty()  # viscoelastic: relaxing pair force [N/m^6]
    particle_m: np.ndarray = _empty()  # viscoelastic: LPS weighted volume [m^5]
    particle_dtheta: np.ndarray = _empty()  # viscoelastic: incremental dilatation of the step [-]
    particle_x_prev: np.ndarray = _empty(3)  # viscoelastic: positions at the previous force evaluation [m]
    particle_x_rebuild: np.ndarray = _empty(3)  # viscoelastic: positions at the last family rebuild [m]
    dt_prev: float = 0.0  # length of the previous step [s] (0 before the first)

    @classmethod
    def allocate(cls, model: Model, disc: Discretization, fields: dict) -> "State":
        """Allocate the state arrays the Plan's `fields` list, with their initial values."""
        state = cls(
            time=0.0, step=0,
            particle_x=disc.rest_x.copy(), particle_v=disc.velocity.copy(),
            particle_C=disc.velocity_gradient.copy(), particle_force=np.zeros((model.n_particles, 3)),
            grid=np.zeros(fields["grid"][0]), grid_private=np.zeros(fields["grid_private"][0]),
            bond_start=model.bond_start, bond_nbr=model.bond_nbr,
        )
        optional = {f.name for f in dataclasses.fields(cls) if f.default_factory is not dataclasses.MISSING}
        for name, (shape, dtype) in fields.items():
            if name in optional:
                setattr(state, name, np.zeros(shape, dtype=dtype))
        if len(state.bond_wv):
            bond_reference_terms(model.rest_x, model.particle_volume, model.bond_start, model.bond_nbr,
                                 model.particle_body, model.body_horizon, state.bond_wv, state.bond_inv_len)
        if len(state.bond_active):
            state.bond_active[:] = 1
        if len(state.particle_x_prev):
            state.particle_x_prev[:] = state.particle_x
            state.particle_x_rebuild[:] = state.particle_x
        return state
