"""State: everything a step changes, arrays and scalars, so that a checkpoint is the State and nothing else."""

from __future__ import annotations

import numpy as np

from pdmpm_cli.engine.fields import BOND, CSR, GRID, Field

# Scalars that evolve with the run (besides the arrays): a checkpoint stores them all.
SCALARS = {
    "time": 0.0,  # [s]
    "step": 0,
    "dt_prev": 0.0,  # length of the previous step [s] (0 before the first)
    "vmax": 0.0,  # largest particle speed after the last step [m/s]: the next step's CFL bound
    "energy_budget": 0.0,  # what gravity, colliders, pins, wind and the initial motion can supply [J]
    "energy_prev": 0.0,  # kinetic + strain energy at the previous frame [J]
    "yield_residual": -1.0,  # largest f / psi_p after any return map so far (0: exactly on the surface)
    "bonds_cut": 0,  # bonds removed by fracture planes so far
    "emitted": 0,  # layers an emitter has born so far (engine.emitter)
}


class State:
    """Per-step arrays by name (`state.particle_x`) and the evolving scalars.

    Only the arrays the Plan lists exist; any other declared array reads as its empty stand-in (shape (0, ...)),
    which kernels test once, outside their loops: a scene without plasticity has an empty bond_ep, one without
    fracture an empty bond_active, and so on."""

    def __init__(self, declared: dict[str, Field], arrays: dict[str, np.ndarray], **scalars):
        object.__setattr__(self, "declared", declared)
        object.__setattr__(self, "arrays", arrays)
        for name, default in SCALARS.items():
            object.__setattr__(self, name, type(default)(scalars.get(name, default)))

    def __getattr__(self, name):
        arrays, declared = self.__dict__.get("arrays", {}), self.__dict__.get("declared", {})
        if name in arrays:
            return arrays[name]
        if name in declared:
            return declared[name].empty()
        raise AttributeError(f"State has no array or scalar '{name}'")

    def __setattr__(self, name, value):
        if name in SCALARS:
            object.__setattr__(self, name, value)
        elif name in self.arrays or name in self.declared:
            self.arrays[name] = value
        else:
            raise AttributeError(f"State has no array or scalar '{name}'")

    def has(self, name: str) -> bool:
        return name in self.arrays

    @property
    def scalars(self) -> dict:
        return {name: getattr(self, name) for name in SCALARS}

    def lasting(self) -> dict[str, np.ndarray]:
        """The arrays a checkpoint stores: all but the transient ones."""
        return {n: a for n, a in self.arrays.items() if not self.declared[n].transient}

    def bond_arrays(self) -> dict[str, np.ndarray]:
        """Every allocated per-bond array except the families themselves: what a family rebuild carries along (the
        transient ones only resized) and what the CUDA backend copies down and back around it."""
        return {n: a for n, a in self.arrays.items() if self.declared[n].where == BOND and n != "bond_nbr"}

    def fit_transient_bonds(self):
        """Reallocate the transient per-bond arrays to the families' size (after a rebuild or a restore changed it):
        they are refilled before they are read, so only their length matters."""
        for name, array in self.bond_arrays().items():
            if self.declared[name].transient and len(array) != len(self.bond_nbr):
                self.arrays[name] = np.empty((len(self.bond_nbr),) + array.shape[1:], array.dtype)

    def copy(self) -> State:
        return State(self.declared, {n: a.copy() for n, a in self.arrays.items()}, **self.scalars)

    def __deepcopy__(self, memo) -> State:
        return self.copy()

    @classmethod
    def allocate(cls, fields: dict[str, Field], specs: dict[str, tuple[tuple, str]], initial: dict[str, np.ndarray]
                 ) -> State:
        """Allocate the Plan's arrays: `specs` gives each one's full shape and dtype (the Plan's `fields`, whose
        dtypes follow simulation.precision), `initial` the values of some (positions, velocities, the families); the
        rest start at their declared fill value."""
        arrays = {}
        for name, (shape, dtype) in specs.items():
            f = fields[name]
            if name in initial:
                arrays[name] = np.array(initial[name], dtype=dtype, copy=True).reshape(shape)
            else:
                arrays[name] = np.full(shape, f.fill, dtype=dtype)
        return cls(fields, arrays)


def shape_of(f: Field, n: int, n_bonds: int, grid: tuple = ()) -> tuple:
    """The full shape of a declared array for n particles and n_bonds bonds (grid arrays: the given shape)."""
    if f.where == GRID:
        return tuple(grid)
    if f.where == CSR:
        return (n + 1,)
    return ((n_bonds if f.where == BOND else n),) + f.tail
