"""A test-only material, added as docs/architecture.md's walk-through adds one: linear springs between bonded
particles (bond-based peridynamics, Silling 2000) that soften with the largest stretch each bond has seen.

It is registered through the environment (PDMPM_MATERIALS=tests.spring_material), the way a material outside the
package is; inside the package it would be one more entry in engine.materials.BUILTIN. Its per-bond memory
(`bond_peak`) is declared once and so is allocated, checkpointed and carried like any engine array: a resume that
lost it would not reproduce the run (tests/test_materials.py checks both backends and the resume).

    PDMPM_MATERIALS=tests.spring_material python -m tests.spring_material OUTDIR   # reference, kill, resume: JSON
"""

import json
import math
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numba import njit, prange
from pydantic import Field as Doc

from pdmpm_cli.engine.bonds import bond_vector
from pdmpm_cli.engine.fields import BOND, Field
from pdmpm_cli.engine.kernel import Kernel
from pdmpm_cli.engine.materials.base import MaterialKind
from pdmpm_cli.spec import Strict


class Schema(Strict):
    """Linear bond springs (bond-based peridynamics) that soften with the largest stretch a bond has seen."""

    model: Literal["spring"]
    density: float = Doc(gt=0, description="Mass density [kg/m^3].")
    youngs_modulus: float = Doc(gt=0, description="Young's modulus E of the bond-based solid (nu = 1/4) [Pa].")
    softening: float = Doc(0.0, ge=0, description="Stiffness divided by 1 + softening x peak stretch [-].")


@dataclass(frozen=True)
class Params:
    density: float
    youngs_modulus: float
    softening: float


def params(section) -> Params:
    return Params(section.density, section.youngs_modulus, section.softening)


@njit(cache=True)
def spring_force_at(p, c, softening, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_peak,
                    particle_force):
    """f_p = sum_q c s / (1 + softening peak) dir(eta) V_p V_q, with the bond's peak stretch updated first."""
    f0 = f1 = f2 = 0.0
    for b in range(bond_start[p], bond_start[p + 1]):
        q = bond_nbr[b]
        r = bond_vector(rest_x, p, q)[3]
        e0, e1, e2, l = bond_vector(particle_x, p, q)
        s = l / r - 1.0
        if s > bond_peak[b]:
            bond_peak[b] = s
        if l > 0.0:
            g = c * s / (1.0 + softening * bond_peak[b]) * particle_volume[p] * particle_volume[q] / l
            f0 += g * e0
            f1 += g * e1
            f2 += g * e2
    particle_force[p, 0] = f0
    particle_force[p, 1] = f1
    particle_force[p, 2] = f2


@njit(parallel=True, cache=True)
def spring_forces(start, end, c, softening, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_peak,
                  particle_force):
    for p in prange(start, end):
        spring_force_at(p, c, softening, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_peak,
                        particle_force)


SPRING_FORCES = Kernel(spring_force_at, spring_forces)


def micromodulus(p: Params, delta: float) -> float:
    """c = 18 K / (pi delta^4) with K = E / (3 (1 - 2 nu)), nu = 1/4 (bond-based peridynamics in 3-D)."""
    return 18.0 * (2.0 * p.youngs_modulus / 3.0) / (math.pi * delta**4)


def bonds(solver, body: int, dt: float):
    b, a, m = solver.model.bodies[body], solver.a, solver.m
    solver.backend.run(SPRING_FORCES, b.start, b.end, micromodulus(b.params, b.horizon), b.params.softening,
                       a.particle_x, m.rest_x, m.particle_volume, a.bond_start, a.bond_nbr, a.bond_peak,
                       a.particle_force)


def constants(p: Params) -> dict:
    k, mu = 2.0 * p.youngs_modulus / 3.0, 0.4 * p.youngs_modulus
    return {"p_wave_modulus": k + 4.0 * mu / 3.0, "youngs_modulus": p.youngs_modulus, "poisson_ratio": 0.25,
            "bulk_modulus": k, "shear_modulus": mu, "wave_speed": math.sqrt((k + 4.0 * mu / 3.0) / p.density)}


def mean_peak(model, state) -> np.ndarray:
    counts = np.diff(state.bond_start)
    sums = np.add.reduceat(state.bond_peak, state.bond_start[:-1]) if len(state.bond_peak) else np.zeros(len(counts))
    return np.where(counts > 0, sums, 0.0) / np.maximum(counts, 1)


KIND = MaterialKind(
    name="spring", schema=Schema, params=params, forces=bonds, constants=constants,
    fields=(Field("bond_peak", BOND, doc="largest stretch the bond has seen [-]"),),
    outputs={"particle_spring_peak": mean_peak},
)

SCENE = """\
name: springs
simulation: {duration: 0.2, fps: 50}
grid: {cell_size: 0.05, domain: {min: [0, 0, 0], max: [1, 1, 1]}}
bodies:
  - name: block
    geometry: {mode: cloud, sampling: lattice, spacing: 0.05,
               shape: {type: box, center: [0.5, 0.3, 0.5], size: [0.2, 0.15, 0.15]}}
    material: {model: spring, density: 1000, youngs_modulus: 2e5, softening: 50}
    velocity: [0, -3, 0]
output: {fields: [particle_v, particle_spring_peak], checkpoint_every: 3}
"""


def resume_check(out: Path) -> dict:
    """The scene run through, and run again stopped after frame 7 and resumed: are the frames bitwise equal?"""
    from pdmpm_cli.engine.solver import Solver
    from pdmpm_cli.io.hdf5 import read_run
    from pdmpm_cli.runner import prepare, prepare_resume, simulate

    out.mkdir(parents=True, exist_ok=True)
    scene = out / "springs.yaml"
    scene.write_text(SCENE)
    simulate(prepare(scene), out / "reference")
    advance = Solver.advance

    def stop(self, state, t_end, on_substep=None):
        if t_end > 7.5 * self.plan.frame_dt:
            raise KeyboardInterrupt
        advance(self, state, t_end, on_substep)

    Solver.advance = stop
    try:
        simulate(prepare(scene), out / "resumed")
    except KeyboardInterrupt:
        pass
    finally:
        Solver.advance = advance
    shutil.copytree(out / "resumed", out / "forgetful")
    prep, ckpt = prepare_resume(out / "resumed")
    checkpointed = sorted(ckpt.arrays)
    simulate(prep, out / "resumed", resume=ckpt)
    prep, ckpt = prepare_resume(out / "forgetful")  # the same, with the bonds' memory lost
    ckpt.arrays["bond_peak"][:] = 0.0
    simulate(prep, out / "forgetful", resume=ckpt)
    a, b, c = (read_run(out / name / "run.h5") for name in ("reference", "resumed", "forgetful"))

    def same(x, y):
        return all(np.array_equal(x.frame(f)[k], y.frame(f)[k]) for f in range(len(x))
                   for k in ("particle_x", "particle_v", "particle_spring_peak"))

    return {"frames": [len(a), len(b)], "resumed_from": ckpt.frame, "checkpointed": checkpointed,
            "bitwise": same(a, b), "forgetful_differs": not same(a, c),
            "peak": float(a.frame(-1)["particle_spring_peak"].max()),
            "moved": float(np.abs(a.frame(-1)["particle_x"] - a.frame(0)["particle_x"]).max())}


if __name__ == "__main__":
    print(json.dumps(resume_check(Path(sys.argv[1]))))
