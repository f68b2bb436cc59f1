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
part relaxes with time tau (effective shear viscosity ~ l mu tau). The step passes K = 0 (the volume pressure
below replaces the bulk part); the kernels keep K for the checks of the LPS increment against eq. 19.

Each directed bond stores the pair sums t_pq + t_qp of both branches (bond_force_el, bond_force_visc), so
no reverse-bond index is needed; both copies of a bond hold bitwise-identical values and
f_p = sum_q (t_pq + t_qp) dir(eta) V_p V_q conserves linear momentum pairwise. bond_len0 < 0 marks a
broken bond. Families are rebuilt from current neighbours (rebuild_families) so streams merge and split.

Departure from the paper: the bonds' dilatation lets a liquid lose volume, since its increments start from the
current configuration and a family rebuild that keeps every family's mean extension leaves it unchanged; in a
sheared layer it even squeezes the liquid. So the bonds keep only their deviatoric part, and the bulk response is
a pressure p = K (1 - J) from each particle's volume ratio J, advanced by the grid velocity gradient
(J <- J det(I + dt C), C the APIC velocity gradient; Stomakhin et al. 2014, Hu et al. 2018), acting through the
grid as the MLS-MPM stress term (Hu et al. 2018). K defaults to the weakly compressible rule (sound speed ten
times the largest flow speed, Monaghan 1994). The pressure sees volume at the scale of a cell, so after each
step's motion a liquid's J is lowered to the grid's volume ratio where the particles crowd more than J says
(`grid_volume_ratio_at`, a one-sided particle density correction), and its particles are shifted apart where they crowd closer than the
spacing (`shift`, Lind et al. 2012; docs/method.md).
"""

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numba import njit, prange
from pydantic import Field as Doc
from scipy.spatial import cKDTree

from pdmpm_cli.engine.bonds import bond_vector, influence
from pdmpm_cli.engine.fields import BOND, PARTICLE, Field
from pdmpm_cli.engine.kernel import COPY_ROWS, Kernel
from pdmpm_cli.engine.materials.base import MaterialKind
from pdmpm_cli.spec import Strict


class Schema(Strict):
    """Linearised peridynamics (paper section 5, eqs. 12-20) with standard-linear-solid relaxation.

    Each step the previous configuration is the reference: the bond force grows by the deviatoric part of the
    linear peridynamic solid response to the step's increment; (1 - relaxing_fraction) of it is kept,
    relaxing_fraction of it decays with relaxation_time. Shear viscosity relaxing_fraction mu tau. The bulk
    response is a pressure from each particle's volume ratio, which keeps a liquid's volume."""

    model: Literal["viscoelastic"]
    density: float = Doc(gt=0, description="Mass density rho [kg/m^3].")
    lam: float = Doc(ge=0, description="Lame's first parameter lambda: the bulk modulus is at least lam + 2 mu / 3 "
                     "[Pa].")
    mu: float = Doc(gt=0, description="Instantaneous shear modulus mu [Pa].")
    relaxation_time: float = Doc(
        gt=0, description="Relaxation time tau of the relaxing deviatoric part (honey short, cream longer) [s].")
    relaxing_fraction: float = Doc(
        1.0, ge=0, le=1, description="Fraction l of the deviatoric response that relaxes: 1 flows like a fluid "
        "(honey), < 1 keeps some shape until bonds break (whipped cream) [-].")
    break_stretch: float | None = Doc(
        None, gt=0, description="Bonds stretched beyond this strain from their formation length break (Table 1: "
        "0.0304 honey, 0.035 cream); families are rebuilt from current neighbours so streams merge and split. "
        "None: bonds never break [-].")
    rebuild_distance: float = Doc(
        0.5, gt=0, le=2, description="Families are rebuilt when some particle has moved this multiple of the "
        "particle spacing since the last rebuild, relative to the middle of the body's range of displacements "
        "(only relative motion counts) [-].")
    bulk_modulus: float | None = Doc(
        None, gt=0, description="Bulk modulus K of the pressure p = K (1 - J) from each particle's volume ratio J, "
        "the material's whole bulk response. None: the weakly compressible rule K = density (10 v)^2, v the "
        "largest speed the body can reach (its initial speed and a fall over the domain's height, the colliders' "
        "and the wind's speed), so volume changes stay near 1 %; at least lam + 2 mu / 3 [Pa].")
    shift_distance: float | None = Doc(
        None, ge=0, le=1.5, description="Particle shifting (Lind et al. 2012): after each step's motion every "
        "particle is pushed apart from the neighbours of its family closer than this multiple of the particle "
        "spacing h (the rest spacing is not pushed), except along the normal of a free surface or wall, and moves "
        "by that push less its family's mean push, so a flowing liquid's particles do not pair up below the cell "
        "size; positions only (velocity and J stay). With it, J is first lowered to the grid's volume ratio where the "
        "particles crowd more than J says (docs/method.md). 0: off. None: 1 for a liquid "
        "(relaxing_fraction 1), 0 otherwise. The neighbours are the family's: a reach beyond horizon - 2 "
        "rebuild_distance can miss a pair that closed in since the last rebuild [-].")


@dataclass(frozen=True)
class Params:
    density: float  # [kg/m^3]
    lam: float  # [Pa]
    mu: float  # [Pa]
    relaxation_time: float  # tau [s]
    relaxing_fraction: float  # l [-]
    break_stretch: float  # [-] (inf: never)
    rebuild_distance: float  # [spacings]
    bulk_modulus: float  # K of the volume-ratio pressure [Pa] (nan: from the flow speed, `with_flow_speed`)
    shift_distance: float = 0.0  # particle shift's reach [spacings] (0: no shift)


def params(section) -> Params:
    shift = section.shift_distance
    if shift is None:
        shift = 1.0 if section.relaxing_fraction == 1.0 else 0.0
    return Params(section.density, section.lam, section.mu, section.relaxation_time, section.relaxing_fraction,
                  section.break_stretch or math.inf, section.rebuild_distance,
                  math.nan if section.bulk_modulus is None else section.bulk_modulus, shift)


SOUND_OVER_FLOW = 10.0  # weakly compressible rule: sound speed >= 10 x flow speed keeps |J - 1| ~ (v / c)^2 ~ 1 %


def with_flow_speed(p: Params, speed: float) -> Params:
    """The bulk modulus the scene left open, K = rho (10 v)^2 for the largest expected flow speed v [m/s] (Monaghan
    1994); at least lam + 2 mu / 3, so a scene at rest still gets a pressure."""
    if not math.isnan(p.bulk_modulus):
        return p
    k = max(p.density * (SOUND_OVER_FLOW * speed) ** 2, p.lam + 2.0 * p.mu / 3.0)
    return replace(p, bulk_modulus=k)


@njit(cache=True)
def weighted_volume_at(p, delta, particle_volume, bond_start, bond_nbr, bond_len0, particle_m):
    """m_p = sum_q w L0^2 V_q over intact bonds (LPS weighted volume) -> particle_m[p]."""
    m = 0.0
    for b in range(bond_start[p], bond_start[p + 1]):
        l0 = bond_len0[b]
        if l0 > 0.0:
            m += influence(l0, delta) * l0 * l0 * particle_volume[bond_nbr[b]]
    particle_m[p] = m


@njit(parallel=True, cache=True)
def lps_weighted_volume(start, end, delta, particle_volume, bond_start, bond_nbr, bond_len0, particle_m):
    """`weighted_volume_at` for particles start..end-1."""
    for p in prange(start, end):
        weighted_volume_at(p, delta, particle_volume, bond_start, bond_nbr, bond_len0, particle_m)


@njit(cache=True)
def incremental_dilatation_at(p, bulk, mu, delta, particle_x, particle_x_prev, particle_volume, bond_start, bond_nbr,
                              bond_len0, particle_m, particle_dtheta, particle_lps, bond_eta, bond_deta, bond_w):
    """dtheta_p = (3 / m_p) sum_q w L0 de V_q, the dilatation of the step's increment -> particle_dtheta[p]. For the
    force pass, which would otherwise take each bond's square roots and divisions again: p's coefficients 3 K
    dtheta_p / m_p and 15 mu / m_p -> particle_lps[p], each intact bond's current length, increment de and
    influence w -> bond_eta, bond_deta, bond_w."""
    s = 0.0
    for b in range(bond_start[p], bond_start[p + 1]):
        l0 = bond_len0[b]
        if l0 > 0.0:
            q = bond_nbr[b]
            l = bond_vector(particle_x, p, q)[3]
            de = l - bond_vector(particle_x_prev, p, q)[3]
            w = influence(l0, delta)
            bond_eta[b] = l
            bond_deta[b] = de
            bond_w[b] = w
            s += w * l0 * de * particle_volume[q]
    m = particle_m[p]
    dtheta = 3.0 * s / m if m > 0.0 else 0.0
    particle_dtheta[p] = dtheta
    particle_lps[p, 0] = 3.0 * bulk * dtheta / m if m > 0.0 else 0.0
    particle_lps[p, 1] = 15.0 * mu / m if m > 0.0 else 0.0


@njit(parallel=True, cache=True)
def incremental_dilatation(start, end, bulk, mu, delta, particle_x, particle_x_prev, particle_volume, bond_start,
                           bond_nbr, bond_len0, particle_m, particle_dtheta, particle_lps, bond_eta, bond_deta, bond_w):
    """`incremental_dilatation_at` for particles start..end-1."""
    for p in prange(start, end):
        incremental_dilatation_at(p, bulk, mu, delta, particle_x, particle_x_prev, particle_volume, bond_start,
                                  bond_nbr, bond_len0, particle_m, particle_dtheta, particle_lps, bond_eta, bond_deta,
                                  bond_w)


@njit(cache=True, inline="always")
def one_sided_increment(lps, dtheta, w, l0, de):
    """Bulk and deviatoric parts of the LPS force increment dt of one side of a bond (eq. 12's K.U); lps: the side's
    (3 K dtheta / m, 15 mu / m)."""
    return lps[0] * w * l0, lps[1] * w * (de - dtheta * l0 / 3.0)


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


@njit(cache=True)
def viscoelastic_force_at(p, tau, fraction, break_stretch, dt, particle_x, particle_volume, bond_start, bond_nbr,
                          particle_dtheta, particle_lps, bond_len0, bond_eta, bond_deta, bond_w, bond_force_el,
                          bond_force_visc, particle_force):
    """Eq. 12 with SLS relaxation for particle p -> bond_len0 (breaks), bond_force_el/visc, particle_force[p];
    returns the bonds it broke.

    particle_lps, bond_eta, bond_deta, bond_w: from incremental_dilatation_at.
    Over-stretched bonds break first (each stored direction by its own particle, so both copies, counted as 2).
    Then every intact bond's pair forces grow by the step's LPS increment and f_p = sum_q (el + visc) dir(eta)
    V_p V_q overwrites particle_force[p]. Both copies of a bond do the same operations in the same order (lower
    index first), so they stay bitwise equal."""
    decay, gain = relaxation_factors(tau, dt)
    keep = 1.0 - fraction
    broken = 0
    f0 = 0.0
    f1 = 0.0
    f2 = 0.0
    vp = particle_volume[p]
    for b in range(bond_start[p], bond_start[p + 1]):
        l0 = bond_len0[b]
        if l0 <= 0.0:
            continue
        q = bond_nbr[b]
        e0, e1, e2, _ = bond_vector(particle_x, p, q)  # its length: bond_eta[b] (the unused sqrt is dropped)
        l = bond_eta[b]
        if l / l0 - 1.0 > break_stretch:
            bond_len0[b] = -1.0
            bond_force_el[b] = 0.0
            bond_force_visc[b] = 0.0
            broken += 1
            continue
        de = bond_deta[b]
        w = bond_w[b]
        lo = p if p < q else q
        hi = q if p < q else p
        b_lo, d_lo = one_sided_increment(particle_lps[lo], particle_dtheta[lo], w, l0, de)
        b_hi, d_hi = one_sided_increment(particle_lps[hi], particle_dtheta[hi], w, l0, de)
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


@njit(parallel=True, cache=True)
def viscoelastic_forces(start, end, tau, fraction, break_stretch, dt, particle_x, particle_volume, bond_start,
                        bond_nbr, particle_dtheta, particle_lps, bond_len0, bond_eta, bond_deta, bond_w, bond_force_el,
                        bond_force_visc, particle_force):
    """`viscoelastic_force_at` for particles start..end-1; returns the bonds broken."""
    broken = 0
    for p in prange(start, end):
        broken += viscoelastic_force_at(p, tau, fraction, break_stretch, dt, particle_x, particle_volume,
                                        bond_start, bond_nbr, particle_dtheta, particle_lps, bond_len0, bond_eta,
                                        bond_deta, bond_w, bond_force_el, bond_force_visc, particle_force)
    return broken


@njit(cache=True, inline="always")
def step_volume_change(p, dt, particle_C):
    """det(I + dt C_p): the volume change of the particle's neighbourhood over a step that moves every point by dt
    times the linear velocity field C_p (the particles move so, x += dt v), not only its first order 1 + dt tr C."""
    a00 = 1.0 + dt * particle_C[p, 0, 0]
    a11 = 1.0 + dt * particle_C[p, 1, 1]
    a22 = 1.0 + dt * particle_C[p, 2, 2]
    a01, a02 = dt * particle_C[p, 0, 1], dt * particle_C[p, 0, 2]
    a10, a12 = dt * particle_C[p, 1, 0], dt * particle_C[p, 1, 2]
    a20, a21 = dt * particle_C[p, 2, 0], dt * particle_C[p, 2, 1]
    return a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20) + a02 * (a10 * a21 - a11 * a20)


@njit(cache=True)
def volume_pressure_at(p, bulk, dt_prev, dt, inv_dx, pin_mask, particle_volume, particle_mass, particle_J,
                       particle_C):
    """Particle p's volume ratio J <- J det(I + dt_prev C) (C from the last G2P is the velocity gradient the
    particle moved with over dt_prev), then its pressure p = K (1 - J) folded into particle_C for this step's P2G:
    the MLS-MPM stress term -dt V sigma D^-1 (x_i - x_p) with sigma = -p I and V = J V0 is an isotropic affine
    momentum, so C += dt V p D^-1 / m (D^-1 = 3 / dx^2 for cubic B-splines; Hu et al. 2018). G2P overwrites C, so
    the checkpointed C stays the velocity gradient. Pinned particles keep only their prescribed motion."""
    j = particle_J[p] * step_volume_change(p, dt_prev, particle_C)
    particle_J[p] = j
    if pin_mask.shape[0] > 0 and pin_mask[p] != 0:
        return
    s = dt * particle_volume[p] * j * bulk * (1.0 - j) * 3.0 * inv_dx * inv_dx / particle_mass[p]
    for a in range(3):
        particle_C[p, a, a] += s


@njit(parallel=True, cache=True)
def volume_pressures(start, end, bulk, dt_prev, dt, inv_dx, pin_mask, particle_volume, particle_mass, particle_J,
                     particle_C):
    """`volume_pressure_at` for particles start..end-1."""
    for p in prange(start, end):
        volume_pressure_at(p, bulk, dt_prev, dt, inv_dx, pin_mask, particle_volume, particle_mass, particle_J,
                           particle_C)


@njit(cache=True)
def grid_volume_ratio_at(p, density, pin_mask, particle_rho, particle_J):
    """J_p <- min(J_p, density / rho_p), rho_p the mass density of the step's grid at the particle (particle_rho,
    gathered by G2P where P2G scattered from; a particle density correction, one-sided): where the particles crowd
    more than J says, the pressure sees it. Only there: at a free surface or a wall the stencil is part empty and
    rho_p falls below the density, which must not pull (tension). Pinned particles keep their J."""
    if pin_mask.shape[0] > 0 and pin_mask[p] != 0:
        return
    rho = particle_rho[p]
    if rho * particle_J[p] > density:
        particle_J[p] = density / rho


@njit(parallel=True, cache=True)
def grid_volume_ratios(start, end, density, pin_mask, particle_rho, particle_J):
    """`grid_volume_ratio_at` for particles start..end-1."""
    for p in prange(start, end):
        grid_volume_ratio_at(p, density, pin_mask, particle_rho, particle_J)


SHIFT_STRENGTH = 0.1  # a pair closer than the reach r_s separates by up to 2 x this x r_s per step
SHIFT_CAP = 0.1  # largest shift of one particle in one step [spacings]
SURFACE_OFFSET = 0.1  # a particle whose neighbours' weighted centroid lies this fraction of the horizon away from it
# is at a free surface or a wall (0 in a lattice's bulk; 0.2-0.4 on its faces; below 0.1 in a disordered bulk)


@njit(cache=True)
def shift_at(p, reach, delta, strength, cap, surface, pin_mask, particle_x, particle_volume, bond_start, bond_nbr,
             particle_shift):
    """Particle p's shift -> particle_shift[p] (Lind et al. 2012): dx_p = -D grad C_p, C the concentration of a kernel
    W = (1 - r / r_s)^3 whose support r_s (reach) is within the rest spacing, so a relaxed lattice is not pushed:
    dx_p = strength r_s sum_q (V_q / V_p) (1 - r / r_s)^2 (x_p - x_q) / r, capped at `cap`. At a free surface or a
    wall (the family's weighted centroid, weight 1 - r / delta, more than `surface` from p) the component along the
    normal (away from the centroid) is dropped: the shift rearranges a surface along it and never swells it. The
    neighbours are p's family (the pairs within delta at the last rebuild, hence every pair now within
    delta - 2 rebuild_distance h). apply_shift_at then removes the family's mean. Pinned particles get none."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    c0 = 0.0
    c1 = 0.0
    c2 = 0.0
    wsum = 0.0
    vp = particle_volume[p]
    for b in range(bond_start[p], bond_start[p + 1]):
        q = bond_nbr[b]
        e0, e1, e2, l = bond_vector(particle_x, p, q)
        if l < delta:
            w = 1.0 - l / delta
            c0 += w * e0
            c1 += w * e1
            c2 += w * e2
            wsum += w
        if l > 0.0 and l < reach:
            k = 1.0 - l / reach
            g = k * k * particle_volume[q] / (vp * l)
            s0 -= g * e0
            s1 -= g * e1
            s2 -= g * e2
    f = strength * reach
    s0 *= f
    s1 *= f
    s2 *= f
    if wsum > 0.0:
        c0 /= wsum
        c1 /= wsum
        c2 /= wsum
        c = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        if c > surface:
            n0 = c0 / c
            n1 = c1 / c
            n2 = c2 / c
            dot = s0 * n0 + s1 * n1 + s2 * n2
            s0 -= dot * n0
            s1 -= dot * n1
            s2 -= dot * n2
    size = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    if size > cap:
        s0 *= cap / size
        s1 *= cap / size
        s2 *= cap / size
    if pin_mask.shape[0] > 0 and pin_mask[p] != 0:
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
    particle_shift[p, 0] = s0
    particle_shift[p, 1] = s1
    particle_shift[p, 2] = s2


