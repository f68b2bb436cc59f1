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

from pdmpm_cli.engine.bonds import bond_vector


@njit(cache=True, inline="always")
def averaged_bond(fbar, x0, x1, x2):
    """Ybar = Fbar xi (eq. 4's averaged deformed bond) and its length."""
    y0 = fbar[0, 0] * x0 + fbar[0, 1] * x1 + fbar[0, 2] * x2
    y1 = fbar[1, 0] * x0 + fbar[1, 1] * x1 + fbar[1, 2] * x2
    y2 = fbar[2, 0] * x0 + fbar[2, 1] * x1 + fbar[2, 2] * x2
    return y0, y1, y2, math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)


@njit(parallel=True, cache=True)
def elastic_forces(start, end, lam, mu, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr,
                   bond_active, bond_ep, particle_crack, particle_coef, particle_Fbar, particle_force):
    """Bond forces f_p (eqs. 6-7, 9) for particles start..end-1 of one elastic or plastic body -> particle_force."""
    has_active = bond_active.shape[0] > 0
    has_crack = particle_crack.shape[0] > 0
    has_ep = bond_ep.shape[0] > 0
    for p in prange(start, end):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        cp = particle_coef[p]
        fp = particle_Fbar[p]
        vp = particle_volume[p]
        for b in range(bond_start[p], bond_start[p + 1]):
            if has_active and bond_active[b] == 0:
                continue
            ep = bond_ep[b] if has_ep else 0.0
            q = bond_nbr[b]
            x0, x1, x2, r = bond_vector(rest_x, p, q)
            e0, e1, e2, l = bond_vector(particle_x, p, q)
            cq = particle_coef[q]
            a = (1.0 - r / delta) / r * vp * particle_volume[q]
            if l > 0.0:
                g = a * lam * (l / r - 1.0 - ep) * (cp + cq) / l
                f0 += g * e0
                f1 += g * e1
                f2 += g * e2
            if mu > 0.0:
                fq = particle_Fbar[q]
                for side in range(2):
                    fm = fp if side == 0 else fq
                    c = cp if side == 0 else cq
                    if has_crack and particle_crack[p if side == 0 else q]:
                        y0, y1, y2, ly = e0, e1, e2, l
                    else:
                        y0, y1, y2, ly = averaged_bond(fm, x0, x1, x2)
                    if ly > 0.0:
                        g = a * 2.0 * mu * c * (ly / r - 1.0 - ep) / ly
                        f0 += g * y0
                        f1 += g * y1
                        f2 += g * y2
        particle_force[p, 0] = f0
        particle_force[p, 1] = f1
        particle_force[p, 2] = f2


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
                   state.particle_crack, model.particle_coef, fbar, state.particle_force)


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
