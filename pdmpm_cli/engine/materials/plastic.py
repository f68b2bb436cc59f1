"""Per-bond deviatoric plasticity (paper eqs. 8-11; docs/method.md 'Plastic bonds').

Forces are the elastic ones of eq. 9 with the bond's plastic strain e_p subtracted (elastic.py takes bond_ep).
Each step, before the forces, every bond is tested against the yield function of eq. 10,

    E_dev = M (e_dev - e_p),   f = E_dev^2 / 2 - psi_p,   M = lam + 2 mu,
    e_dev = (lam s + mu (sbar_p + sbar_q)) / M - e_iso,

and returned exactly onto f = 0 when it is outside (eq. 11 corrected: divide by M, not lam / |X|):

    e_p += (E_dev - sqrt(2 psi_p) sign(E_dev)) / M.

(lam s + mu (sbar_p + sbar_q)) / M is the strain the force of eq. 9 acts on (s from eta, sbar from Fbar xi), so f = 0
is the force's yield limit; measuring s alone let a flattened soft block gain strain energy until it blew up.
e_iso is the isotropic part of the bond strain: the mean of the pair's two particle dilatations / 3, where a
particle's dilatation theta_p = 3 sum_q w |xi|^2 s V_q / sum_q w |xi|^2 V_q (the LPS dilatation written with
strains; unlike tr(Fbar) - 3 it is zero under any rigid rotation and defined for cloth). Using the pair mean
makes e_p identical on both stored directions of a bond, so forces stay pairwise equal and opposite. The return map
therefore runs once per bond pair, at its lower-index particle, and copies e_p to the reverse bond (`bond_reverse`:
the slot of q -> p in q's family, found once at the start and checkpointed with e_p).
"""

import math
from dataclasses import replace
from typing import Literal

import numpy as np
from numba import njit, prange
from pydantic import Field as Doc, model_validator

from pdmpm_cli.engine.bonds import bond_vector, influence
from pdmpm_cli.engine.fields import BOND, PARTICLE, Field
from pdmpm_cli.engine.kernel import Kernel
from pdmpm_cli.engine.materials import elastic
from pdmpm_cli.engine.materials.elastic import averaged_bond
from pdmpm_cli.engine.materials.base import MaterialKind

ELASTIC_PSI = 1e20  # psi_p at or above this means the bonds never yield (Table 1 writes 1e25 for "elastic")


class Schema(elastic.Schema):
    """Elastic bonds with per-bond deviatoric plasticity (paper eqs. 8-11, docs/method.md 'Plastic bonds').

    Give either the paper's yield parameter `psi_p` or a physical `yield_stress` (then psi_p = sigma_y^2 / 2:
    a bar in uniaxial tension starts to yield at sigma_y)."""

    model: Literal["plastic"]
    psi_p: float | None = Doc(
        None, gt=0, description="Yield parameter psi_p of eq. 10: a bond yields when E_dev^2 / 2 > psi_p, with the "
        "bond's deviatoric stress E_dev = (lam + 2 mu)(e_dev - e_p) [Pa^2]. At or above 1e20 the body is elastic "
        "and the plastic pass is left out.",
    )
    yield_stress: float | None = Doc(
        None, gt=0, description="Uniaxial yield stress sigma_y, an alternative to psi_p (psi_p = sigma_y^2 / 2) [Pa].",
    )

    @model_validator(mode="after")
    def _one_yield(self):
        if (self.psi_p is None) == (self.yield_stress is None):
            raise ValueError("give exactly one of psi_p (the paper's yield parameter, Pa^2) or yield_stress (Pa)")
        return self

    @property
    def yield_psi(self) -> float:
        """psi_p [Pa^2], from whichever of psi_p and yield_stress was given."""
        return self.psi_p if self.psi_p is not None else 0.5 * self.yield_stress**2


def params(section) -> elastic.Params:
    return replace(elastic.params(section), psi=section.yield_psi)


@njit(cache=True)
def dilatation_at(p, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_active, particle_theta):
    """theta_p = 3 sum w |xi|^2 s V_q / sum w |xi|^2 V_q over intact bonds (e_iso of eq. 9) -> particle_theta[p]."""
    has_active = bond_active.shape[0] > 0
    num = 0.0
    den = 0.0
    for b in range(bond_start[p], bond_start[p + 1]):
        if has_active and bond_active[b] == 0:
            continue
        q = bond_nbr[b]
        r = bond_vector(rest_x, p, q)[3]
        l = bond_vector(particle_x, p, q)[3]
        wv = influence(r, delta) * r * r * particle_volume[q]
        num += wv * (l / r - 1.0)
        den += wv
    particle_theta[p] = 3.0 * num / den if den > 0.0 else 0.0


@njit(parallel=True, cache=True)
def bond_dilatation(start, end, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_active,
                    particle_theta):
    """`dilatation_at` for particles start..end-1."""
    for p in prange(start, end):
        dilatation_at(p, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_active, particle_theta)


@njit(cache=True)
def reverse_slots(bond_start, bond_nbr, start, end, bond_reverse):
    """bond_reverse[b] = the slot of q -> p in q's family, for the bonds b = p -> q of particles start..end-1."""
    for p in range(start, end):
        for b in range(bond_start[p], bond_start[p + 1]):
            q = bond_nbr[b]
            for r in range(bond_start[q], bond_start[q + 1]):
                if bond_nbr[r] == p:
                    bond_reverse[b] = r - bond_start[q]
                    break