@njit(parallel=True, cache=True)
def shifts(start, end, reach, delta, strength, cap, surface, pin_mask, particle_x, particle_volume, bond_start,
           bond_nbr, particle_shift):
    """`shift_at` for particles start..end-1."""
    for p in prange(start, end):
        shift_at(p, reach, delta, strength, cap, surface, pin_mask, particle_x, particle_volume, bond_start, bond_nbr,
                 particle_shift)


@njit(cache=True)
def apply_shift_at(p, delta, pin_mask, bond_start, bond_nbr, bond_len0, particle_shift, particle_x, particle_x_prev):
    """x_p and x_prev_p move by p's shift less the family's weighted mean shift (weight 1 - L0 / delta over intact
    bonds, p itself weight 1): only the part that rearranges p among its neighbours, none that carries particles
    across the family's scale and so packs them against a surface or a wall. x_prev moves too, so the next step's
    bond increment does not see the shift: it corrects where the particles sample the liquid and is no deformation
    (J and the velocity stay). Pinned particles stay."""
    if pin_mask.shape[0] > 0 and pin_mask[p] != 0:
        return
    m0 = particle_shift[p, 0]
    m1 = particle_shift[p, 1]
    m2 = particle_shift[p, 2]
    wsum = 1.0
    for b in range(bond_start[p], bond_start[p + 1]):
        l0 = bond_len0[b]
        if l0 > 0.0:
            q = bond_nbr[b]
            w = influence(l0, delta)
            m0 += w * particle_shift[q, 0]
            m1 += w * particle_shift[q, 1]
            m2 += w * particle_shift[q, 2]
            wsum += w
    d0 = particle_shift[p, 0] - m0 / wsum
    d1 = particle_shift[p, 1] - m1 / wsum
    d2 = particle_shift[p, 2] - m2 / wsum
    particle_x[p, 0] += d0
    particle_x[p, 1] += d1
    particle_x[p, 2] += d2
    particle_x_prev[p, 0] += d0
    particle_x_prev[p, 1] += d1
    particle_x_prev[p, 2] += d2


