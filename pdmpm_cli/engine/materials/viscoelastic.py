"""Linearised peridynamics for viscoelastic materials (paper section 5, eqs. 12-20).

The model is structureless: the configuration of the previous force evaluation is the reference, and the
force state grows by the modulus state applied to the step's displacement (eq. 12: T = T0 + K.U). We apply
K.U at O(family) cost as the linear peridynamic solid (LPS, Silling 2007) force of the increment, which
equals eq. 19's modulus state to first order:
    m_p      = sum_q w L0^2 V_q                                        (weighted volume, w = 1 - L0 / delta)
    de       = |x_q - x_p| - |xprev_q - xprev_p|                       (incremental extension)
    dtheta_p = (3 / m_p) sum_q w L0 de V_q                             (incremental dilatation)
    dt_pq    = (3 K dtheta_p / m_p) w L0  +  (15 mu / m_p) w (de - dtheta_p L0 / 3)   (bulk + deviatoric part)
L0 is the bond's formation length. Relaxation is the standard linear solid (Mitchell 2011; Peridigm
twoPoint_SLS): the bulk part and (1 - l) of the deviatoric part accumulate, a fraction l of the deviatoric
part relaxes with time tau (effective shear viscosity ~ l mu tau).

Each directed bond stores the pair sums t_pq + t_qp of both branches (bond_force_el, bond_force_visc), so
no reverse-bond index is needed; both copies of a bond hold bitwise-identical values and
f_p = sum_q (t_pq + t_qp) dir(eta) V_p V_q conserves linear momentum pairwise. bond_len0 < 0 marks a
broken bond. Families are rebuilt from current neighbours (rebuild_families) so streams merge and split.
"""

import math

import numpy as np
from numba import njit, prange
from scipy.spatial import cKDTree

from pdmpm_cli.engine.bonds import bond_vector


@njit(parallel=True, cache=True)
def lps_weighted_volume(start, end, delta, particle_volume, bond_start, bond_nbr, bond_len0, particle_m):
    """m_p = sum_q w L0^2 V_q over intact bonds (LPS weighted volume) -> particle_m[start:end]."""
    for p in prange(start, end):
        m = 0.0
        for b in range(bond_start[p], bond_start[p + 1]):
            l0 = bond_len0[b]
            if l0 > 0.0:
                m += (1.0 - l0 / delta) * l0 * l0 * particle_volume[bond_nbr[b]]
        particle_m[p] = m


@njit(parallel=True, cache=True)
def incremental_dilatation(start, end, delta, particle_x, particle_x_prev, particle_volume, bond_start, bond_nbr,
                           bond_len0, particle_m, particle_dtheta):
    """dtheta_p = (3 / m_p) sum_q w L0 de V_q, the dilatation of the step's increment -> particle_dtheta."""
    for p in prange(start, end):
        s = 0.0
        for b in range(bond_start[p], bond_start[p + 1]):
            l0 = bond_len0[b]
            if l0 > 0.0:
                q = bond_nbr[b]
                de = bond_vector(particle_x, p, q)[3] - bond_vector(particle_x_prev, p, q)[3]
                s += (1.0 - l0 / delta) * l0 * de * particle_volume[q]
        particle_dtheta[p] = 3.0 * s / particle_m[p] if particle_m[p] > 0.0 else 0.0


@njit(cache=True, inline="always")
def one_sided_increment(bulk, mu, dtheta, m, w, l0, de):
    """Bulk and deviatoric parts of the LPS force increment dt of one side of a bond (eq. 12's K.U)."""
    return 3.0 * bulk * dtheta / m * w * l0, 15.0 * mu / m * w * (de - dtheta * l0 / 3.0)


@njit(cache=True)
def relaxation_factors(tau, dt):
    """Decay exp(-dt/tau) and gain (tau/dt)(1 - exp(-dt/tau)): exact SLS update for a constant rate over dt.

    tau = inf gives (1, 1) (no relaxation), tau = 0 gives (0, 0) (the relaxing part vanishes at once)."""
    if tau <= 0.0:
        return 0.0, 0.0
    x = dt / tau
    if x == 0.0:
        return 1.0, 1.0
    return math.exp(-x), -math.expm1(-x) / x


