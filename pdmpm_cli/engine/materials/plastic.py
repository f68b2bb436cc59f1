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
makes e_p identical on both stored directions of a bond, so forces stay pairwise equal and opposite.

A pair's force reads only its own e_p, so the map runs inside the force pass, each bond just before its force, on the
eta and Ybar the force needs anyway; only the dilatations (every pair reads both ends') need a pass of their own
before it, which computes the body's Fbar from the same gather of each family (the step's fbar phase leaves a
plastic body out). The CPU's pair pass maps each pair once, at its lower-index particle, and copies e_p to the
reverse bond (`bond_reverse`: the slot of q -> p in q's family, found once at the start and checkpointed with e_p);
the GPU's threads map each bond from both ends, each writing its own side.
"""

import math
from dataclasses import replace
from typing import Literal

import numpy as np
from numba import njit, prange
from pydantic import Field as Doc, model_validator

from pdmpm_cli.engine.bonds import averaged_deformation_at, bond_vector, chunk_width, fbar_of_rows, influence
from pdmpm_cli.engine.fields import BOND, PARTICLE, Field
from pdmpm_cli.engine.kernel import Kernel
from pdmpm_cli.engine.materials import elastic
from pdmpm_cli.engine.materials.elastic import ROOT_TINY, bond_at, gather_pairs, pair_force_of, sum_forces
from pdmpm_cli.engine.materials.base import MaterialKind
from pdmpm_cli.engine.parallel import particle_chunks

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


@njit(cache=True)
def fbar_dilatation_at(p, delta, mu, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_wv, bond_active,
                       particle_Kinv, particle_Fbar, particle_theta, chunks):
    """Fbar_p (eq. 4, where mu > 0) and theta_p: the GPU's form of `fbar_dilatation`."""
    if mu > 0.0:
        averaged_deformation_at(p, particle_x, rest_x, bond_start, bond_nbr, bond_wv, particle_Kinv, particle_Fbar,
                                chunks)
    dilatation_at(p, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_active, particle_theta)


@njit(parallel=True, cache=True, error_model="numpy")  # no fastmath: see parallel.py
def fbar_dilatation(start, end, delta, mu, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_wv,
                    bond_active, particle_Kinv, particle_Fbar, particle_theta, chunks):
    """Fbar_p (eq. 4, where mu > 0; bonds.averaged_deformation) and theta_p (`dilatation_at`) of particles
    start..end-1 from one gather of each family, the CPU's form: a loop gathers xi, eta, w V_q, V_q and whether the
    bond is intact into contiguous scratch rows; Fbar's sums run over the whole family in bond order
    (bonds.fbar_of_rows, as averaged_deformation), a loop without gathers or sums turns each bond into its two
    dilatation terms (the square roots and divisions, which the compiler can vectorise), and a last loop sums those
    of the intact bonds in bond order: to the bit the sums of averaged_deformation and `dilatation_at`."""
    has_active, has_mu = bond_active.shape[0] > 0, mu > 0.0
    n = end - start
    for t in prange(chunks):
        lo, hi = start + t * n // chunks, start + (t + 1) * n // chunks
        s = np.empty((9, chunk_width(bond_start, lo, hi)))  # xi (3), eta (3), w V_q, V_q, intact; terms in 0, 1
        for p in range(lo, hi):
            r0, r1, r2 = rest_x[p, 0], rest_x[p, 1], rest_x[p, 2]
            p0, p1, p2 = particle_x[p, 0], particle_x[p, 1], particle_x[p, 2]
            b0, m = bond_start[p], bond_start[p + 1] - bond_start[p]
            for k in range(m):
                q = bond_nbr[b0 + k]
                s[0, k], s[1, k], s[2, k] = rest_x[q, 0] - r0, rest_x[q, 1] - r1, rest_x[q, 2] - r2
                s[3, k], s[4, k], s[5, k] = particle_x[q, 0] - p0, particle_x[q, 1] - p1, particle_x[q, 2] - p2
                s[6, k], s[7, k] = bond_wv[b0 + k], particle_volume[q]
                s[8, k] = 0.0 if has_active and bond_active[b0 + k] == 0 else 1.0
            if has_mu:
                fbar_of_rows(p, s, m, particle_Kinv, particle_Fbar)
            for k in range(m):
                r = math.sqrt(s[0, k] * s[0, k] + s[1, k] * s[1, k] + s[2, k] * s[2, k])
                l = math.sqrt(s[3, k] * s[3, k] + s[4, k] * s[4, k] + s[5, k] * s[5, k])
                wv = influence(r, delta) * r * r * s[7, k]
                s[0, k], s[1, k] = wv * (l / r - 1.0), wv
            num = 0.0
            den = 0.0
            for k in range(m):
                if s[8, k] != 0.0:
                    num += s[0, k]
                    den += s[1, k]
            particle_theta[p] = 3.0 * num / den if den > 0.0 else 0.0


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


@njit(cache=True, inline="always")
def returned_force(has_mu, lam, mu, psi, r, tp, tq, ep, cp, cq, a, ir, e0, e1, e2, y0, y1, y2, z0, z1, z2):
    """Eqs. 10-11 on bond p -> q, then its force G (elastic.pair_force with the new e_p): returns e_p, f / psi_p
    after the map, and G.

    The bond strain is the one the force of eq. 9 acts on (elastic.py): (lam s + mu (sbar_p + sbar_q)) / M, with
    s = |eta|/|xi| - 1 and sbar = |Ybar|/|xi| - 1 (eta = e, Ybar_p = y, Ybar_q = z: Fbar xi, or eta for a crack
    particle); tp, tq are the pair's dilatations, r = |xi|. Both stored directions of a bond see the same strain and
    pair mean of theta (to the bit: e, y and z only change sign, and the sums are symmetric), so either end gets the
    same e_p. The force reuses the three lengths (floored as pair_force floors them)."""
    modulus = lam + 2.0 * mu
    limit = math.sqrt(2.0 * psi)
    le = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    ly = lz = 0.0
    strain = le / r - 1.0
    if has_mu:
        ly = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
        lz = math.sqrt(z0 * z0 + z1 * z1 + z2 * z2)
        strain = (lam * strain + mu * ((ly / r - 1.0) + (lz / r - 1.0))) / modulus
    e_dev = strain - (tp + tq) / 6.0
    e = modulus * (e_dev - ep)
    if abs(e) > limit:
        ep += (e - math.copysign(limit, e)) / modulus
        e = modulus * (e_dev - ep)
    g0, g1, g2 = pair_force_of(has_mu, lam, mu, cp, cq, a, ir, 1.0 + ep, max(le, ROOT_TINY), max(ly, ROOT_TINY),
                               max(lz, ROOT_TINY), e0, e1, e2, y0, y1, y2, z0, z1, z2)
    return ep, (0.5 * e * e - psi) / psi, g0, g1, g2


@njit(parallel=True, cache=True, error_model="numpy")  # no fastmath: see parallel.py
def plastic_forces(start, end, lam, mu, psi, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_wv,
                   bond_inv_len, bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar, particle_theta,
                   bond_reverse, force_private):
    """The return map and the bond forces (eqs. 6-7, 9-11) of particles start..end-1 in one pass: elastic.py's pair
    pass, each pair's e_p returned just before its force (`returned_force`), on the same eta, Ybar_p and Ybar_q, and
    written to both of its stored directions (`bond_reverse`: q -> p's slot in q's family). A pair's force reads only
    its own e_p, so this is the map for every bond followed by the forces. -> force_private (one force array per
    thread, as elastic_forces); returns the largest f / psi_p after the map (-1 for no bond)."""
    has_active, has_crack, has_mu = bond_active.shape[0] > 0, particle_crack.shape[0] > 0, mu > 0.0
    nt, n = force_private.shape[0], end - start
    worst = np.full(nt, -1.0)
    for t in prange(nt):
        f = force_private[t]
        for p in range(start, end):
            f[p, 0] = f[p, 1] = f[p, 2] = 0.0
        lo, hi = start + t * n // nt, start + (t + 1) * n // nt
        width = chunk_width(bond_start, lo, hi)
        s = np.zeros((15, width))  # elastic.gather_pairs' rows: eta, Ybar_p, Ybar_q (3 each), w V_q, 1 / |xi|, c_q,
        # e_p, |xi| (then f / psi_p), theta_q
        pair = np.zeros((3, width))  # G of each pair
        slot = np.zeros(width, dtype=np.int64)  # the bond p -> q
        fmax = -1.0
        for p in range(lo, hi):
            m = gather_pairs(p, has_mu, has_crack, has_active, True, particle_x, rest_x, bond_start, bond_nbr, bond_wv,
                             bond_inv_len, bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar,
                             particle_theta, s, slot)
            cp, vp, tp = particle_coef[p], particle_volume[p], particle_theta[p]
            for k in range(m):
                ep, ratio, g0, g1, g2 = returned_force(has_mu, lam, mu, psi, s[13, k], tp, s[14, k], s[12, k], cp,
                                                       s[11, k], s[9, k] * s[10, k] * vp, s[10, k], s[0, k], s[1, k],
                                                       s[2, k], s[3, k], s[4, k], s[5, k], s[6, k], s[7, k], s[8, k])
                pair[0, k], pair[1, k], pair[2, k] = g0, g1, g2
                s[12, k], s[13, k] = ep, ratio
            f0 = f1 = f2 = 0.0
            for k in range(m):
                f0 += pair[0, k]
                f1 += pair[1, k]
                f2 += pair[2, k]
                fmax = max(fmax, s[13, k])
                b = slot[k]
                q = bond_nbr[b]
                f[q, 0] -= pair[0, k]
                f[q, 1] -= pair[1, k]
                f[q, 2] -= pair[2, k]
                if s[12, k] != bond_ep[b]:
                    bond_ep[b] = s[12, k]
                    bond_ep[bond_start[q] + bond_reverse[b]] = s[12, k]
            f[p, 0] += f0
            f[p, 1] += f1
            f[p, 2] += f2
        worst[t] = fmax
    return worst.max()


def plastic_forces_cpu(start, end, lam, mu, psi, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_wv,
                       bond_inv_len, bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar, particle_theta,
                       bond_reverse, particle_force, force_private):
    """The CPU loop of PLASTIC_FORCES: the pair pass, then the per-thread arrays summed into particle_force; returns
    the largest f / psi_p after the map."""
    fmax = plastic_forces(start, end, lam, mu, psi, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_wv,
                          bond_inv_len, bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar,
                          particle_theta, bond_reverse, force_private)
    sum_forces(start, end, force_private, particle_force)
    return fmax


@njit(cache=True)
def plastic_force_at(p, lam, mu, psi, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_wv,
                     bond_inv_len, bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar, particle_theta,
                     bond_reverse, particle_force, force_private):
    """The GPU's form of `plastic_forces` (one thread per particle, no atomics): every intact bond of p is returned
    and its e_p written on p's side only (the other end's thread returns the same e_p on its side), then
    f_p = sum_q G as in elastic_force_at; returns the largest f / psi_p after the map (-1 for no bond)."""
    has_active, has_crack, has_mu = bond_active.shape[0] > 0, particle_crack.shape[0] > 0, mu > 0.0
    cp, vp, tp = particle_coef[p], particle_volume[p], particle_theta[p]
    p_crack = has_crack and particle_crack[p] != 0
    fmax = -1.0
    f0 = f1 = f2 = 0.0
    for b in range(bond_start[p], bond_start[p + 1]):
        if has_active and bond_active[b] == 0:
            continue
        q = bond_nbr[b]
        r, e0, e1, e2, y0, y1, y2, z0, z1, z2 = bond_at(p, q, has_mu, has_crack, p_crack, particle_x, rest_x,
                                                        particle_crack, particle_Fbar)
        ep, ratio, g0, g1, g2 = returned_force(has_mu, lam, mu, psi, r, tp, particle_theta[q], bond_ep[b], cp,
                                               particle_coef[q], bond_wv[b] * bond_inv_len[b] * vp, bond_inv_len[b],
                                               e0, e1, e2, y0, y1, y2, z0, z1, z2)
        bond_ep[b] = ep
        fmax = max(fmax, ratio)
        f0 += g0
        f1 += g1
        f2 += g2
    particle_force[p, 0] = f0
    particle_force[p, 1] = f1
    particle_force[p, 2] = f2
    return fmax


FBAR_DILATATION = Kernel(fbar_dilatation_at, fbar_dilatation)
PLASTIC_FORCES = Kernel(plastic_force_at, plastic_forces_cpu, reduce="max")


@njit(parallel=True, cache=True)
def particle_plastic_strain(bond_start, bond_ep, out):
    """Mean |e_p| over each particle's bonds: a scalar plastic-strain field for output [-]."""
    for p in prange(out.shape[0]):
        n = bond_start[p + 1] - bond_start[p]
        acc = 0.0
        for b in range(bond_start[p], bond_start[p + 1]):
            acc += abs(bond_ep[b])
        out[p] = acc / n if n > 0 else 0.0


def dilatation(solver, body: int, dt: float):
    """Before the forces: the body's Fbar (eq. 4; the step's fbar phase leaves a plastic body out) and every
    particle's dilatation (e_iso of eq. 9), which the return map of both ends of a bond reads, from one gather."""
    b, a, m = solver.model.bodies[body], solver.a, solver.m
    solver.backend.run(FBAR_DILATATION, b.start, b.end, b.horizon, b.params.mu, a.particle_x, m.rest_x,
                       m.particle_volume, a.bond_start, a.bond_nbr, a.bond_wv, a.bond_active, m.particle_Kinv,
                       a.particle_Fbar, a.particle_theta, particle_chunks())


def bonds(solver, body: int, dt: float):
    """Eqs. 10-11 on every bond of the body, then its bond forces (eqs. 6-7, 9) -> particle_force, in one pass;
    keeps the largest f / psi_p."""
    b, a, m = solver.model.bodies[body], solver.a, solver.m
    residual = solver.backend.run(PLASTIC_FORCES, b.start, b.end, b.params.lam, b.params.mu, b.params.psi,
                                  a.particle_x, m.rest_x, m.particle_volume, a.bond_start, a.bond_nbr, a.bond_wv,
                                  a.bond_inv_len, a.bond_active, a.bond_ep, a.particle_crack, m.particle_coef,
                                  a.particle_Fbar, a.particle_theta, a.bond_reverse, a.particle_force,
                                  a.particle_force_private)
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
    name="plastic", schema=Schema, params=params, forces=bonds, bond_forces=elastic.bonds, constants=elastic.constants,
    energy=elastic.energy, before_forces=dilatation, start=start, uses_fbar=lambda p: p.mu > 0,
    computes_fbar=True,
    fields=elastic.KIND.fields + (
        Field("bond_ep", BOND, doc="plastic strain per bond (eq. 9) [-]"),
        Field("bond_reverse", BOND, dtype="i8", doc="slot of the reverse bond q -> p in q's family [-]"),
        Field("particle_theta", PARTICLE, transient=True, doc="dilatation for e_iso (eq. 9) [-]"),
    ),
    outputs={"particle_plastic_strain": plastic_strain},
    runs_as=lambda section: "elastic" if section.yield_psi >= ELASTIC_PSI else "plastic",
)