@njit(parallel=True, cache=True)
def apply_shifts(start, end, delta, pin_mask, bond_start, bond_nbr, bond_len0, particle_shift, particle_x,
                 particle_x_prev):
    """`apply_shift_at` for particles start..end-1."""
    for p in prange(start, end):
        apply_shift_at(p, delta, pin_mask, bond_start, bond_nbr, bond_len0, particle_shift, particle_x, particle_x_prev)


VOLUME_PRESSURE = Kernel(volume_pressure_at, volume_pressures)
GRID_VOLUME_RATIO = Kernel(grid_volume_ratio_at, grid_volume_ratios)
SHIFT = Kernel(shift_at, shifts)
APPLY_SHIFT = Kernel(apply_shift_at, apply_shifts)
INCREMENTAL_DILATATION = Kernel(incremental_dilatation_at, incremental_dilatation)
FORCES = Kernel(viscoelastic_force_at, viscoelastic_forces, reduce="sum")


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


@njit(cache=True)
def pair_lengths(x, pairs):
    """|x_j - x_i| of each pair (i, j) [m]."""
    d = np.empty(pairs.shape[0])
    for e in range(pairs.shape[0]):
        i, j = pairs[e, 0], pairs[e, 1]
        a, b, c = x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2]
        d[e] = math.sqrt(a * a + b * b + c * c)
    return d


