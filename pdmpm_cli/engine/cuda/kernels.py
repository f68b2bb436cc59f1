"""CUDA kernels of the step: eq. 4, bond forces (eqs. 6-7, 9), the plastic return map (eqs. 10-11), P2G, the grid
update and G2P (section 3), one thread per particle or grid node.

The scalar @njit helpers (B-spline weights, bond vectors, Ybar, collider level sets and responses, the speed test)
are compiled for the GPU from their own Python source by `device`, so both backends share one definition of that
math. The kernels repeat the CPU kernels' per-particle loops in the same order, so everything but P2G matches the
CPU backend to round-off (fused multiply-adds on the GPU); P2G adds into one grid with float64 atomics, whose
order varies between runs.
"""

import math
import types

from numba import cuda, float64

from pdmpm_cli.engine.bonds import bond_vector
from pdmpm_cli.engine.bspline import cubic_weights
from pdmpm_cli.engine.colliders import collide_all, push_out, respond, signed_distance
from pdmpm_cli.engine.materials.elastic import averaged_bond
from pdmpm_cli.engine.transfer import WALL, particle_speed, pin_share, stencil_on_grid

# Slots of the per-step statistics array the host reads once per step.
STAT_LO, STAT_HI = 0, 3  # per-axis min and max of the particle positions after G2P [m] (the next P2G's node box)
STAT_VMAX, STAT_BAD = 6, 7  # max particle speed [m/s], number of non-finite particles
STAT_YIELD = 8  # largest f / psi_p after any return map so far (-1 before the first)
N_STATS = 9


def device(fn, **callees):
    """A CUDA device function compiled from the Python source of the @njit helper `fn`, with the globals in
    `callees` replaced: the jitted helpers it calls by their device versions (the simulator cannot call
    CPU-compiled code), or a module by one whose functions CUDA has."""
    py = fn.py_func
    scope = {**py.__globals__, **callees}
    return cuda.jit(device=True)(types.FunctionType(py.__code__, scope, py.__name__, py.__defaults__, py.__closure__))


@cuda.jit(device=True)
def larger(a, b):
    """max(a, b) as Python defines it (b only if b > a): numba 0.68's CUDA target cannot compile the builtin."""
    return b if b > a else a


d_bond_vector = device(bond_vector)
d_averaged_bond = device(averaged_bond)
d_cubic_weights = device(cubic_weights, np=math)  # CUDA has no np.floor; math.floor is the same on finite floats
d_stencil_on_grid = device(stencil_on_grid)
d_particle_speed = device(particle_speed)
d_pin_share = device(pin_share)
d_signed_distance = device(signed_distance, max=larger)
d_respond = device(respond)
d_collide_all = device(collide_all, signed_distance=d_signed_distance, respond=d_respond)
d_push_out = device(push_out, signed_distance=d_signed_distance)


@cuda.jit(cache=True)
def averaged_deformation(start, end, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr,
                         particle_Kinv, particle_Fbar):
    """Fbar_p = (sum_q w V_q eta (x) xi) K_p^-1 (eq. 4) for particles start..end-1 of one body -> particle_Fbar."""
    p = start + cuda.grid(1)
    if p >= end:
        return
    a = cuda.local.array((3, 3), float64)
    for i in range(3):
        for c in range(3):
            a[i, c] = 0.0
    for b in range(bond_start[p], bond_start[p + 1]):
        q = bond_nbr[b]
        x0, x1, x2, r = d_bond_vector(rest_x, p, q)
        wv = (1.0 - r / delta) * particle_volume[q]
        for i in range(3):
            e = wv * (particle_x[q, i] - particle_x[p, i])
            a[i, 0] += e * x0
            a[i, 1] += e * x1
            a[i, 2] += e * x2
    kinv = particle_Kinv[p]
    for i in range(3):
        for c in range(3):
            particle_Fbar[p, i, c] = a[i, 0] * kinv[0, c] + a[i, 1] * kinv[1, c] + a[i, 2] * kinv[2, c]


