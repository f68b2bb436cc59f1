"""Material registry: scene `model` name -> the phases, arrays and constants of that material.

Adding a material means one module with its kernels and one entry here. A material contributes phases
named `<phase>:<model>` that the solver runs for each body of that kind, in the order listed, before the
MPM transfers; `bonds` is the force pass. The solver and the Plan never branch on material types.
"""

from dataclasses import dataclass, field
from typing import Callable

from pdmpm_cli.engine.materials import elastic, plastic, viscoelastic
from pdmpm_cli.scene.schema import ELASTIC_PSI


@dataclass(frozen=True)
class MaterialKind:
    phases: dict[str, Callable]  # phase name -> fn(model, state, body, dt); "bonds" writes state.particle_force
    energy: Callable  # fn(model, state, body) -> stored strain energy [J]
    effective_constants: Callable  # fn(lam, mu, density) -> dict of effective isotropic constants
    needs_fbar: Callable  # fn(material) -> whether the averaged deformation Fbar (eq. 4) is needed
    bond_fields: dict[str, str] = field(default_factory=dict)  # per-bond state arrays: name -> dtype
    particle_fields: dict[str, tuple] = field(default_factory=dict)  # name -> (trailing shape, dtype)
    init: Callable | None = None  # fn(model, state, body): initial values of the material's state arrays
    pair_forces: bool = False  # the bond pass is elastic.py's pair pass: per-thread force arrays, bond_wv, bond_inv_len


MATERIALS: dict[str, MaterialKind] = {
    "elastic": MaterialKind(
        phases={"bonds": elastic.forces},
        energy=elastic.energy,
        effective_constants=elastic.effective_constants,
        needs_fbar=lambda mat: mat.mu > 0,
        pair_forces=True,
    ),
    "plastic": MaterialKind(
        phases={"return_map": plastic.return_map, "bonds": elastic.forces},
        energy=elastic.energy,
        effective_constants=elastic.effective_constants,
        needs_fbar=lambda mat: mat.mu > 0,
        bond_fields={"bond_ep": "f8"},
        particle_fields={"particle_theta": ((), "f8")},
        pair_forces=True,
    ),
    "viscoelastic": MaterialKind(
        phases={"families": viscoelastic.refresh_families, "bonds": viscoelastic.forces},
        energy=viscoelastic.energy,
        effective_constants=viscoelastic.effective_constants,
        needs_fbar=lambda mat: False,
        bond_fields={"bond_len0": "f8", "bond_force_el": "f8", "bond_force_visc": "f8"},
        particle_fields={"particle_m": ((), "f8"), "particle_dtheta": ((), "f8"), "particle_x_prev": ((3,), "f8"),
                         "particle_x_rebuild": ((3,), "f8")},
        init=viscoelastic.init_state,
    ),
}


def kind_of(material) -> str:
    """The registry entry a body runs: a plastic body that can never yield (psi_p >= 1e20) runs as elastic."""
    if material.model == "plastic" and material.yield_psi >= ELASTIC_PSI:
        return "elastic"
    return material.model
