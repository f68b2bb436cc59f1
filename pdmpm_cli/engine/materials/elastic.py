"""Elastic peridynamic bonds (paper eqs. 5-7) with the per-particle calibration of docs/method.md.

Energy density of particle p (eq. 5, normalised):
    W_p = c_p sum_q w V_q [ mu (|Ybar|/|xi| - 1)^2 + lam/2 (|eta|/|xi| - 1)^2 ],   c_p = 5 / omega_p,
with Ybar = Fbar_p xi. Under a homogeneous small strain eps this is the isotropic solid
W = (M/6) (tr(eps)^2 + 2 eps:eps), M = lam + 2 mu: E_eff = 5 M / 6, nu_eff = 1/4, P-wave modulus M.
Bond force state (eq. 6 in strains), acting on p along the bond:
    T<p,q> = c_p w / |xi| [ 2 mu (|Ybar|/|xi| - 1) dir(Ybar) + lam (|eta|/|xi| - 1) dir(eta) ]
and f_p = sum_q (T<p,q> - T<q,p>) V_p V_q (eq. 2, 7), which conserves linear momentum pairwise.

Crack-surface particles (particle_crack = 1, section 6) use their bond eta in place of Ybar in the mu term:
Fbar over a cut family is ill-defined, and without the grid's smoothing the Fbar term (not an exact energy
gradient) lets crack particles gain energy; the pure bond term is conservative and has the same stiffness
under homogeneous deformation (Ybar = eta there).

The same kernels serve plastic bodies (eq. 9): both strains are measured from the bond's plastic strain e_p,
i.e. (|Ybar|/|xi| - 1 - e_p) and (|eta|/|xi| - 1 - e_p). bond_ep and bond_active are empty arrays (shape (0,))
when no body of the scene needs them: then e_p = 0 and every bond is intact.
"""

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numba import njit, prange
from pydantic import Field as Doc, model_validator

from pdmpm_cli.engine import fields
from pdmpm_cli.engine.bonds import bond_vector, chunk_width, influence
from pdmpm_cli.engine.kernel import Kernel
from pdmpm_cli.engine.materials.base import MaterialKind
from pdmpm_cli.spec import Strict

NO_THETA = np.zeros(0)  # gather_pairs' particle_theta for elastic bodies: no plastic rows
TINY = 1e-300  # floor of a squared bond length: a zero-length bond gets a finite coefficient times a zero vector
ROOT_TINY = math.sqrt(TINY)  # floor of a bond length: max(sqrt(x), ROOT_TINY) = sqrt(max(x, TINY)) to the bit


class Schema(Strict):
    """Elastic peridynamic bonds (paper eqs. 5-7). See docs/method.md for the calibration to E and nu."""

    model: Literal["elastic"]
    density: float = Doc(gt=0, description="Mass density rho [kg/m^3].")
    lam: float = Doc(ge=0, description="Lame's first parameter lambda: isotropic (bond-stretch) term [Pa].")
    mu: float = Doc(ge=0, description="Shear modulus mu: deviatoric (averaged-deformation) term [Pa].")

    @model_validator(mode="after")
    def _stiff(self):
        if self.lam + 2 * self.mu <= 0:
            raise ValueError("lam + 2 mu must be positive: a material with no stiffness cannot hold its shape")
        return self


@dataclass(frozen=True)
class Params:
    density: float  # [kg/m^3]
    lam: float  # [Pa]
    mu: float  # [Pa]
    psi: float = math.inf  # yield parameter psi_p [Pa^2] (plastic bodies; inf: never yields)


def params(section) -> Params:
    return Params(section.density, section.lam, section.mu)


@njit(cache=True, inline="always")
def averaged_bond(fbar, x0, x1, x2):
    """Ybar = Fbar xi (eq. 4's averaged deformed bond) and its length."""
    y0 = fbar[0, 0] * x0 + fbar[0, 1] * x1 + fbar[0, 2] * x2
    y1 = fbar[1, 0] * x0 + fbar[1, 1] * x1 + fbar[1, 2] * x2
    y2 = fbar[2, 0] * x0 + fbar[2, 1] * x1 + fbar[2, 2] * x2
    return y0, y1, y2, math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)


@njit(cache=True, inline="always")
def pair_force(has_mu, lam, mu, cp, cq, a, ir, one_ep, e0, e1, e2, y0, y1, y2, z0, z1, z2):
    """G = V_p V_q (T<p,q> - T<q,p>) of bond p -> q (eqs. 6-7, 9): the force on p, -G on q.

    a = w V_q V_p / |xi|, ir = 1 / |xi|, one_ep = 1 + e_p; eta = e, Ybar_p = y, Ybar_q = z (= Fbar_q xi, or eta for a
    crack particle)."""
    le = math.sqrt(max(e0 * e0 + e1 * e1 + e2 * e2, TINY))
    ly = lz = 0.0
    if has_mu:
        ly = math.sqrt(max(y0 * y0 + y1 * y1 + y2 * y2, TINY))
        lz = math.sqrt(max(z0 * z0 + z1 * z1 + z2 * z2, TINY))
    return pair_force_of(has_mu, lam, mu, cp, cq, a, ir, one_ep, le, ly, lz, e0, e1, e2, y0, y1, y2, z0, z1, z2)