@cuda.jit(cache=True)
def elastic_forces(start, end, lam, mu, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_ep,
                   particle_coef, particle_Fbar, particle_force):
    """Bond forces f_p (eqs. 6-7, 9) for particles start..end-1 of one elastic or plastic body -> particle_force.
    A thread gathers over its own bonds (both directions are stored), so no atomics are needed."""
    p = start + cuda.grid(1)
    if p >= end:
        return
    has_ep = bond_ep.shape[0] > 0
    f0 = 0.0
    f1 = 0.0
    f2 = 0.0
    cp = particle_coef[p]
    vp = particle_volume[p]
    for b in range(bond_start[p], bond_start[p + 1]):
        ep = bond_ep[b] if has_ep else 0.0
        q = bond_nbr[b]
        x0, x1, x2, r = d_bond_vector(rest_x, p, q)
        e0, e1, e2, l = d_bond_vector(particle_x, p, q)
        cq = particle_coef[q]
        a = (1.0 - r / delta) / r * vp * particle_volume[q]
        if l > 0.0:
            g = a * lam * (l / r - 1.0 - ep) * (cp + cq) / l
            f0 += g * e0
            f1 += g * e1
            f2 += g * e2
        if mu > 0.0:
            for side in range(2):
                fm = particle_Fbar[p] if side == 0 else particle_Fbar[q]
                c = cp if side == 0 else cq
                y0, y1, y2, ly = d_averaged_bond(fm, x0, x1, x2)
                if ly > 0.0:
                    g = a * 2.0 * mu * c * (ly / r - 1.0 - ep) / ly
                    f0 += g * y0
                    f1 += g * y1
                    f2 += g * y2
    particle_force[p, 0] = f0
    particle_force[p, 1] = f1
    particle_force[p, 2] = f2


@cuda.jit(cache=True)
def bond_dilatation(start, end, delta, particle_x, rest_x, particle_volume, bond_start, bond_nbr, particle_theta):
    """theta_p = 3 sum w |xi|^2 s V_q / sum w |xi|^2 V_q (e_iso of eq. 9) for particles start..end-1."""
    p = start + cuda.grid(1)
    if p >= end:
        return
    num = 0.0
    den = 0.0
    for b in range(bond_start[p], bond_start[p + 1]):
        q = bond_nbr[b]
        r = d_bond_vector(rest_x, p, q)[3]
        l = d_bond_vector(particle_x, p, q)[3]
        wv = (1.0 - r / delta) * r * r * particle_volume[q]
        num += wv * (l / r - 1.0)
        den += wv
    particle_theta[p] = 3.0 * num / den if den > 0.0 else 0.0


@cuda.jit(cache=True)
def plastic_return_map(start, end, lam, mu, psi, particle_x, rest_x, bond_start, bond_nbr, particle_Fbar,
                       particle_theta, bond_ep, stats):
    """Eqs. 10-11: project each yielding bond of particles start..end-1 onto f = 0 (bond_ep in place), with the
    strain the force acts on, (lam s + mu (sbar_p + sbar_q)) / M (the CPU kernel's); the largest f / psi_p after
    the update goes to stats[STAT_YIELD]. Each stored direction of a bond has its own thread, and both see the same
    strain and pair mean of theta, so e_p stays equal on the two."""
    p = start + cuda.grid(1)
    if p >= end:
        return
    modulus = lam + 2.0 * mu
    limit = math.sqrt(2.0 * psi)
    tp = particle_theta[p]
    fmax = -1.0
    for b in range(bond_start[p], bond_start[p + 1]):
        q = bond_nbr[b]
        x0, x1, x2, r = d_bond_vector(rest_x, p, q)
        s = d_bond_vector(particle_x, p, q)[3] / r - 1.0
        strain = s
        if mu > 0.0:
            sp = d_averaged_bond(particle_Fbar[p], x0, x1, x2)[3] / r - 1.0
            sq = d_averaged_bond(particle_Fbar[q], x0, x1, x2)[3] / r - 1.0
            strain = (lam * s + mu * (sp + sq)) / modulus
        e_dev = strain - (tp + particle_theta[q]) / 6.0
        e = modulus * (e_dev - bond_ep[b])
        if abs(e) > limit:
            bond_ep[b] += (e - math.copysign(limit, e)) / modulus
            e = modulus * (e_dev - bond_ep[b])
        fmax = larger(fmax, (0.5 * e * e - psi) / psi)
    cuda.atomic.max(stats, STAT_YIELD, fmax)


