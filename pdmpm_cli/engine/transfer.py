"""MPM transfers (paper section 3, steps 1, 3-6): P2G, grid update with colliders, G2P with APIC.

The grid is dense over the domain, but each step touches only the node box around the particles.
P2G scatters into one private grid per thread (fixed particle chunks, fixed reduction order), so the
result does not depend on thread timing: runs are bitwise reproducible for a given thread count.
"""

import math

import numpy as np
from numba import njit, prange

from pdmpm_cli.engine.bspline import cubic_weights
from pdmpm_cli.engine.colliders import collide_all, push_out, respond

WALL = 3  # nodes within this many cells of the domain edge act as walls; particles stay >= 1 cell inside


@njit(cache=True, inline="always")
def particle_speed(v, particle_x, p):
    """|v| of particle p after its update, or -1 when its velocity or position is not finite."""
    s = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if math.isfinite(s) and math.isfinite(particle_x[p, 0] + particle_x[p, 1] + particle_x[p, 2]):
        return s
    return -1.0


@njit(cache=True, inline="always")
def stencil_on_grid(fx, fy, fz, grid):
    """Whether the 4 x 4 x 4 B-spline stencil of a particle at (fx, fy, fz) (in cells) lies on the grid."""
    return fx >= 1.0 and fy >= 1.0 and fz >= 1.0 and fx < grid.shape[0] - 3 and fy < grid.shape[1] - 3 \
        and fz < grid.shape[2] - 3