@njit(cache=True)
def merged_rows(bond_start, bond_nbr, len0, rebuilt, pairs, dist):
    """The CSR of `rebuild_families`, sorted by (p, q): a row not rebuilt is copied, a rebuilt row holds the new
    pairs (both directions) sorted by q. Returns (start, nbr, src, length): src the old bond a new one carries its
    values from (-1: a fresh bond, or one that was broken), length the current length of each pair's bond."""
    n = bond_start.shape[0] - 1
    count = np.zeros(n, np.int64)
    for p in range(n):
        if not rebuilt[p]:
            count[p] = bond_start[p + 1] - bond_start[p]
    for e in range(pairs.shape[0]):
        count[pairs[e, 0]] += 1
        count[pairs[e, 1]] += 1
    start = np.zeros(n + 1, np.int64)
    for p in range(n):
        start[p + 1] = start[p] + count[p]
    nbr = np.empty(start[n], np.int32)
    src = np.full(start[n], -1, np.int64)
    length = np.zeros(start[n])
    fill = start[:n].copy()
    for p in range(n):
        if not rebuilt[p]:
            for b in range(bond_start[p], bond_start[p + 1]):
                nbr[fill[p]] = bond_nbr[b]
                src[fill[p]] = b
                fill[p] += 1
    # The new bonds, both directions (k < E: pairs[k, 0] -> pairs[k, 1], k >= E: the reverse), counting-sorted by
    # neighbour first, so that each row fills in neighbour order.
    e_count = pairs.shape[0]
    first = np.zeros(n + 1, np.int64)
    for e in range(e_count):
        first[pairs[e, 0] + 1] += 1
        first[pairs[e, 1] + 1] += 1
    for q in range(n):
        first[q + 1] += first[q]
    order = np.empty(2 * e_count, np.int64)
    for k in range(2 * e_count):
        q = pairs[k, 1] if k < e_count else pairs[k - e_count, 0]
        order[first[q]] = k
        first[q] += 1
    for k in order:
        e = k if k < e_count else k - e_count
        p, q = (pairs[e, 0], pairs[e, 1]) if k < e_count else (pairs[e, 1], pairs[e, 0])
        nbr[fill[p]], length[fill[p]] = q, dist[e]
        fill[p] += 1
    for p in range(n):
        if not rebuilt[p]:
            continue
        b, last = bond_start[p], bond_start[p + 1]
        for a in range(start[p], start[p + 1]):  # both rows sorted: one walk finds the surviving bonds
            while b < last and bond_nbr[b] < nbr[a]:
                b += 1
            if b < last and bond_nbr[b] == nbr[a] and len0[b] > 0.0:
                src[a] = b
    return start, nbr, src, length


