"""Per-bond deviatoric plasticity (paper eqs. 8-11, METHOD.md section 3, docs/method.md 'Plastic bonds').

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
"""

import math

import numpy as np
from numba import njit, prange

from pdmpm_cli.engine.bonds import bond_vector
from pdmpm_cli.engine.materials.elastic import DUMMY_FBAR, averaged_bond


@njit(parallel=True, cache=True)
def bond_dilatation(start, end, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_active,
                    particle_theta):
    """theta_p = 3 sum w |xi|^2 s V_q / sum w |xi|^2 V_q over intact bonds (e_iso of eq. 9) -> particle_theta."""
    has_active = bond_active.shape[0] > 0
    for p in prange(start, end):
        num = 0.0
        den = 0.0
        for b in range(bond_start[p], bond_start[p + 1]):
            if has_active and bond_active[b] == 0:
                continue
            q = bond_nbr[b]
            r = bond_vector(rest_x, p, q)[3]
            l = bond_vector(particle_x, p, q)[3]
            wv = (1.0 - r / delta) * r * r * particle_volume[q]
            num += wv * (l / r - 1.0)
            den += wv
        particle_theta[p] = 3.0 * num / den if den > 0.0 else 0.0


@njit(parallel=True, cache=True)
def plastic_return_map(start, end, lam, mu, psi, particle_x, rest_x, bond_start, bond_nbr, bond_active, particle_crack,
                       particle_Fbar, particle_theta, bond_ep):
    """Eqs. 10-11: project every yielding bond of particles start..end-1 onto f = 0, updating bond_ep in place.

    The bond strain is the one the force of eq. 9 acts on (elastic.py): (lam s + mu (sbar_p + sbar_q)) / M, with
    s = |eta|/|xi| - 1 and sbar = |Fbar xi|/|xi| - 1 (s for a crack particle). Returns the largest f / psi_p after
    the update (0 up to round-off when the map is exact)."""
    has_active = bond_active.shape[0] > 0
    has_crack = particle_crack.shape[0] > 0
    modulus = lam + 2.0 * mu
    limit = math.sqrt(2.0 * psi)
    worst = np.zeros(end - start)
    for p in prange(start, end):
        tp = particle_theta[p]
        p_crack = has_crack and particle_crack[p] != 0
        fmax = -1.0
        for b in range(bond_start[p], bond_start[p + 1]):
            if has_active and bond_active[b] == 0:
                continue
            q = bond_nbr[b]
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
                e = modulus * (e_dev - bond_ep[b])
            fmax = max(fmax, (0.5 * e * e - psi) / psi)
        worst[p - start] = fmax
    return worst.max() if end > start else -1.0


@njit(parallel=True, cache=True)
def particle_plastic_strain(bond_start, bond_ep, out):
    """Mean |e_p| over each particle's bonds: a scalar plastic-strain field for output [-]."""
    for p in prange(out.shape[0]):
        n = bond_start[p + 1] - bond_start[p]
        acc = 0.0
        for b in range(bond_start[p], bond_start[p + 1]):
            acc += abs(bond_ep[b])
        out[p] = acc / n if n > 0 else 0.0


def return_map(model, state, body: int, dt: float) -> float:
    """Phase return_map:plastic for one body: dilatations, then eqs. 10-11 on every bond; returns max f/psi_p."""
    start, end = model.body_ranges[body]
    mat = model.materials[body]
    bond_dilatation(start, end, model.body_horizon[body], state.particle_x, model.rest_x, model.particle_volume,
                    state.bond_start, state.bond_nbr, state.bond_active, state.particle_theta)
    fbar = state.particle_Fbar if len(state.particle_Fbar) else DUMMY_FBAR
    return plastic_return_map(start, end, mat.lam, mat.mu, mat.yield_psi, state.particle_x, model.rest_x,
                              state.bond_start, state.bond_nbr, state.bond_active, state.particle_crack, fbar,
                              state.particle_theta, state.bond_ep)
