"""Peridynamic families and the averaged deformation (paper eq. 4; docs/method.md).

Families are stored in CSR form: the bonds of particle p are bond_nbr[bond_start[p]:bond_start[p+1]].
Bonds join particles of the same body within the horizon delta (strictly: w(delta) = 0 adds nothing).
Influence w(|xi|) = 1 - |xi| / delta (the paper's "linear weight function").
"""

import math

import numpy as np
from numba import njit, prange
from scipy.spatial import cKDTree

from pdmpm_cli.engine.kernel import Kernel

# Regularisation of rank-deficient shape tensors (cloth, chains): K + EPS tr(K) I, exact within the span.
RANK_TOL = 1e-6
EPS = 1e-9


@njit(cache=True, inline="always")
def influence(r, delta):
    """w(|xi|) = 1 - |xi| / delta, the paper's linear influence function (its one definition)."""
    return 1.0 - r / delta


@njit(cache=True, inline="always")
def bond_vector(x, p, q):
    """(x_q - x_p) and its length: the reference bond xi on rest positions, eta on current ones."""
    d0 = x[q, 0] - x[p, 0]
    d1 = x[q, 1] - x[p, 1]
    d2 = x[q, 2] - x[p, 2]
    return d0, d1, d2, math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


def build_families(rest_x: np.ndarray, body_ranges, body_horizon, body_pairs=None) -> tuple[np.ndarray, np.ndarray]:
    """CSR families, both directions stored: bonds within each body's horizon, or, where `body_pairs[i]` is
    given ((m, 2) local indices, Voronoi mode), exactly those pairs."""
    src, dst = [], []
    for i, ((start, end), delta) in enumerate(zip(body_ranges, body_horizon)):
        pts = rest_x[start:end]
        given = body_pairs[i] if body_pairs is not None else None
        if given is not None:
            pairs = np.asarray(given, dtype=np.int64).reshape(-1, 2) + start
        else:
            pairs = cKDTree(pts).query_pairs(delta, output_type="ndarray")
            if len(pairs):
                d = np.linalg.norm(pts[pairs[:, 1]] - pts[pairs[:, 0]], axis=1)
                pairs = pairs[d < delta * (1.0 - 1e-12)]
            pairs = pairs + start
        src += [pairs[:, 0], pairs[:, 1]]
        dst += [pairs[:, 1], pairs[:, 0]]
    n = len(rest_x)
    src = np.concatenate(src) if src else np.zeros(0, np.int64)
    dst = np.concatenate(dst) if dst else np.zeros(0, np.int64)
    order = np.lexsort((dst, src))
    bond_nbr = dst[order].astype(np.int32)
    bond_start = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=bond_start[1:])
    return bond_start, bond_nbr