@cuda.jit(device=True)
def box_node(t, box):
    """Node (i, j, k) of thread t over the node box (i0, i1, j0, j1, k0, k1), or i = -1 past its end."""
    ny = box[3] - box[2]
    nz = box[5] - box[4]
    if t >= (box[1] - box[0]) * ny * nz:
        return -1, 0, 0
    return box[0] + t // (ny * nz), box[2] + (t // nz) % ny, box[4] + t % nz


@cuda.jit(cache=True)
def zero_box(box, grid):
    """grid = 0 on the node box: the only nodes P2G can touch this step."""
    i, j, k = box_node(cuda.grid(1), box)
    if i < 0:
        return
    for q in range(4):
        grid[i, j, k, q] = 0.0


@cuda.jit(cache=True)
def p2g(particle_x, particle_v, particle_C, particle_mass, particle_force, pin_mask, dt, origin, inv_dx, grid):
    """P2G of mass, APIC momentum and dt * bond force (eq. 7) -> grid, with float64 atomics; pinned particles
    bring their momentum but not their bond force (transfer.p2g)."""
    p = cuda.grid(1)
    if p >= particle_x.shape[0]:
        return
    fx = (particle_x[p, 0] - origin[0]) * inv_dx
    fy = (particle_x[p, 1] - origin[1]) * inv_dx
    fz = (particle_x[p, 2] - origin[2]) * inv_dx
    if not d_stencil_on_grid(fx, fy, fz, grid):
        return  # the host stops the run before this launch (CudaSolver.gpu_p2g); this only guards memory
    wx = cuda.local.array(4, float64)
    wy = cuda.local.array(4, float64)
    wz = cuda.local.array(4, float64)
    bx = d_cubic_weights(fx, wx)
    by = d_cubic_weights(fy, wy)
    bz = d_cubic_weights(fz, wz)
    m = particle_mass[p]
    fdt = 0.0 if pin_mask.shape[0] > 0 and pin_mask[p] != 0 else dt
    for i in range(4):
        dx0 = (bx + i - fx) / inv_dx
        for j in range(4):
            dx1 = (by + j - fy) / inv_dx
            wij = wx[i] * wy[j]
            for k in range(4):
                dx2 = (bz + k - fz) / inv_dx
                wgt = wij * wz[k]
                cuda.atomic.add(grid, (bx + i, by + j, bz + k, 0), wgt * m)
                for a in range(3):
                    mom = m * (particle_v[p, a] + particle_C[p, a, 0] * dx0 + particle_C[p, a, 1] * dx1
                               + particle_C[p, a, 2] * dx2)
                    cuda.atomic.add(grid, (bx + i, by + j, bz + k, 1 + a), wgt * (mom + fdt * particle_force[p, a]))


@cuda.jit(cache=True)
def grid_update(grid, dt, gravity, wind, drag, origin, dx, box, t_new, colliders, wall_boundary, wall_friction):
    """Grid momentum -> velocity with gravity and the wind's implicit drag (step 3), domain walls and colliders
    (step 4), one thread per node of the box; in place (transfer.grid_update)."""
    i, j, k = box_node(cuda.grid(1), box)
    if i < 0:
        return
    m = grid[i, j, k, 0]
    if m <= 0.0:
        return
    relax = 1.0 / (1.0 + dt * drag)
    v = cuda.local.array(3, float64)
    nrm = cuda.local.array(3, float64)
    for a in range(3):
        v[a] = (grid[i, j, k, 1 + a] / m + dt * (gravity[a] + drag * wind[a])) * relax
    for a in range(3):
        idx = i if a == 0 else (j if a == 1 else k)
        hi = (grid.shape[0] if a == 0 else (grid.shape[1] if a == 1 else grid.shape[2])) - 1 - WALL
        side = 1.0 if idx < WALL else (-1.0 if idx > hi else 0.0)
        if side != 0.0:
            nrm[0], nrm[1], nrm[2] = 0.0, 0.0, 0.0
            nrm[a] = side
            d_respond(v, 0.0, 0.0, 0.0, nrm, wall_boundary, wall_friction)
    if colliders.shape[0]:
        d_collide_all(colliders, origin[0] + i * dx, origin[1] + j * dx, origin[2] + k * dx, t_new, v, nrm)
    grid[i, j, k, 1] = v[0]
    grid[i, j, k, 2] = v[1]
    grid[i, j, k, 3] = v[2]