@njit(parallel=True, cache=True)
def viscoelastic_forces(start, end, bulk, mu, tau, fraction, break_stretch, delta, dt, particle_x, particle_x_prev,
                        particle_volume, bond_start, bond_nbr, particle_m, particle_dtheta, bond_len0, bond_force_el,
                        bond_force_visc, particle_force):
    """Eq. 12 with SLS relaxation -> bond_len0 (breaks), bond_force_el/visc, particle_force; returns bonds broken.

    Over-stretched bonds break first (both copies in the same call, counted as 2). Then every intact bond's pair
    forces grow by the step's LPS increment and f_p = sum_q (el + visc) dir(eta) V_p V_q overwrites particle_force."""
    decay, gain = relaxation_factors(tau, dt)
    keep = 1.0 - fraction
    broken = 0
    for p in prange(start, end):
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        vp = particle_volume[p]
        for b in range(bond_start[p], bond_start[p + 1]):
            l0 = bond_len0[b]
            if l0 <= 0.0:
                continue
            q = bond_nbr[b]
            e0, e1, e2, l = bond_vector(particle_x, p, q)
            if l / l0 - 1.0 > break_stretch:
                bond_len0[b] = -1.0
                bond_force_el[b] = 0.0
                bond_force_visc[b] = 0.0
                broken += 1
                continue
            de = l - bond_vector(particle_x_prev, p, q)[3]
            w = 1.0 - l0 / delta
            # Same operations in the same order on both copies: lower index first, then higher.
            lo = min(p, q)
            hi = max(p, q)
            b_lo, d_lo = one_sided_increment(bulk, mu, particle_dtheta[lo], particle_m[lo], w, l0, de)
            b_hi, d_hi = one_sided_increment(bulk, mu, particle_dtheta[hi], particle_m[hi], w, l0, de)
            ddev = d_lo + d_hi
            bond_force_el[b] += (b_lo + b_hi) + keep * ddev
            bond_force_visc[b] = bond_force_visc[b] * decay + fraction * ddev * gain
            if l > 0.0:
                g = (bond_force_el[b] + bond_force_visc[b]) * (vp * particle_volume[q]) / l
                f0 += g * e0
                f1 += g * e1
                f2 += g * e2
        particle_force[p, 0] = f0
        particle_force[p, 1] = f1
        particle_force[p, 2] = f2
    return broken


@njit(cache=True)
def lps_stress(p, particle_x, particle_volume, bond_start, bond_nbr, bond_pair_force):
    """Stress of particle p, sigma = sum_q (pair / 2) dir(eta) (x) eta V_q [Pa] (Lehoucq & Silling 2008).

    Equals the continuum stress for an interior particle under a homogeneous deformation, where t_pq = t_qp."""
    s = np.zeros((3, 3))
    for b in range(bond_start[p], bond_start[p + 1]):
        q = bond_nbr[b]
        e0, e1, e2, l = bond_vector(particle_x, p, q)
        if l > 0.0:
            g = 0.5 * bond_pair_force[b] * particle_volume[q] / l
            e = (e0, e1, e2)
            for i in range(3):
                for j in range(3):
                    s[i, j] += g * e[i] * e[j]
    return s