@njit(cache=True)
def return_map_at(p, lam, mu, psi, particle_x, rest_x, bond_start, bond_nbr, bond_active, particle_crack,
                  particle_Fbar, particle_theta, bond_reverse, bond_ep):
    """Eqs. 10-11 for every yielding bond p -> q with q > p, bond_ep in place on it and its reverse q -> p; returns
    the largest f / psi_p after (-1 for no such bond).

    The bond strain is the one the force of eq. 9 acts on (elastic.py): (lam s + mu (sbar_p + sbar_q)) / M, with
    s = |eta|/|xi| - 1 and sbar = |Fbar xi|/|xi| - 1 (s for a crack particle). Both stored directions of a bond see
    the same strain and pair mean of theta (to the bit), so one update serves both; each pair is written by one
    particle only (families are symmetric, and cuts remove both directions)."""
    has_active = bond_active.shape[0] > 0
    has_crack = particle_crack.shape[0] > 0
    modulus = lam + 2.0 * mu
    limit = math.sqrt(2.0 * psi)
    tp = particle_theta[p]
    p_crack = has_crack and particle_crack[p] != 0
    fmax = -1.0
    for b in range(bond_start[p], bond_start[p + 1]):
        q = bond_nbr[b]
        if q < p or (has_active and bond_active[b] == 0):
            continue
        x0, x1, x2, r = bond_vector(rest_x, p, q)
        s = bond_vector(particle_x, p, q)[3] / r - 1.0
        strain = s
        if mu > 0.0:
            sp = s if p_crack else averaged_bond(particle_Fbar[p], x0, x1, x2)[3] / r - 1.0
            q_crack = has_crack and particle_crack[q] != 0
            sq = s if q_crack else averaged_bond(particle_Fbar[q], x0, x1, x2)[3] / r - 1.0
            strain = (lam * s + mu * (sp + sq)) / modulus
        e_dev = strain - (tp + particle_theta[q]) / 6.0
        e = modulus * (e_dev - bond_ep[b])
        if abs(e) > limit:
            bond_ep[b] += (e - math.copysign(limit, e)) / modulus
            bond_ep[bond_start[q] + bond_reverse[b]] = bond_ep[b]
            e = modulus * (e_dev - bond_ep[b])
        fmax = max(fmax, (0.5 * e * e - psi) / psi)
    return fmax


@njit(parallel=True, cache=True)
def plastic_return_map(start, end, lam, mu, psi, particle_x, rest_x, bond_start, bond_nbr, bond_active, particle_crack,
                       particle_Fbar, particle_theta, bond_reverse, bond_ep):
    """`return_map_at` for particles start..end-1; returns the largest f / psi_p after the update (0 up to round-off
    when the map is exact, -1 for no particles)."""
    worst = np.full(end - start, -1.0)
    for p in prange(start, end):
        worst[p - start] = return_map_at(p, lam, mu, psi, particle_x, rest_x, bond_start, bond_nbr, bond_active,
                                         particle_crack, particle_Fbar, particle_theta, bond_reverse, bond_ep)
    return worst.max() if end > start else -1.0


DILATATION = Kernel(dilatation_at, bond_dilatation)
RETURN_MAP = Kernel(return_map_at, plastic_return_map, reduce="max")


@njit(parallel=True, cache=True)
def particle_plastic_strain(bond_start, bond_ep, out):
    """Mean |e_p| over each particle's bonds: a scalar plastic-strain field for output [-]."""
    for p in prange(out.shape[0]):
        n = bond_start[p + 1] - bond_start[p]
        acc = 0.0
        for b in range(bond_start[p], bond_start[p + 1]):
            acc += abs(bond_ep[b])
        out[p] = acc / n if n > 0 else 0.0


def return_map(solver, body: int, dt: float):
    """Before the forces: dilatations, then eqs. 10-11 on every bond of the body; keeps the largest f / psi_p."""
    b, a, m = solver.model.bodies[body], solver.a, solver.m
    run = solver.backend.run
    run(DILATATION, b.start, b.end, b.horizon, a.particle_x, m.rest_x, m.particle_volume, a.bond_start, a.bond_nbr,
        a.bond_active, a.particle_theta)
    residual = run(RETURN_MAP, b.start, b.end, b.params.lam, b.params.mu, b.params.psi, a.particle_x, m.rest_x,
                   a.bond_start, a.bond_nbr, a.bond_active, a.particle_crack, a.particle_Fbar, a.particle_theta,
                   a.bond_reverse, a.bond_ep)
    solver.state.yield_residual = max(solver.state.yield_residual, residual)


def start(solver, state, body: int):
    """The reverse-bond slots of the body's bonds (its families never change: plastic bodies are not rebuilt)."""
    b = solver.model.bodies[body]
    reverse_slots(state.bond_start, state.bond_nbr, b.start, b.end, state.bond_reverse)


def plastic_strain(model, state) -> np.ndarray:
    out = np.zeros(len(state.particle_x))
    particle_plastic_strain(state.bond_start, state.bond_ep, out)
    return out


KIND = MaterialKind(
    name="plastic", schema=Schema, params=params, forces=elastic.bonds, constants=elastic.constants,
    energy=elastic.energy, before_forces=return_map, start=start, uses_fbar=lambda p: p.mu > 0,
    fields=elastic.KIND.fields + (
        Field("bond_ep", BOND, doc="plastic strain per bond (eq. 9) [-]"),
        Field("bond_reverse", BOND, dtype="i8", doc="slot of the reverse bond q -> p in q's family [-]"),
        Field("particle_theta", PARTICLE, transient=True, doc="dilatation for e_iso (eq. 9) [-]"),
    ),
    outputs={"particle_plastic_strain": plastic_strain},
    runs_as=lambda section: "elastic" if section.yield_psi >= ELASTIC_PSI else "plastic",
)