@njit(parallel=True, cache=True)
def p2g(particle_x, particle_v, particle_C, particle_mass, particle_force, particle_crack, pin_mask, dt, origin,
        inv_dx, box, grid_private, grid):
    """P2G of mass, APIC momentum and dt * bond force (eq. 7: f_I = sum_p N_I(x_p) f_p) -> grid.

    Crack-surface particles (particle_crack = 1; the array is empty without fracture) stay off the grid:
    they have their own integrator (section 6). Pinned particles bring their prescribed momentum but not their
    bond force: that force is the grip's reaction, and scattering it would pull their free neighbours.
    Returns the number of particles outside the valid domain."""
    has_crack = particle_crack.shape[0] > 0
    has_pins = pin_mask.shape[0] > 0
    nt = grid_private.shape[0]
    n = particle_x.shape[0]
    outside = 0
    for t in prange(nt):
        g = grid_private[t]
        g[box[0]:box[1], box[2]:box[3], box[4]:box[5], :] = 0.0
        wx = np.empty(4)
        wy = np.empty(4)
        wz = np.empty(4)
        for p in range(t * n // nt, (t + 1) * n // nt):
            if has_crack and particle_crack[p]:
                continue
            fx = (particle_x[p, 0] - origin[0]) * inv_dx
            fy = (particle_x[p, 1] - origin[1]) * inv_dx
            fz = (particle_x[p, 2] - origin[2]) * inv_dx
            if not stencil_on_grid(fx, fy, fz, grid):
                outside += 1
                continue
            bx = cubic_weights(fx, wx)
            by = cubic_weights(fy, wy)
            bz = cubic_weights(fz, wz)
            m = particle_mass[p]
            c = particle_C[p]
            fdt = 0.0 if has_pins and pin_mask[p] else dt
            for i in range(4):
                dx0 = (bx + i - fx) / inv_dx
                for j in range(4):
                    dx1 = (by + j - fy) / inv_dx
                    wij = wx[i] * wy[j]
                    for k in range(4):
                        dx2 = (bz + k - fz) / inv_dx
                        wgt = wij * wz[k]
                        node = g[bx + i, by + j, bz + k]
                        node[0] += wgt * m
                        for a in range(3):
                            mom = m * (particle_v[p, a] + c[a, 0] * dx0 + c[a, 1] * dx1 + c[a, 2] * dx2)
                            node[1 + a] += wgt * (mom + fdt * particle_force[p, a])
    for i in prange(box[0], box[1]):
        for j in range(box[2], box[3]):
            for k in range(box[4], box[5]):
                for q in range(4):
                    s = 0.0
                    for t in range(nt):
                        s += grid_private[t, i, j, k, q]
                    grid[i, j, k, q] = s
    return outside


@njit(parallel=True, cache=True)
def grid_update(grid, dt, gravity, wind, drag, origin, dx, box, t_new, colliders, wall_boundary, wall_friction):
    """Grid momentum -> velocity, v_I += dt g (step 3) and the wind's drag towards `wind` at rate `drag`
    (implicit, stable for any dt), domain walls and colliders (step 4); in place."""
    relax = 1.0 / (1.0 + dt * drag)
    nx, ny, nz = grid.shape[0], grid.shape[1], grid.shape[2]
    hi = (nx - 1 - WALL, ny - 1 - WALL, nz - 1 - WALL)
    for i in prange(box[0], box[1]):
        v = np.empty(3)
        nrm = np.empty(3)
        for j in range(box[2], box[3]):
            for k in range(box[4], box[5]):
                node = grid[i, j, k]
                m = node[0]
                if m <= 0.0:
                    continue
                for a in range(3):
                    v[a] = (node[1 + a] / m + dt * (gravity[a] + drag * wind[a])) * relax
                idx = (i, j, k)
                for a in range(3):
                    side = 1.0 if idx[a] < WALL else (-1.0 if idx[a] > hi[a] else 0.0)
                    if side != 0.0:
                        nrm[0], nrm[1], nrm[2] = 0.0, 0.0, 0.0
                        nrm[a] = side
                        respond(v, 0.0, 0.0, 0.0, nrm, wall_boundary, wall_friction)
                if colliders.shape[0]:
                    collide_all(colliders, origin[0] + i * dx, origin[1] + j * dx, origin[2] + k * dx,
                                t_new, v, nrm)
                node[1], node[2], node[3] = v[0], v[1], v[2]


@njit(parallel=True, cache=True)
def g2p(grid, dt, origin, inv_dx, t_new, colliders, pin_mask, pin_velocity, particle_crack, particle_x,
        particle_v, particle_C):
    """G2P velocity and APIC affine matrix (step 5), pins, particle collisions (step 6), advection; crack-surface
    particles are left to their own integrator. Returns (max particle speed, number of non-finite particles)."""
    n = particle_x.shape[0]
    has_pins = pin_mask.shape[0] > 0
    has_crack = particle_crack.shape[0] > 0
    vmax = 0.0
    bad = 0
    scale = 3.0 * inv_dx * inv_dx  # D_p^-1 for cubic B-splines (Jiang et al. 2015)
    for p in prange(n):
        if has_crack and particle_crack[p]:
            continue
        wx = np.empty(4)
        wy = np.empty(4)
        wz = np.empty(4)
        v = np.zeros(3)
        b = np.zeros((3, 3))
        nrm = np.empty(3)
        fx = (particle_x[p, 0] - origin[0]) * inv_dx
        fy = (particle_x[p, 1] - origin[1]) * inv_dx
        fz = (particle_x[p, 2] - origin[2]) * inv_dx
        bx = cubic_weights(fx, wx)
        by = cubic_weights(fy, wy)
        bz = cubic_weights(fz, wz)
        for i in range(4):
            dx0 = (bx + i - fx) / inv_dx
            for j in range(4):
                dx1 = (by + j - fy) / inv_dx
                for k in range(4):
                    dx2 = (bz + k - fz) / inv_dx
                    wgt = wx[i] * wy[j] * wz[k]
                    node = grid[bx + i, by + j, bz + k]
                    for a in range(3):
                        va = wgt * node[1 + a]
                        v[a] += va
                        b[a, 0] += va * dx0
                        b[a, 1] += va * dx1
                        b[a, 2] += va * dx2
        if has_pins and pin_mask[p]:
            for a in range(3):
                v[a] = pin_velocity[p, a]
            b[:, :] = 0.0
        elif colliders.shape[0]:
            collide_all(colliders, particle_x[p, 0], particle_x[p, 1], particle_x[p, 2], t_new, v, nrm)
        for a in range(3):
            particle_v[p, a] = v[a]
            particle_x[p, a] += dt * v[a]
            for c in range(3):
                particle_C[p, a, c] = b[a, c] * scale
        if colliders.shape[0] and not (has_pins and pin_mask[p]):
            push_out(colliders, particle_x[p], t_new, nrm)
        s = particle_speed(v, particle_x, p)
        if s < 0.0:
            bad += 1
        else:
            vmax = max(vmax, s)
    return vmax, bad