def rebuild_families(particle_x, bond_start, bond_nbr, bond_arrays, ranges, length_name="bond_len0"):
    """Families of the bodies in `ranges` rebuilt from current neighbours; all other bonds kept as they are.

    ranges: (start, end, delta) of each rebuilt body. A pair within delta that was an intact bond keeps every
    per-bond value; a new pair (or a broken one, bond_arrays[length_name] < 0) starts with length_name = current
    length and 0 in every other array; pairs beyond delta are dropped. Other bodies' bonds and values are
    relocated unchanged. The CSR must be sorted by (p, q) (build_families' order) and stays so."""
    if length_name not in bond_arrays:
        raise KeyError(f"rebuild_families needs the per-bond array {length_name}")
    rebuilt = np.zeros(len(particle_x), dtype=np.bool_)
    found, dists = [np.zeros((0, 2), np.int64)], [np.zeros(0)]
    for start, end, delta in ranges:
        rebuilt[start:end] = True
        pts = particle_x[start:end]
        pairs = cKDTree(pts).query_pairs(delta, output_type="ndarray").astype(np.int64)
        d = pair_lengths(pts, pairs)
        inside = d < delta * (1.0 - 1e-12)
        found.append(pairs[inside] + start)
        dists.append(d[inside])
    new_start, new_nbr, src, length = merged_rows(bond_start, bond_nbr, bond_arrays[length_name], rebuilt,
                                                  np.concatenate(found), np.concatenate(dists))
    carried = src >= 0
    arrays = {}
    for name, arr in bond_arrays.items():
        out = np.zeros((len(src),) + arr.shape[1:], dtype=arr.dtype)
        out[carried] = arr[src[carried]]
        if name == length_name:
            out[~carried] = length[~carried]
        arrays[name] = out
    return new_start, new_nbr, arrays