def rebuild_families(particle_x, bond_start, bond_nbr, bond_arrays, ranges,
                     visco_names=("bond_len0", "bond_force_el", "bond_force_visc")):
    """Families of the bodies in `ranges` rebuilt from current neighbours; all other bonds kept as they are.

    ranges: (start, end, delta) of each rebuilt body. A pair within delta that was an intact bond keeps every
    per-bond value; a new pair (or a broken one, visco_names[0] < 0) starts with visco_names[0] = current
    length and 0 in every other array; pairs beyond delta are dropped. Other bodies' bonds and values are
    relocated unchanged. The CSR must be sorted by (p, q) (build_families' order) and stays so."""
    missing = [name for name in visco_names if name not in bond_arrays]
    if missing:
        raise KeyError(f"rebuild_families needs the per-bond arrays {missing}")
    n = len(particle_x)
    src = np.repeat(np.arange(n, dtype=np.int64), np.diff(bond_start))
    old_keys = src * n + bond_nbr
    rebuilt = np.zeros(n, dtype=bool)
    for start, end, _ in ranges:
        rebuilt[start:end] = True
    kept = np.flatnonzero(~rebuilt[src])
    keys = [old_keys[kept]]
    values = {name: [arr[kept]] for name, arr in bond_arrays.items()}
    len0 = bond_arrays[visco_names[0]]
    for start, end, delta in ranges:
        pts = particle_x[start:end]
        pairs = cKDTree(pts).query_pairs(delta, output_type="ndarray").astype(np.int64)
        d = np.linalg.norm(pts[pairs[:, 1]] - pts[pairs[:, 0]], axis=1)
        inside = d < delta * (1.0 - 1e-12)
        pairs, d = pairs[inside] + start, d[inside]
        new_keys = np.concatenate([pairs[:, 0] * n + pairs[:, 1], pairs[:, 1] * n + pairs[:, 0]])
        length = np.concatenate([d, d])
        idx = np.minimum(np.searchsorted(old_keys, new_keys), max(len(old_keys) - 1, 0))
        survive = np.zeros(len(new_keys), dtype=bool)
        if len(old_keys):
            survive = (old_keys[idx] == new_keys) & (len0[idx] > 0.0)
        keys.append(new_keys)
        for name, arr in bond_arrays.items():
            fresh = np.zeros((len(new_keys),) + arr.shape[1:], dtype=arr.dtype)
            fresh[survive] = arr[idx[survive]]
            if name == visco_names[0]:
                fresh[~survive] = length[~survive]
            values[name].append(fresh)
    keys = np.concatenate(keys)
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    new_start = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(keys // n, minlength=n), out=new_start[1:])
    new_nbr = (keys % n).astype(np.int32)
    return new_start, new_nbr, {name: np.concatenate(parts)[order] for name, parts in values.items()}


def effective_constants(lam: float, mu: float, density: float) -> dict:
    """Instantaneous (unrelaxed) isotropic constants of the LPS response: K = lam + 2 mu / 3 and mu."""
    k = lam + 2.0 * mu / 3.0
    m = lam + 2.0 * mu
    return {
        "p_wave_modulus": m,
        "youngs_modulus": 9.0 * k * mu / (3.0 * k + mu),
        "poisson_ratio": (3.0 * k - 2.0 * mu) / (2.0 * (3.0 * k + mu)),
        "bulk_modulus": k,
        "shear_modulus": mu,
        "wave_speed": math.sqrt(m / density),
    }


# ---- phases the solver runs (registry entry "viscoelastic")

def init_state(model, state, body: int):
    """Initial state: every bond formed at its rest length with zero force; m_p of the rest families."""
    start, end = model.body_ranges[body]
    b0, b1 = state.bond_start[start], state.bond_start[end]
    src = np.repeat(np.arange(start, end), np.diff(state.bond_start[start:end + 1]))
    state.bond_len0[b0:b1] = np.linalg.norm(model.rest_x[state.bond_nbr[b0:b1]] - model.rest_x[src], axis=1)
    lps_weighted_volume(start, end, model.body_horizon[body], model.particle_volume, state.bond_start,
                        state.bond_nbr, state.bond_len0, state.particle_m)


def refresh_families(model, state, body: int, dt: float):
    """Phase families:viscoelastic, right after the forces (so particle_x_prev = particle_x and new bonds form
    at the next step's reference length): once a particle has moved rebuild_distance h since the last rebuild,
    rebuild the body's families from current neighbours (streams merge and split), keeping surviving bonds."""
    start, end = model.body_ranges[body]
    mat = model.materials[body]
    moved = state.particle_x[start:end] - state.particle_x_rebuild[start:end]
    moved -= moved.mean(axis=0)  # a body moving as a whole keeps its neighbours: only relative motion counts
    limit = mat.rebuild_distance * model.body_spacing[body]
    if end == start or np.einsum("ij,ij->i", moved, moved).max() <= limit * limit:
        return
    names = [k for k in ("bond_len0", "bond_force_el", "bond_force_visc", "bond_ep", "bond_active", "bond_wv",
                         "bond_inv_len")
             if len(getattr(state, k))]
    state.bond_start, state.bond_nbr, arrays = rebuild_families(
        state.particle_x, state.bond_start, state.bond_nbr, {k: getattr(state, k) for k in names},
        [(start, end, model.body_horizon[body])])
    for k, v in arrays.items():
        setattr(state, k, v)
    if len(state.bond_active):  # bonds of a viscoelastic body never count as fracture damage
        state.bond_active[state.bond_start[start]:state.bond_start[end]] = 1
    lps_weighted_volume(start, end, model.body_horizon[body], model.particle_volume, state.bond_start,
                        state.bond_nbr, state.bond_len0, state.particle_m)
    state.particle_x_rebuild[start:end] = state.particle_x[start:end]


def forces(model, state, body: int, dt: float):
    """Phase bonds:viscoelastic: eq. 12 with the LPS increment since the previous force evaluation."""
    start, end = model.body_ranges[body]
    mat = model.materials[body]
    delta = model.body_horizon[body]
    elapsed = state.dt_prev  # the increment since particle_x_prev happened over the previous step, not over dt
    incremental_dilatation(start, end, delta, state.particle_x, state.particle_x_prev, model.particle_volume,
                           state.bond_start, state.bond_nbr, state.bond_len0, state.particle_m, state.particle_dtheta)
    viscoelastic_forces(start, end, mat.lam + 2.0 * mat.mu / 3.0, mat.mu, mat.relaxation_time, mat.relaxing_fraction,
                        mat.break_stretch or math.inf, delta, elapsed, state.particle_x, state.particle_x_prev,
                        model.particle_volume, state.bond_start, state.bond_nbr, state.particle_m,
                        state.particle_dtheta, state.bond_len0, state.bond_force_el, state.bond_force_visc,
                        state.particle_force)
    state.particle_x_prev[start:end] = state.particle_x[start:end]


def energy(model, state, body: int) -> float:
    """0: the linearised model has no stored-energy function of the positions (its forces depend on the path)."""
    return 0.0