@njit(cache=True, inline="always")
def pair_force_of(has_mu, lam, mu, cp, cq, a, ir, one_ep, le, ly, lz, e0, e1, e2, y0, y1, y2, z0, z1, z2):
    """`pair_force` given the lengths le, ly, lz of eta, Ybar_p, Ybar_q (each at least ROOT_TINY). Each strain
    (|y|/|xi| - 1 - e_p)/|y| is 1/|xi| - (1 + e_p)/|y|, and the three 1/|y| share one division:
    1/|eta| = |Ybar_p| |Ybar_q| / (|eta| |Ybar_p| |Ybar_q|), and so on."""
    if has_mu:
        inv = one_ep / max(le * ly * lz, TINY)
        gy = a * 2.0 * mu * cp * (ir - inv * le * lz)
        gz = a * 2.0 * mu * cq * (ir - inv * le * ly)
        g = a * lam * (cp + cq) * (ir - inv * ly * lz)
        return g * e0 + gy * y0 + gz * z0, g * e1 + gy * y1 + gz * z1, g * e2 + gy * y2 + gz * z2
    g = a * lam * (cp + cq) * (ir - one_ep / le)
    return g * e0, g * e1, g * e2


@njit(cache=True, inline="always")
def gather_pairs(p, has_mu, has_crack, has_active, has_ep, particle_x, rest_x, bond_start, bond_nbr, bond_wv,
                 bond_inv_len, bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar, particle_theta, s,
                 slot):
    """Rows 0-12 of s and slot for the intact bonds b = p -> q with q > p: eta, Ybar_p = Fbar_p xi, Ybar_q = Fbar_q xi
    (eta for a crack-surface particle), w V_q, 1 / |xi|, c_q, e_p (0 without bond_ep) and b; with a particle_theta
    (plastic bodies: plastic.plastic_forces; empty for elastic ones) also rows 13 and 14, |xi| and theta_q. Returns
    their count."""
    with_theta = particle_theta.shape[0] > 0
    r0, r1, r2 = rest_x[p, 0], rest_x[p, 1], rest_x[p, 2]
    p0, p1, p2 = particle_x[p, 0], particle_x[p, 1], particle_x[p, 2]
    f = p if has_mu else 0
    a00, a01, a02 = particle_Fbar[f, 0, 0], particle_Fbar[f, 0, 1], particle_Fbar[f, 0, 2]
    a10, a11, a12 = particle_Fbar[f, 1, 0], particle_Fbar[f, 1, 1], particle_Fbar[f, 1, 2]
    a20, a21, a22 = particle_Fbar[f, 2, 0], particle_Fbar[f, 2, 1], particle_Fbar[f, 2, 2]
    p_crack = has_crack and particle_crack[p] != 0
    m = 0
    for b in range(bond_start[p], bond_start[p + 1]):
        q = bond_nbr[b]
        if q < p or (has_active and bond_active[b] == 0):
            continue
        e0, e1, e2 = particle_x[q, 0] - p0, particle_x[q, 1] - p1, particle_x[q, 2] - p2
        s[0, m], s[1, m], s[2, m] = e0, e1, e2
        x0, x1, x2 = rest_x[q, 0] - r0, rest_x[q, 1] - r1, rest_x[q, 2] - r2
        if has_mu:
            if p_crack:
                s[3, m], s[4, m], s[5, m] = e0, e1, e2
            else:
                s[3, m] = a00 * x0 + a01 * x1 + a02 * x2
                s[4, m] = a10 * x0 + a11 * x1 + a12 * x2
                s[5, m] = a20 * x0 + a21 * x1 + a22 * x2
            if has_crack and particle_crack[q] != 0:
                s[6, m], s[7, m], s[8, m] = e0, e1, e2
            else:
                for i in range(3):
                    s[6 + i, m] = particle_Fbar[q, i, 0] * x0 + particle_Fbar[q, i, 1] * x1 + particle_Fbar[q, i, 2] * x2
        s[9, m] = bond_wv[b]
        s[10, m] = bond_inv_len[b]
        s[11, m] = particle_coef[q]
        s[12, m] = bond_ep[b] if has_ep else 0.0
        if with_theta:
            s[13, m], s[14, m] = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2), particle_theta[q]
        slot[m] = b
        m += 1
    return m


