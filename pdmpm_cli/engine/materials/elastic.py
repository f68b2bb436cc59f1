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

import numpy as np
from numba import njit, prange

from pdmpm_cli.engine.bonds import bond_vector, chunk_width
from pdmpm_cli.engine.parallel import VECTOR_MATH, particle_chunks

TINY = 1e-300  # floor of a squared bond length: a zero-length bond gets a finite coefficient times a zero vector


@njit(cache=True, inline="always")
def averaged_bond(fbar, x0, x1, x2):
    """Ybar = Fbar xi (eq. 4's averaged deformed bond) and its length."""
    y0 = fbar[0, 0] * x0 + fbar[0, 1] * x1 + fbar[0, 2] * x2
    y1 = fbar[1, 0] * x0 + fbar[1, 1] * x1 + fbar[1, 2] * x2
    y2 = fbar[2, 0] * x0 + fbar[2, 1] * x1 + fbar[2, 2] * x2
    return y0, y1, y2, math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)


@njit(parallel=True, cache=True, fastmath=VECTOR_MATH, error_model="numpy")
def elastic_forces(start, end, lam, mu, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr,
                   bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar, particle_force, chunks):
    """Bond forces f_p (eqs. 6-7, 9) for particles start..end-1 of one elastic or plastic body -> particle_force.

    Per particle, a gather loop writes each intact bond's xi, eta, Ybar_p and Ybar_q into contiguous scratch
    rows; a second loop without gathers evaluates the four lengths and strains per bond as SIMD. Writing
    (|y|/|xi| - 1 - e_p)/|y| as 1/|xi| - (1 + e_p)/|y| leaves one division per strain."""
    has_active = bond_active.shape[0] > 0
    has_crack = particle_crack.shape[0] > 0
    has_ep = bond_ep.shape[0] > 0
    has_mu = mu > 0.0
    n = end - start
    inv_delta = 1.0 / delta
    for t in prange(chunks):
        lo, hi = start + t * n // chunks, start + (t + 1) * n // chunks
        s = np.zeros((15, chunk_width(bond_start, lo, hi)))  # xi, eta, Ybar_p, Ybar_q (3 each), V_q, c_q, 1 + e_p
        for p in range(lo, hi):
            # Everything of p in scalars: the stores into s would otherwise make the compiler reload it per bond.
            r0, r1, r2 = rest_x[p, 0], rest_x[p, 1], rest_x[p, 2]
            p0, p1, p2 = particle_x[p, 0], particle_x[p, 1], particle_x[p, 2]
            f = p if has_mu else 0
            a00, a01, a02 = particle_Fbar[f, 0, 0], particle_Fbar[f, 0, 1], particle_Fbar[f, 0, 2]
            a10, a11, a12 = particle_Fbar[f, 1, 0], particle_Fbar[f, 1, 1], particle_Fbar[f, 1, 2]
            a20, a21, a22 = particle_Fbar[f, 2, 0], particle_Fbar[f, 2, 1], particle_Fbar[f, 2, 2]
            p_crack = has_crack and particle_crack[p] != 0
            m = 0
            for b in range(bond_start[p], bond_start[p + 1]):
                if has_active and bond_active[b] == 0:
                    continue
                q = bond_nbr[b]
                x0, x1, x2 = rest_x[q, 0] - r0, rest_x[q, 1] - r1, rest_x[q, 2] - r2
                e0, e1, e2 = particle_x[q, 0] - p0, particle_x[q, 1] - p1, particle_x[q, 2] - p2
                s[0, m], s[1, m], s[2, m] = x0, x1, x2
                s[3, m], s[4, m], s[5, m] = e0, e1, e2
                if has_mu:
                    if p_crack:
                        s[6, m], s[7, m], s[8, m] = e0, e1, e2
                    else:
                        s[6, m] = a00 * x0 + a01 * x1 + a02 * x2
                        s[7, m] = a10 * x0 + a11 * x1 + a12 * x2
                        s[8, m] = a20 * x0 + a21 * x1 + a22 * x2
                    if has_crack and particle_crack[q] != 0:
                        s[9, m], s[10, m], s[11, m] = e0, e1, e2
                    else:
                        for i in range(3):
                            s[9 + i, m] = (particle_Fbar[q, i, 0] * x0 + particle_Fbar[q, i, 1] * x1
                                           + particle_Fbar[q, i, 2] * x2)
                s[12, m] = particle_volume[q]
                s[13, m] = particle_coef[q]
                s[14, m] = 1.0 + bond_ep[b] if has_ep else 1.0
                m += 1
            cp = particle_coef[p]
            f0 = f1 = f2 = 0.0
            for k in range(m):
                r = math.sqrt(s[0, k] * s[0, k] + s[1, k] * s[1, k] + s[2, k] * s[2, k])
                ir = 1.0 / r
                a = (1.0 - r * inv_delta) * ir * s[12, k]
                e0, e1, e2 = s[3, k], s[4, k], s[5, k]
                g = a * lam * (cp + s[13, k]) * (ir - s[14, k] / math.sqrt(max(e0 * e0 + e1 * e1 + e2 * e2, TINY)))
                f0 += g * e0
                f1 += g * e1
                f2 += g * e2
                if has_mu:
                    y0, y1, y2 = s[6, k], s[7, k], s[8, k]
                    g = a * 2.0 * mu * cp * (ir - s[14, k] / math.sqrt(max(y0 * y0 + y1 * y1 + y2 * y2, TINY)))
                    f0 += g * y0
                    f1 += g * y1
                    f2 += g * y2
                    y0, y1, y2 = s[9, k], s[10, k], s[11, k]
                    g = a * 2.0 * mu * s[13, k] * (ir - s[14, k] / math.sqrt(max(y0 * y0 + y1 * y1 + y2 * y2, TINY)))
                    f0 += g * y0
                    f1 += g * y1
                    f2 += g * y2
            vp = particle_volume[p]
            particle_force[p, 0] = f0 * vp
            particle_force[p, 1] = f1 * vp
            particle_force[p, 2] = f2 * vp