@cuda.jit(cache=True)
def reset_stats(stats):
    """Clear the per-step slots (bounds, max speed, non-finite count) before G2P fills them."""
    if cuda.grid(1) == 0:
        for a in range(3):
            stats[STAT_LO + a] = math.inf
            stats[STAT_HI + a] = -math.inf
        stats[STAT_VMAX] = 0.0
        stats[STAT_BAD] = 0.0


@cuda.jit(cache=True)
def g2p(grid, dt, origin, inv_dx, t_new, colliders, pin_mask, pin_velocity, pin_stop, particle_x, particle_v,
        particle_C, stats):
    """G2P velocity and APIC affine matrix (step 5), pins, particle collisions (step 6) and advection
    (transfer.g2p); the max speed, non-finite count and position bounds go to `stats` with atomics."""
    p = cuda.grid(1)
    if p >= particle_x.shape[0]:
        return
    wx = cuda.local.array(4, float64)
    wy = cuda.local.array(4, float64)
    wz = cuda.local.array(4, float64)
    v = cuda.local.array(3, float64)
    b = cuda.local.array((3, 3), float64)
    nrm = cuda.local.array(3, float64)
    for a in range(3):
        v[a] = 0.0
        for c in range(3):
            b[a, c] = 0.0
    scale = 3.0 * inv_dx * inv_dx  # D_p^-1 for cubic B-splines
    fx = (particle_x[p, 0] - origin[0]) * inv_dx
    fy = (particle_x[p, 1] - origin[1]) * inv_dx
    fz = (particle_x[p, 2] - origin[2]) * inv_dx
    bx = d_cubic_weights(fx, wx)
    by = d_cubic_weights(fy, wy)
    bz = d_cubic_weights(fz, wz)
    for i in range(4):
        dx0 = (bx + i - fx) / inv_dx
        for j in range(4):
            dx1 = (by + j - fy) / inv_dx
            for k in range(4):
                dx2 = (bz + k - fz) / inv_dx
                wgt = wx[i] * wy[j] * wz[k]
                for a in range(3):
                    va = wgt * grid[bx + i, by + j, bz + k, 1 + a]
                    v[a] += va
                    b[a, 0] += va * dx0
                    b[a, 1] += va * dx1
                    b[a, 2] += va * dx2
    pinned = pin_mask.shape[0] > 0 and pin_mask[p] != 0
    if pinned:
        share = d_pin_share(pin_stop[p], t_new, dt)
        for a in range(3):
            v[a] = share * pin_velocity[p, a]
            for c in range(3):
                b[a, c] = 0.0
    elif colliders.shape[0]:
        d_collide_all(colliders, particle_x[p, 0], particle_x[p, 1], particle_x[p, 2], t_new, v, nrm)
    for a in range(3):
        particle_v[p, a] = v[a]
        particle_x[p, a] += dt * v[a]
        for c in range(3):
            particle_C[p, a, c] = b[a, c] * scale
    if colliders.shape[0] and not pinned:
        d_push_out(colliders, particle_x[p], t_new, nrm)
    s = d_particle_speed(v[0], v[1], v[2], particle_x, p)
    if s < 0.0:
        cuda.atomic.add(stats, STAT_BAD, 1.0)
        return
    cuda.atomic.max(stats, STAT_VMAX, s)
    for a in range(3):
        cuda.atomic.min(stats, STAT_LO + a, particle_x[p, a])
        cuda.atomic.max(stats, STAT_HI + a, particle_x[p, a])
