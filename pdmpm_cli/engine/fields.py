"""Declarations of the arrays a run allocates: where each lives (per particle, per bond, on the grid), its shape,
dtype and initial value. The engine's own features declare theirs here; a material declares its own in its module
(MaterialKind.fields). The Plan picks the declarations a scene needs; State.allocate allocates exactly those,
checkpoints carry every one that is not transient, and family rebuilds carry every per-bond one that is not
transient.

Precision (simulation.precision): with float32 the Plan stores the per-particle and per-bond float arrays in single
precision (`Field.dtype_for`), except those declared `precise`, whose values float32 would spoil. Positions: a step
moves a particle by v dt, 1e-6 to 1e-5 m, while float32 spaces values 6e-8 m apart at 0.5-1 m and 1.2e-7 m at 1-2 m,
so each step's move would be rounded by 1-10 %, and the bond vector x_q - x_p of a 2 cm bond at 2 m from the origin
would carry 6e-6 of round-off, the order of an elastic strain. 1 / |xi| (a liquid's formation length) is what a
bond's stretch |eta| / |xi| - 1 is measured from: rounded, it leaves a body at rest a strain of 3e-8 and bond forces
that are not zero. w V_q is float32, and K_p (the Model's, float64) sums the same rounded weights
(assemble.build_model), so Fbar at rest is I to float64's round-off: with both, a body at rest has float64's bond
forces (zero to round-off for a solid; the tiny cloth_pegs, whose shell regularises K_p: 5.8e-5 of a particle's
weight in both precisions, 5.4e-3 with both factors rounded). Fbar is I plus a strain of 1e-6 to 1e-3, and a
liquid's volume ratio J grows by 1e-6 of itself per step: both are kept. The grids stay float64 (P2G sums every
particle's mass and momentum into them; a float32 grid made P2G and G2P slower, docs/results.md), and kernels
compute in float64 (a float32 value is widened where it is read): float32 is a storage format, so one kernel serves
both precisions."""

from dataclasses import dataclass

import numpy as np

PARTICLE, BOND, GRID, CSR = "particle", "bond", "grid", "csr"


@dataclass(frozen=True)
class Field:
    """One array: name (`<location>_<quantity>`), location, trailing shape, dtype and initial value."""

    name: str
    where: str  # PARTICLE (n, *tail), BOND (n_bonds, *tail), GRID (shape given by the Plan) or CSR (n + 1)
    tail: tuple[int, ...] = ()
    dtype: str = "f8"
    fill: float = 0.0
    transient: bool = False  # refilled every step before it is read: neither checkpointed nor carried
    stand_in: int = 0  # rows of the stand-in (kernels that index a row they never use need 1)
    doc: str = ""
    precise: bool = False  # stays float64 with simulation.precision float32 (see the module docstring)

    def dtype_for(self, precision: str) -> str:
        """The dtype the Plan allocates: float32 for a per-particle or per-bond float array that is not `precise`
        when the scene asks for float32, the declared dtype otherwise."""
        single = precision == "float32" and self.dtype == "f8" and self.where in (PARTICLE, BOND) and not self.precise
        return "f4" if single else self.dtype

    def empty(self) -> np.ndarray:
        """The (stand_in, *tail) stand-in kernels receive when the scene does not allocate this array; kernels
        test `shape[0] > 0` (or a parameter, for stand-ins with a row) once, outside their loops."""
        return np.zeros((self.stand_in,) + self.tail, dtype=self.dtype)