@njit(parallel=True, cache=True)
def elastic_energy(start, end, lam, mu, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr,
                   bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar):
    """Total strain energy sum_p W_p V_p (eq. 5, normalised; elastic strains only) of particles start..end-1 [J]."""
    has_active = bond_active.shape[0] > 0
    has_crack = particle_crack.shape[0] > 0
    has_ep = bond_ep.shape[0] > 0
    total = 0.0
    for p in prange(start, end):
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
            wsum += (1.0 - r / delta) * particle_volume[q] * (mu * sb * sb + 0.5 * lam * s * s)
        total += particle_coef[p] * wsum * particle_volume[p]
    return total


DUMMY_FBAR = np.zeros((1, 3, 3))  # stands in for Fbar when mu = 0 and no body needs it


def forces(model, state, body: int, dt: float):
    """Phase bonds:elastic (and bonds:plastic): eqs. 6-7, 9 for one body -> state.particle_force."""
    start, end = model.body_ranges[body]
    mat = model.materials[body]
    fbar = state.particle_Fbar if len(state.particle_Fbar) else DUMMY_FBAR
    elastic_forces(start, end, mat.lam, mat.mu, model.body_horizon[body], state.particle_x, model.rest_x,
                   model.particle_volume, state.bond_start, state.bond_nbr, state.bond_active, state.bond_ep,
                   state.particle_crack, model.particle_coef, fbar, state.particle_force, particle_chunks())


def energy(model, state, body: int) -> float:
    """Strain energy of one body [J] (Fbar must be current)."""
    start, end = model.body_ranges[body]
    mat = model.materials[body]
    fbar = state.particle_Fbar if len(state.particle_Fbar) else DUMMY_FBAR
    return elastic_energy(start, end, mat.lam, mat.mu, model.body_horizon[body], state.particle_x, model.rest_x,
                          model.particle_volume, state.bond_start, state.bond_nbr, state.bond_active, state.bond_ep,
                          state.particle_crack, model.particle_coef, fbar)


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