@njit(parallel=True, cache=True, error_model="numpy")  # no fastmath: see parallel.py
def elastic_forces(start, end, lam, mu, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_wv,
                   bond_inv_len, bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar, force_private):
    """Bond forces (eqs. 6-7, 9) of particles start..end-1 of one elastic or plastic body -> force_private, one
    force array per thread (sum them with `sum_forces`): the CPU's pair pass.

    Each bond pair is evaluated once, at its lower-index particle p: `pair_force` G is added to p and subtracted
    from q, so the pair's forces are equal and opposite to the bit (families are symmetric: build_families stores
    both directions, cuts and fracture remove both). Thread t takes a fixed particle range and scatters into
    force_private[t] only: no races, and a fixed order. Per particle, a gather loop fills the scratch rows
    (`gather_pairs`), a loop without gathers or sums evaluates the pairs (the loop the compiler vectorises: packed
    square roots and divisions), and a third sums G onto p in bond order and scatters -G onto the q."""
    has_active, has_crack = bond_active.shape[0] > 0, particle_crack.shape[0] > 0
    has_ep, has_mu = bond_ep.shape[0] > 0, mu > 0.0
    nt, n = force_private.shape[0], end - start
    for t in prange(nt):
        f = force_private[t]
        for p in range(start, end):
            f[p, 0] = f[p, 1] = f[p, 2] = 0.0
        lo, hi = start + t * n // nt, start + (t + 1) * n // nt
        width = chunk_width(bond_start, lo, hi)
        s = np.zeros((13, width))  # eta, Ybar_p, Ybar_q (3 each), w V_q, 1 / |xi|, c_q, e_p
        pair = np.zeros((3, width))  # G of each pair
        slot = np.zeros(width, dtype=np.int64)  # the bond p -> q
        for p in range(lo, hi):
            m = gather_pairs(p, has_mu, has_crack, has_active, has_ep, particle_x, rest_x, bond_start, bond_nbr,
                             bond_wv, bond_inv_len, bond_active, bond_ep, particle_crack, particle_coef,
                             particle_Fbar, NO_THETA, s, slot)
            cp, vp = particle_coef[p], particle_volume[p]
            for k in range(m):
                pair[0, k], pair[1, k], pair[2, k] = pair_force(
                    has_mu, lam, mu, cp, s[11, k], s[9, k] * s[10, k] * vp, s[10, k], 1.0 + s[12, k], s[0, k],
                    s[1, k], s[2, k], s[3, k], s[4, k], s[5, k], s[6, k], s[7, k], s[8, k])
            f0 = f1 = f2 = 0.0
            for k in range(m):
                f0 += pair[0, k]
                f1 += pair[1, k]
                f2 += pair[2, k]
                q = bond_nbr[slot[k]]
                f[q, 0] -= pair[0, k]
                f[q, 1] -= pair[1, k]
                f[q, 2] -= pair[2, k]
            f[p, 0] += f0
            f[p, 1] += f1
            f[p, 2] += f2


@njit(parallel=True, cache=True)
def sum_forces(start, end, force_private, particle_force):
    """particle_force = the threads' force arrays summed in thread order (a fixed order: reproducible)."""
    for p in prange(start, end):
        for a in range(3):
            acc = 0.0
            for t in range(force_private.shape[0]):
                acc += force_private[t, p, a]
            particle_force[p, a] = acc


@njit(cache=True, inline="always")
def bond_at(p, q, has_mu, has_crack, p_crack, particle_x, rest_x, particle_crack, particle_Fbar):
    """|xi|, eta, Ybar_p and Ybar_q of bond p -> q (Ybar = Fbar xi, or eta for a crack-surface particle or where
    mu = 0): the vectors of one bond in the GPU's forms of the pair passes (`elastic_force_at`,
    plastic.plastic_force_at)."""
    x0, x1, x2, r = bond_vector(rest_x, p, q)
    e0, e1, e2, _ = bond_vector(particle_x, p, q)
    y0, y1, y2, z0, z1, z2 = e0, e1, e2, e0, e1, e2
    if has_mu:
        if not p_crack:
            y0, y1, y2, _ = averaged_bond(particle_Fbar[p], x0, x1, x2)
        if not (has_crack and particle_crack[q] != 0):
            z0, z1, z2, _ = averaged_bond(particle_Fbar[q], x0, x1, x2)
    return r, e0, e1, e2, y0, y1, y2, z0, z1, z2