# Every run.
CORE = (
    Field("particle_x", PARTICLE, (3,), precise=True, doc="position [m]"),
    Field("particle_v", PARTICLE, (3,), doc="velocity [m/s]"),
    Field("particle_C", PARTICLE, (3, 3), doc="APIC affine velocity matrix [1/s]"),
    Field("particle_force", PARTICLE, (3,), transient=True, doc="bond force f_p of the step (eqs. 2, 7) [N]"),
    Field("bond_start", CSR, dtype="i8", doc="CSR family offsets (n + 1 entries); flowing bodies rebuild them"),
    Field("bond_nbr", BOND, dtype="i4", doc="CSR family members"),
)
GRIDS = (
    Field("grid", GRID, transient=True, doc="node mass, then momentum / velocity"),
    Field("grid_private", GRID, transient=True, doc="per-thread P2G scatter targets (CPU)"),
)
# Contact between bodies (engine/contact.py): one grid velocity field per body, in place of `grid`.
CONTACT = (
    Field("grid_field", GRID, transient=True, doc="per body: node mass, then momentum / velocity"),
    Field("grid_surface", GRID, transient=True,
          doc="per body: mass gradient [kg/m] and mass-weighted offset of its particles from the node [kg m]"),
    Field("grid_surface_private", GRID, transient=True, doc="per-thread scatter targets of grid_surface (CPU)"),
)
# Crack fields (engine/crack.py, contact.cracks: separate): a body's cracks and notches split its grid field in two.
CRACK_SIDES = (
    Field("particle_crack_n", PARTICLE, (4,), transient=True,
          doc="unit direction from the particle into its crack or notch, in the reference frame [-]; 0: none "
              "(recomputed when bonds break and when a State is bound); then 1 where it is a cutout's alone"),
    Field("particle_crack_s", PARTICLE, transient=True, doc="length of the summed X_q - X_p of its broken and cut "
          "bonds [m]: the node's owner is the particle with the largest"),
    Field("particle_dust", PARTICLE, dtype="u1", transient=True,
          doc="1: a crack particle of a small piece (dust, chips), integrated off the grid as on one field"),
    Field("particle_piece", PARTICLE, dtype="i8", transient=True,
          doc="the piece of its body the particle belongs to (connected over intact bonds)"),
    Field("grid_owner", GRID, dtype="i8", fill=-1, transient=True,
          doc="per crack body: the particle whose crack plane splits the node's field; -1: the node is not split"),
)
# Reference bond factors, computed once: the Fbar pass and the pair pass read them.
BOND_FACTORS = (
    Field("bond_wv", BOND, doc="w(|xi|) V_q, eq. 4's weight times the neighbour's volume [m^3]"),
    Field("bond_inv_len", BOND, precise=True, doc="1 / |xi| [1/m]"),
)
FBAR = (Field("particle_Fbar", PARTICLE, (3, 3), transient=True, stand_in=1, precise=True,
              doc="averaged deformation gradient (eq. 4) [-]; read only where mu > 0"),) + BOND_FACTORS
# The grid's mass density at each particle, which G2P gathers from the nodes it reads anyway (a liquid's volume ratio).
GRID_DENSITY = (Field("particle_rho", PARTICLE, transient=True, precise=True,
                      doc="mass density of the step's grid at the particle, sum_i w_i m_i / dx^3 [kg/m^3]"),)
# Bond passes that evaluate each pair once and scatter (the elastic and plastic forces).
PAIR = (Field("particle_force_private", GRID, transient=True, doc="per-thread pair-force scatter targets (CPU) [N]"),
        ) + BOND_FACTORS
FRACTURE = (
    Field("bond_active", BOND, dtype="u1", fill=1, doc="1 intact, 0 broken (section 6)"),
    Field("particle_damage", PARTICLE, doc="broken / initial bonds [-]"),
    Field("particle_crack", PARTICLE, dtype="u1", doc="1: crack-surface particle, integrated off the grid"),
    Field("particle_inactive", PARTICLE, transient=True, doc="p_inactive of eq. 21 [-]"),
    Field("particle_lmax", PARTICLE, transient=True, doc="largest eq. 21 criterion over the particle's bonds [-]"),
    Field("particle_bmax", PARTICLE, dtype="i8", transient=True, doc="its bond index"),
)
# Eq. 21's bonds counted per cell into dense cell arrays (the GPU with atomics, the CPU serially).
FRACTURE_CELLS = (
    Field("cell_bonds", GRID, dtype="i8", transient=True, doc="bonds of the particles in each cell (eq. 21)"),
    Field("cell_broken", GRID, dtype="i8", transient=True, doc="broken bonds of the particles in each cell"),
)