def effective_constants(lam: float, mu: float, density: float, bulk: float) -> dict:
    """Instantaneous (unrelaxed) isotropic constants: the volume pressure's bulk modulus and the bonds' mu.
    p_wave_modulus, lam + 2 mu as in the paper's calibration, sets the bond bound of the step; wave_speed, with the
    pressure's K, the CFL bound."""
    return {
        "p_wave_modulus": lam + 2.0 * mu,
        "youngs_modulus": 9.0 * bulk * mu / (3.0 * bulk + mu),
        "poisson_ratio": (3.0 * bulk - 2.0 * mu) / (2.0 * (3.0 * bulk + mu)),
        "bulk_modulus": bulk,
        "shear_modulus": mu,
        "wave_speed": math.sqrt((bulk + 4.0 * mu / 3.0) / density),
    }


# ---- the material's hooks

def init_state(solver, state, body: int):
    """Initial state: every bond formed at its rest length with zero force; m_p of the rest families; the
    previous and last-rebuild positions are the initial ones."""
    b, model = solver.model.bodies[body], solver.model
    b0, b1 = state.bond_start[b.start], state.bond_start[b.end]
    src = np.repeat(np.arange(b.start, b.end), np.diff(state.bond_start[b.start:b.end + 1]))
    state.bond_len0[b0:b1] = np.linalg.norm(model.rest_x[state.bond_nbr[b0:b1]] - model.rest_x[src], axis=1)
    lps_weighted_volume(b.start, b.end, b.horizon, model.particle_volume, state.bond_start, state.bond_nbr,
                        state.bond_len0, state.particle_m)
    state.particle_x_prev[b.start:b.end] = state.particle_x[b.start:b.end]
    state.particle_x_rebuild[b.start:b.end] = state.particle_x[b.start:b.end]