def drop_bonds(bond_start: np.ndarray, bond_nbr: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The CSR families without the bonds where `keep` is False (order preserved)."""
    owner = np.repeat(np.arange(len(bond_start) - 1), np.diff(bond_start))
    new_start = np.zeros_like(bond_start)
    np.cumsum(np.bincount(owner[keep], minlength=len(bond_start) - 1), out=new_start[1:])
    return new_start, bond_nbr[keep]


@njit(cache=True, inline="always")
def invert3(a00, a01, a02, a10, a11, a12, a20, a21, a22, out):
    """out = the inverse of the 3 x 3 matrix a (adjugate over determinant; no LAPACK: it compiles in a fraction of
    the time)."""
    c00, c01, c02 = a11 * a22 - a12 * a21, a12 * a20 - a10 * a22, a10 * a21 - a11 * a20
    inv_det = 1.0 / (a00 * c00 + a01 * c01 + a02 * c02)
    out[0, 0], out[0, 1], out[0, 2] = c00 * inv_det, (a02 * a21 - a01 * a22) * inv_det, (a01 * a12 - a02 * a11) * inv_det
    out[1, 0], out[1, 1], out[1, 2] = c01 * inv_det, (a00 * a22 - a02 * a20) * inv_det, (a02 * a10 - a00 * a12) * inv_det
    out[2, 0], out[2, 1], out[2, 2] = c02 * inv_det, (a01 * a20 - a00 * a21) * inv_det, (a00 * a11 - a01 * a10) * inv_det


@njit(cache=True)
def invert_shape_tensor(k, out):
    """out = K^-1, or the inverse of K + EPS tr(K) I when K is rank-deficient (shells, cloth)."""
    tr = k[0, 0] + k[1, 1] + k[2, 2]
    if tr <= 0.0:
        for a in range(3):
            for c in range(3):
                out[a, c] = 0.0
        return
    det = (k[0, 0] * (k[1, 1] * k[2, 2] - k[1, 2] * k[2, 1]) - k[0, 1] * (k[1, 0] * k[2, 2] - k[1, 2] * k[2, 0])
           + k[0, 2] * (k[1, 0] * k[2, 1] - k[1, 1] * k[2, 0]))
    reg = EPS * tr if det <= RANK_TOL * (tr / 3.0) ** 3 else 0.0
    invert3(k[0, 0] + reg, k[0, 1], k[0, 2], k[1, 0], k[1, 1] + reg, k[1, 2], k[2, 0], k[2, 1], k[2, 2] + reg, out)


@njit(cache=True)
def reference_family_terms(rest_x, particle_volume, bond_start, bond_nbr, particle_body, body_horizon,
                           particle_omega, particle_Kinv, single=False):
    """Weighted volume omega_p = sum_q w V_q and the inverse shape tensor K_p^-1 (eq. 4, second factor). Once per
    run, serial: a parallel loop would cost more to compile than it saves. `single`: the State stores w V_q in
    float32 (simulation.precision), so K_p sums the rounded weights the Fbar pass will read, and Fbar at rest is
    the identity to float64's round-off."""
    for p in range(rest_x.shape[0]):
        delta = body_horizon[particle_body[p]]
        k = np.zeros((3, 3))
        om = 0.0
        for b in range(bond_start[p], bond_start[p + 1]):
            q = bond_nbr[b]
            x0, x1, x2, r = bond_vector(rest_x, p, q)
            wv = influence(r, delta) * particle_volume[q]
            if single:
                wv = float(np.float32(wv))
            om += wv
            xi = (x0, x1, x2)
            for a in range(3):
                for c in range(3):
                    k[a, c] += wv * xi[a] * xi[c]
        particle_omega[p] = om
        invert_shape_tensor(k, particle_Kinv[p])


@njit(cache=True)
def chunk_width(bond_start, lo, hi):
    """Largest family in particles lo..hi-1: the length of a chunk's bond scratch rows."""
    width = 0
    for p in range(lo, hi):
        width = max(width, bond_start[p + 1] - bond_start[p])
    return width


@njit(cache=True)
def bond_reference_terms(rest_x, particle_volume, bond_start, bond_nbr, particle_body, body_horizon, bond_wv,
                         bond_inv_len):
    """Per bond p -> q, the reference factors the bond passes reuse every step: w(|xi|) V_q (eq. 4's weight times
    the neighbour's volume) -> bond_wv and 1 / |xi| -> bond_inv_len. Once per run, serial."""
    for p in range(rest_x.shape[0]):
        delta = body_horizon[particle_body[p]]
        for b in range(bond_start[p], bond_start[p + 1]):
            q = bond_nbr[b]
            r = bond_vector(rest_x, p, q)[3]
            bond_wv[b] = influence(r, delta) * particle_volume[q]
            bond_inv_len[b] = 1.0 / r


@njit(cache=True, inline="always")
def times_kinv(p, a00, a01, a02, a10, a11, a12, a20, a21, a22, particle_Kinv, particle_Fbar):
    """Fbar_p = A K_p^-1 with A = sum_q w V_q eta (x) xi (eq. 4's second factor) -> particle_Fbar[p]."""
    k = particle_Kinv[p]
    for c in range(3):
        particle_Fbar[p, 0, c] = a00 * k[0, c] + a01 * k[1, c] + a02 * k[2, c]
        particle_Fbar[p, 1, c] = a10 * k[0, c] + a11 * k[1, c] + a12 * k[2, c]
        particle_Fbar[p, 2, c] = a20 * k[0, c] + a21 * k[1, c] + a22 * k[2, c]


@njit(cache=True, inline="always")
def add_outer(a00, a01, a02, a10, a11, a12, a20, a21, a22, e0, e1, e2, x0, x1, x2):
    """The nine sums of eq. 4, A = sum_q w V_q eta (x) xi, with one bond's term added (x = w V_q xi)."""
    return (a00 + e0 * x0, a01 + e0 * x1, a02 + e0 * x2, a10 + e1 * x0, a11 + e1 * x1, a12 + e1 * x2,
            a20 + e2 * x0, a21 + e2 * x1, a22 + e2 * x2)


@njit(cache=True, inline="always")
def fbar_of_rows(p, s, m, particle_Kinv, particle_Fbar):
    """Fbar_p (eq. 4) from a family gathered into scratch rows (xi in rows 0-2, eta in 3-5, w V_q in 6, bonds
    0..m-1): the sums of w V_q eta (x) xi in bond order (no fastmath: the order is fixed), then times K_p^-1.
    plastic.fbar_dilatation's form of eq. 4, whose dilatations reuse the rows (to the bit `averaged_deformation_at`'s
    sums)."""
    a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = 0.0
    for k in range(m):
        w = s[6, k]
        x0, x1, x2 = w * s[0, k], w * s[1, k], w * s[2, k]
        a00, a01, a02, a10, a11, a12, a20, a21, a22 = add_outer(a00, a01, a02, a10, a11, a12, a20, a21, a22, s[3, k],
                                                                s[4, k], s[5, k], x0, x1, x2)
    times_kinv(p, a00, a01, a02, a10, a11, a12, a20, a21, a22, particle_Kinv, particle_Fbar)


@njit(cache=True, inline="always")
def averaged_deformation_at(p, particle_x, rest_x, bond_start, bond_nbr, bond_wv, particle_Kinv, particle_Fbar,
                            chunks):
    """Fbar_p = (sum_q w V_q eta (x) xi) K_p^-1 (eq. 4 with the correction of docs/method.md: eta, not w, in front)
    over p's whole reference family: only intact particles use Fbar (a particle with a broken bond uses eta instead,
    elastic.py), so the sum always matches the K^-1 it is multiplied by. One loop gathering directly, summing in bond
    order: the GPU's per-thread form and, inlined, the CPU's (`averaged_deformation`). Without fastmath the sums
    cannot become SIMD across bonds, and a gather into scratch rows first (as `fbar_of_rows`) cost more than it saved
    (cloth:soft 59 -> 52 ns per particle, beams 190 -> 168)."""
    r0, r1, r2 = rest_x[p, 0], rest_x[p, 1], rest_x[p, 2]
    p0, p1, p2 = particle_x[p, 0], particle_x[p, 1], particle_x[p, 2]
    a00 = a01 = a02 = a10 = a11 = a12 = a20 = a21 = a22 = 0.0
    for b in range(bond_start[p], bond_start[p + 1]):
        q, w = bond_nbr[b], bond_wv[b]
        x0, x1, x2 = w * (rest_x[q, 0] - r0), w * (rest_x[q, 1] - r1), w * (rest_x[q, 2] - r2)
        a00, a01, a02, a10, a11, a12, a20, a21, a22 = add_outer(a00, a01, a02, a10, a11, a12, a20, a21, a22,
                                                                particle_x[q, 0] - p0, particle_x[q, 1] - p1,
                                                                particle_x[q, 2] - p2, x0, x1, x2)
    times_kinv(p, a00, a01, a02, a10, a11, a12, a20, a21, a22, particle_Kinv, particle_Fbar)


@njit(parallel=True, cache=True, error_model="numpy")  # no fastmath: see parallel.py
def averaged_deformation(start, end, particle_x, rest_x, bond_start, bond_nbr, bond_wv, particle_Kinv,
                         particle_Fbar, chunks):
    """`averaged_deformation_at` (eq. 4) for particles start..end-1, in `chunks` fixed particle ranges."""
    n = end - start
    for t in prange(chunks):
        for p in range(start + t * n // chunks, start + (t + 1) * n // chunks):
            averaged_deformation_at(p, particle_x, rest_x, bond_start, bond_nbr, bond_wv, particle_Kinv,
                                    particle_Fbar, chunks)


AVERAGED_DEFORMATION = Kernel(averaged_deformation_at, averaged_deformation)


def calibration_coefficients(particle_omega, particle_body, body_horizon):
    """c_p = 5 / omega_p (docs/method.md): exact energy under isotropic stretch for every particle.

    Dividing by the particle's own weighted volume is the surface correction: a particle near a free
    surface has fewer bonds and gets a larger c_p. omega_p is floored at 1/8 of the full-ball value
    pi delta^3 / 3 (a cube corner) so that nearly isolated particles do not become arbitrarily stiff."""
    full = np.pi * body_horizon[particle_body] ** 3 / 3.0
    coef = 5.0 / np.maximum(particle_omega, full / 8.0)
    coef[particle_omega <= 0.0] = 0.0
    return coef


@njit(cache=True)
def bond_time_steps(rest_x, particle_volume, bond_start, bond_nbr, particle_body, body_horizon, body_modulus,
                    body_density, particle_coef, out):
    """Per-particle critical step sqrt(2 rho / sum_q k_pq / V_p) (Silling & Askari 2005) for our bonds (once per
    run, serial).

    k_pq = (c_p + c_q) w M V_p V_q / |xi|^2 is the axial stiffness of bond p-q under eqs. 6-7."""
    for p in range(rest_x.shape[0]):
        body = particle_body[p]
        delta = body_horizon[body]
        k = 0.0
        for b in range(bond_start[p], bond_start[p + 1]):
            q = bond_nbr[b]
            r = bond_vector(rest_x, p, q)[3]
            k += (particle_coef[p] + particle_coef[q]) * influence(r, delta) * particle_volume[q] / (r * r)
        k *= body_modulus[body]
        out[p] = math.sqrt(2.0 * body_density[body] / k) if k > 0.0 else np.inf
