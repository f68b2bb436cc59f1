"""Elastic peridynamic bonds (paper eqs. 5-7) with the per-particle calibration of docs/method.md.

Energy density of particle p (eq. 5, normalised):
    W_p = c_p sum_q w V_q [ mu (|Ybar|/|xi| - 1)^2 + lam/2 (|eta|/|xi| - 1)^2 ],   c_p = 5 / omega_p,
with Ybar = Fbar_p xi. Under a homogeneous small strain eps this is the isotropic solid
W = (M/6) (tr(eps)^2 + 2 eps:eps), M = lam + 2 mu: E_eff = 5 M / 6, nu_eff = 1/4, P-wave modulus M.
Bond force state (eq. 6 in strains), acting on p along the bond:
    T<p,q> = c_p w / |xi| [ 2 mu (|Ybar|/|xi| - 1) dir(Ybar) + lam (|eta|/|xi| - 1) dir(eta) ]
and f_p = sum_q (T<p,q> - T<q,p>) V_p V_q (eq. 2, 7), which conserves linear momentum pairwise.
"""

import math

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
                   particle_coef, particle_Fbar, particle_force):
    """Bond forces f_p (eqs. 6-7) for particles start..end-1 of one elastic body -> particle_force."""
    for p in prange(start, end):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        cp = particle_coef[p]
        fp = particle_Fbar[p]
        vp = particle_volume[p]
        for b in range(bond_start[p], bond_start[p + 1]):
            q = bond_nbr[b]
            x0, x1, x2, r = bond_vector(rest_x, p, q)
            e0, e1, e2, l = bond_vector(particle_x, p, q)
            cq = particle_coef[q]
            a = (1.0 - r / delta) / r * vp * particle_volume[q]
            if l > 0.0:
                g = a * lam * (l / r - 1.0) * (cp + cq) / l
                f0 += g * e0
                f1 += g * e1
                f2 += g * e2
            if mu > 0.0:
                fq = particle_Fbar[q]
                for side in range(2):
                    fm = fp if side == 0 else fq
                    c = cp if side == 0 else cq
                    y0, y1, y2, ly = averaged_bond(fm, x0, x1, x2)
                    if ly > 0.0:
                        g = a * 2.0 * mu * c * (ly / r - 1.0) / ly
                        f0 += g * y0
                        f1 += g * y1
                        f2 += g * y2
        particle_force[p, 0] = f0
        particle_force[p, 1] = f1
        particle_force[p, 2] = f2


@njit(parallel=True, cache=True)
def elastic_energy(start, end, lam, mu, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr,
                   particle_coef, particle_Fbar):
    """Total strain energy sum_p W_p V_p (eq. 5, normalised) of particles start..end-1 [J]."""
    total = 0.0
    for p in prange(start, end):
        fp = particle_Fbar[p if mu > 0.0 else 0]
        wsum = 0.0
        for b in range(bond_start[p], bond_start[p + 1]):
            q = bond_nbr[b]
            x0, x1, x2, r = bond_vector(rest_x, p, q)
            s = bond_vector(particle_x, p, q)[3] / r - 1.0
            sb = 0.0
            if mu > 0.0:
                sb = averaged_bond(fp, x0, x1, x2)[3] / r - 1.0
            wsum += (1.0 - r / delta) * particle_volume[q] * (mu * sb * sb + 0.5 * lam * s * s)
        total += particle_coef[p] * wsum * particle_volume[p]
    return total


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