def families(solver, body: int, dt: float):
    """After the forces (so particle_x_prev = particle_x and new bonds form at the next step's reference length):
    once a particle has moved rebuild_distance h since the last rebuild, relative to the middle of the body's range
    of displacements, rebuild the body's families from current neighbours (streams merge and split), keeping
    surviving bonds and every per-bond array with them. On the host: the CUDA backend copies the arrays down and
    back.

    Only relative motion counts, in any common frame: when no particle is more than r = rebuild_distance h from
    it, no two have closed in by more than 2 r, so every pair within delta - 2 r is a bond. The middle of the
    displacements' bounding box is that frame's centre (near the smallest r) where a stream falls onto a pile at
    rest; the mean, which the pile's particles outweigh, rebuilt 1.5x as often (docs/results.md)."""
    b, state = solver.model.bodies[body], solver.state
    if b.end == b.start:
        return
    with solver.backend.on_host(state, ("particle_x", "particle_x_rebuild")):
        moved = state.particle_x[b.start:b.end] - state.particle_x_rebuild[b.start:b.end]
        moved -= 0.5 * (moved.min(axis=0) + moved.max(axis=0))
        limit = b.params.rebuild_distance * b.spacing
        if np.einsum("ij,ij->i", moved, moved).max() <= limit * limit:
            return
    carried = tuple(state.bond_arrays())
    with solver.backend.on_host(state, ("particle_x", "bond_start", "bond_nbr", "particle_m", "particle_x_rebuild")
                                + carried):
        rebuild(solver, state, b)


def rebuild(solver, state, b):
    """Body b's families rebuilt from current neighbours on the host State, with m_p and the rebuild positions. The
    per-bond arrays are carried with their bonds, but for the transient ones (refilled before they are read), which
    are only resized."""
    lasting = {name: a for name, a in state.bond_arrays().items() if not state.declared[name].transient}
    state.bond_start, state.bond_nbr, carried = rebuild_families(
        state.particle_x, state.bond_start, state.bond_nbr, lasting, [(b.start, b.end, b.horizon)])
    for name, array in carried.items():
        setattr(state, name, array)
    state.fit_transient_bonds()
    if state.has("bond_active"):  # bonds of a viscoelastic body never count as fracture damage
        state.bond_active[state.bond_start[b.start]:state.bond_start[b.end]] = 1
    lps_weighted_volume(b.start, b.end, b.horizon, solver.model.particle_volume, state.bond_start, state.bond_nbr,
                        state.bond_len0, state.particle_m)
    state.particle_x_rebuild[b.start:b.end] = state.particle_x[b.start:b.end]


def born(solver, state, body: int, first: int):
    """Particles first.. just appended by an emitter (engine.emitter; J = 1 by its fill): the previous positions
    their own, then the body's families rebuilt, so their bonds form at the current lengths with zero force. Births
    run after the force hooks, where particle_x_prev = particle_x for every other particle too."""
    b = solver.model.bodies[body]
    state.particle_x_prev[first:b.end] = state.particle_x[first:b.end]
    rebuild(solver, state, b)


def volume_pressure(solver, body: int, dt: float):
    """J advanced over the previous step and this step's pressure folded into the P2G affine momentum."""
    b, a, m = solver.model.bodies[body], solver.a, solver.m
    solver.backend.run(VOLUME_PRESSURE, b.start, b.end, b.params.bulk_modulus, solver.state.dt_prev, solver.kick,
                       1.0 / solver.model.dx, m.pin_mask, m.particle_volume, m.particle_mass, a.particle_J,
                       a.particle_C)


