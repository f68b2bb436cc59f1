"""Material registry: scene `model` name -> the jitted kernels and constants of that material.

Adding a material means one module with its kernels and one entry here; the solver looks a body's
kernels up by name and never branches on material types itself.
"""

from dataclasses import dataclass
from typing import Callable

from pdmpm_cli.engine.materials import elastic


@dataclass(frozen=True)
class MaterialKind:
    forces: Callable  # (start, end, lam, mu, delta, x, X, V, bond_start, bond_nbr, coef, Fbar, force_out)
    energy: Callable  # same inputs without force_out -> strain energy [J]
    effective_constants: Callable  # (lam, mu, density) -> dict of effective isotropic constants
    needs_fbar: bool  # whether the averaged deformation Fbar (eq. 4) must be computed each step


MATERIALS: dict[str, MaterialKind] = {
    "elastic": MaterialKind(
        forces=elastic.elastic_forces,
        energy=elastic.elastic_energy,
        effective_constants=elastic.effective_constants,
        needs_fbar=True,
    ),
}