@njit(cache=True)
def elastic_force_at(p, lam, mu, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_wv, bond_inv_len,
                     bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar, particle_force, force_private):
    """f_p = sum_q G over all of p's intact bonds (`pair_force`, p's side of each pair) -> particle_force[p]: the
    GPU's form of the bond pass (one thread per particle, no atomics), the same formula as the CPU's pair pass."""
    has_active, has_crack = bond_active.shape[0] > 0, particle_crack.shape[0] > 0
    has_ep, has_mu = bond_ep.shape[0] > 0, mu > 0.0
    cp, vp = particle_coef[p], particle_volume[p]
    p_crack = has_crack and particle_crack[p] != 0
    f0 = f1 = f2 = 0.0
    for b in range(bond_start[p], bond_start[p + 1]):
        if has_active and bond_active[b] == 0:
            continue
        q = bond_nbr[b]
        _, e0, e1, e2, y0, y1, y2, z0, z1, z2 = bond_at(p, q, has_mu, has_crack, p_crack, particle_x, rest_x,
                                                        particle_crack, particle_Fbar)
        one_ep = 1.0 + bond_ep[b] if has_ep else 1.0
        g0, g1, g2 = pair_force(has_mu, lam, mu, cp, particle_coef[q], bond_wv[b] * bond_inv_len[b] * vp,
                                bond_inv_len[b], one_ep, e0, e1, e2, y0, y1, y2, z0, z1, z2)
        f0 += g0
        f1 += g1
        f2 += g2
    particle_force[p, 0] = f0
    particle_force[p, 1] = f1
    particle_force[p, 2] = f2


def pair_forces_cpu(start, end, lam, mu, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_wv,
                    bond_inv_len, bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar, particle_force,
                    force_private):
    """The CPU loop of ELASTIC_FORCES: the pair pass, then the per-thread arrays summed into particle_force."""
    elastic_forces(start, end, lam, mu, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_wv,
                   bond_inv_len, bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar, force_private)
    sum_forces(start, end, force_private, particle_force)


ELASTIC_FORCES = Kernel(elastic_force_at, pair_forces_cpu)


@njit(cache=True)
def elastic_energy(start, end, lam, mu, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr,
                   bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar):
    """Total strain energy sum_p W_p V_p (eq. 5, normalised; elastic strains only) of particles start..end-1 [J].
    Once per frame (the blow-up check), serial."""
    has_active = bond_active.shape[0] > 0
    has_crack = particle_crack.shape[0] > 0
    has_ep = bond_ep.shape[0] > 0
    total = 0.0
    for p in range(start, end):
        fp = particle_Fbar[p if mu > 0.0 else 0]
        wsum = 0.0
        for b in range(bond_start[p], bond_start[p + 1]):
            if has_active and bond_active[b] == 0:
                continue
            ep = bond_ep[b] if has_ep else 0.0
            q = bond_nbr[b]
            x0, x1, x2, r = bond_vector(rest_x, p, q)
            s = bond_vector(particle_x, p, q)[3] / r - 1.0 - ep
            sb = 0.0
            if mu > 0.0:
                sb = s if has_crack and particle_crack[p] else averaged_bond(fp, x0, x1, x2)[3] / r - 1.0 - ep
            wsum += influence(r, delta) * particle_volume[q] * (mu * sb * sb + 0.5 * lam * s * s)
        total += particle_coef[p] * wsum * particle_volume[p]
    return total


def bonds(solver, body: int, dt: float):
    """Bond forces of one elastic or plastic body (eqs. 6-7, 9) -> particle_force."""
    b, a, m = solver.model.bodies[body], solver.a, solver.m
    solver.backend.run(ELASTIC_FORCES, b.start, b.end, b.params.lam, b.params.mu, a.particle_x, m.rest_x,
                       m.particle_volume, a.bond_start, a.bond_nbr, a.bond_wv, a.bond_inv_len, a.bond_active,
                       a.bond_ep, a.particle_crack, m.particle_coef, a.particle_Fbar, a.particle_force,
                       a.particle_force_private)


def energy(solver, state, body: int) -> float:
    """Strain energy of one body [J] on the host State (Fbar must be current)."""
    b, m = solver.model.bodies[body], solver.model
    return elastic_energy(b.start, b.end, b.params.lam, b.params.mu, b.horizon, state.particle_x, m.rest_x,
                          m.particle_volume, state.bond_start, state.bond_nbr, state.bond_active, state.bond_ep,
                          state.particle_crack, m.particle_coef, state.particle_Fbar)


def effective_constants(lam: float, mu: float, density: float) -> dict:
    """Isotropic constants an interior particle reproduces (docs/method.md, 'Calibration')."""
    m = lam + 2.0 * mu
    return {
        "p_wave_modulus": m,
        "youngs_modulus": 5.0 * m / 6.0,
        "poisson_ratio": 0.25,
        "bulk_modulus": 5.0 * m / 9.0,
        "shear_modulus": m / 3.0,
        "wave_speed": math.sqrt(m / density),
    }


def constants(p: Params) -> dict:
    return effective_constants(p.lam, p.mu, p.density)


KIND = MaterialKind(
    name="elastic", schema=Schema, params=params, forces=bonds, constants=constants, energy=energy,
    uses_fbar=lambda p: p.mu > 0, fields=fields.PAIR,
)