def bonds(solver, body: int, dt: float):
    """Eq. 12 with the LPS increment since the previous force evaluation -> particle_force: the deviatoric part
    only, since the volume pressure (volume_pressure) replaces the bonds' bulk part."""
    b, a, m = solver.model.bodies[body], solver.a, solver.m
    p = b.params
    run = solver.backend.run
    elapsed = solver.state.dt_prev  # the increment since particle_x_prev happened over the previous step, not dt
    run(INCREMENTAL_DILATATION, b.start, b.end, 0.0, p.mu, b.horizon, a.particle_x, a.particle_x_prev,
        m.particle_volume, a.bond_start, a.bond_nbr, a.bond_len0, a.particle_m, a.particle_dtheta, a.particle_lps,
        a.bond_eta, a.bond_deta, a.bond_w)
    run(FORCES, b.start, b.end, p.relaxation_time, p.relaxing_fraction, p.break_stretch, elapsed, a.particle_x,
        m.particle_volume, a.bond_start, a.bond_nbr, a.particle_dtheta, a.particle_lps, a.bond_len0, a.bond_eta,
        a.bond_deta, a.bond_w, a.bond_force_el, a.bond_force_visc, a.particle_force)
    run(COPY_ROWS, b.start, b.end, a.particle_x, a.particle_x_prev)


def shift(solver, body: int, dt: float):
    """After G2P moved the particles: J no larger than the grid's volume ratio where P2G scattered from
    (grid_volume_ratio_at; the body's own field with contact, gathered by G2P), then the particle shift (shift_at),
    computed for every particle of the body from the moved positions and applied less its family's mean
    (apply_shift_at)."""
    b, a, m = solver.model.bodies[body], solver.a, solver.m
    run = solver.backend.run
    run(GRID_VOLUME_RATIO, b.start, b.end, b.params.density, m.pin_mask, a.particle_rho, a.particle_J)
    run(SHIFT, b.start, b.end, b.params.shift_distance * b.spacing, b.horizon, SHIFT_STRENGTH, SHIFT_CAP * b.spacing,
        SURFACE_OFFSET * b.horizon, m.pin_mask, a.particle_x, m.particle_volume, a.bond_start, a.bond_nbr,
        a.particle_shift)
    run(APPLY_SHIFT, b.start, b.end, b.horizon, m.pin_mask, a.bond_start, a.bond_nbr, a.bond_len0, a.particle_shift,
        a.particle_x, a.particle_x_prev)


def energy(solver, state, body: int) -> float:
    """0: the linearised model has no stored-energy function of the positions (its forces depend on the path)."""
    return 0.0


def constants(p: Params) -> dict:
    bulk = p.lam + 2.0 * p.mu / 3.0 if math.isnan(p.bulk_modulus) else p.bulk_modulus
    return effective_constants(p.lam, p.mu, p.density, bulk)


def volume_ratio(model, state) -> np.ndarray:
    return state.particle_J


KIND = MaterialKind(
    name="viscoelastic", schema=Schema, params=params, forces=bonds, constants=constants, energy=energy,
    before_forces=volume_pressure, after_forces=families, flows=True, after_move=shift,
    moves=lambda p: p.shift_distance > 0.0, reads_grid_density=lambda p: p.shift_distance > 0.0,
    start=init_state, born=born, with_flow_speed=with_flow_speed,
    outputs={"particle_J": volume_ratio},
    fields=(
        Field("particle_J", PARTICLE, fill=1.0, precise=True,
              doc="volume ratio J = V / V0 from the grid velocity gradient [-]"),
        Field("bond_len0", BOND, precise=True, doc="formation length of each bond [m] (< 0: broken)"),
        Field("bond_force_el", BOND, doc="non-relaxing pair force [N/m^6]"),
        Field("bond_force_visc", BOND, doc="relaxing pair force [N/m^6]"),
        Field("particle_m", PARTICLE, doc="LPS weighted volume [m^5]"),
        Field("particle_dtheta", PARTICLE, transient=True, doc="incremental dilatation of the step [-]"),
        Field("particle_lps", PARTICLE, (2,), transient=True, precise=True,
              doc="the step's LPS coefficients 3 K dtheta / m and 15 mu / m of the pair force increment [N/m^7]"),
        Field("bond_eta", BOND, transient=True, precise=True, doc="current length |eta| of each intact bond [m]"),
        Field("bond_w", BOND, transient=True, precise=True, doc="influence w of each intact bond [-]"),
        Field("bond_deta", BOND, transient=True, precise=True,
              doc="length increment of each intact bond since the previous force evaluation [m]"),
        Field("particle_x_prev", PARTICLE, (3,), precise=True, doc="positions at the previous force evaluation [m]"),
        Field("particle_x_rebuild", PARTICLE, (3,), precise=True, doc="positions at the last family rebuild [m]"),
        Field("particle_shift", PARTICLE, (3,), transient=True, doc="particle shift of the step [m]"),
    ),
)
