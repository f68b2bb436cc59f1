"""MPM transfers (paper section 3, steps 1, 3-6): P2G, grid update with colliders, G2P with APIC.

Each transfer is a per-particle (or per-node) formula, `*_at`, that both backends run: the CPU loops below, and
the CUDA backend one thread per item (engine/backends/cuda.py). The grid is dense over the domain, but each step
touches only the node box around the particles. On the CPU, P2G scatters into one private grid per thread (fixed
particle chunks, fixed reduction order), so runs are bitwise reproducible for a given thread count; on the GPU it
adds into the one grid with atomics (`scatter_node` becomes an atomic add there).
"""

import math

import numpy as np
from numba import njit, prange

from pdmpm_cli.engine.bspline import cubic_weights, cubic_weights_grad
from pdmpm_cli.engine.colliders import CLAMPED, collide_all, header_rows, push_out, respond, signed_distance

SAME_CRACK_COS = math.cos(math.pi / 4.0)  # crack directions within 45 degrees: one crack (fracture.SPLIT_COS)

WALL = 3  # nodes within this many cells of the domain edge act as walls; particles stay >= 1 cell inside
CHANNELS = 4  # a grid node: mass, then momentum (P2G) / velocity (after the grid update)
FLIP_CHANNELS = 7  # with a FLIP share: then the force impulse (P2G) / the velocity before the update, v_I^n


@njit(cache=True, inline="always")
def particle_speed(v0, v1, v2, particle_x, p):
    """|v| of particle p after its update, or -1 when its velocity or position is not finite."""
    s = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    if math.isfinite(s) and math.isfinite(particle_x[p, 0] + particle_x[p, 1] + particle_x[p, 2]):
        return s
    return -1.0


@njit(cache=True, inline="always")
def stencil_on_grid(fx, fy, fz, grid):
    """Whether the 4 x 4 x 4 B-spline stencil of a particle at (fx, fy, fz) (in cells) lies on the grid."""
    return fx >= 1.0 and fy >= 1.0 and fz >= 1.0 and fx < grid.shape[0] - 3 and fy < grid.shape[1] - 3 \
        and fz < grid.shape[2] - 3


@njit(cache=True, inline="always")
def stencil(particle_x, p, origin, inv_dx, wx, wy, wz):
    """Particle p's position in cells (fx, fy, fz) and the first node (bx, by, bz) of its 4 x 4 x 4 cubic B-spline
    stencil, with the weights per axis in wx, wy, wz (the one definition of the stencil every transfer uses)."""
    fx = (particle_x[p, 0] - origin[0]) * inv_dx
    fy = (particle_x[p, 1] - origin[1]) * inv_dx
    fz = (particle_x[p, 2] - origin[2]) * inv_dx
    return fx, fy, fz, cubic_weights(fx, wx), cubic_weights(fy, wy), cubic_weights(fz, wz)


@njit(cache=True, inline="always")
def stencil_with_gradients(particle_x, p, origin, inv_dx, wx, wy, wz, gx, gy, gz):
    """`stencil`, with the weights' derivatives per axis (per cell) in gx, gy, gz."""
    fx = (particle_x[p, 0] - origin[0]) * inv_dx
    fy = (particle_x[p, 1] - origin[1]) * inv_dx
    fz = (particle_x[p, 2] - origin[2]) * inv_dx
    return (fx, fy, fz, cubic_weights_grad(fx, wx, gx), cubic_weights_grad(fy, wy, gy),
            cubic_weights_grad(fz, wz, gz))


@njit(cache=True, inline="always")
def stencil_off_box(particle_x, p, origin, inv_dx, box):
    """Whether particle p's stencil surely misses the node box (it lies within cells floor(x) - 2 .. floor(x) + 3)."""
    for a in range(3):
        c = math.floor((particle_x[p, a] - origin[a]) * inv_dx)
        if c + 3 < box[2 * a] or c - 2 >= box[2 * a + 1]:
            return True
    return False


@njit(cache=True, inline="always")
def node_side(p, o, rest_x, crack_n, piece, half_h):
    """Field of particle p at a node that particle o's crack splits (engine/crack.py: o = -1 not split; o <= -2 the
    node sees two pieces and particle -o - 2 owns it): 1 in another piece than the owner's, or in the same one beyond
    its crack where the node sees one piece; else 0. Beyond it: a particle whose crack is a cutout's alone (a notch's
    face, crack_n[p, 3] = 1) and parallel to the owner's (within 45 degrees, as fracture.SPLIT_COS clusters) when the
    two point opposite ways, as CD-MPM sides particles by their damage gradients: the owner's plane need not run
    along the face (an owner ahead of a notch's tip, its crack a spacing or two off the notch's plane, reaches back
    over the faces); any other, when it lies beyond the owner's plane."""
    if o == -1:
        return 0
    if o <= -2:
        return 0 if piece[p] == piece[-o - 2] else 1
    if piece[p] != piece[o]:
        return 1
    if crack_n[p, 3] != 0.0:
        a = crack_n[p, 0] * crack_n[o, 0] + crack_n[p, 1] * crack_n[o, 1] + crack_n[p, 2] * crack_n[o, 2]
        if abs(a) >= SAME_CRACK_COS:
            return 1 if a < 0.0 else 0
    d = ((rest_x[p, 0] - rest_x[o, 0]) * crack_n[o, 0] + (rest_x[p, 1] - rest_x[o, 1]) * crack_n[o, 1]
         + (rest_x[p, 2] - rest_x[o, 2]) * crack_n[o, 2])
    return 1 if d > half_h else 0


@njit(cache=True, inline="always")
def scatter_node(g, i, j, k, m, p0, p1, p2):
    """g[i, j, k] += (m, p): on the CPU into the thread's private grid; the CUDA backend swaps in atomic adds."""
    g[i, j, k, 0] += m
    g[i, j, k, 1] += p0
    g[i, j, k, 2] += p1
    g[i, j, k, 3] += p2


@njit(cache=True, inline="always")
def scatter_impulse(g, i, j, k, f0, f1, f2):
    """g[i, j, k, 4:7] += dt f (a FLIP grid keeps the force out of the momentum); atomic adds on the GPU."""
    g[i, j, k, 4] += f0
    g[i, j, k, 5] += f1
    g[i, j, k, 6] += f2


@njit(cache=True)
def position_bounds(particle_x):
    """Per-axis smallest and largest particle position, (lo, hi): the extent the P2G node box covers. One serial pass
    over particle_x (numpy's axis reductions over an (n, 3) array walk it three times, strided; a parallel loop
    costs more to compile than the few milliseconds it would save at a million particles)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for p in range(particle_x.shape[0]):
        for a in range(3):
            x = particle_x[p, a]
            if x < lo[a]:
                lo[a] = x
            if x > hi[a]:
                hi[a] = x
    return lo, hi


@njit(cache=True, inline="always")
def p2g_at(p, particle_x, particle_v, particle_C, particle_mass, particle_force, particle_crack, pin_mask, dt, origin,
           inv_dx, g, wx, wy, wz, owner, rest_x, crack_n, piece, half_h, cbox, want):
    """P2G of particle p: mass, APIC momentum and dt * bond force (eq. 7: f_I = sum_p N_I(x_p) f_p) -> g.
    Returns 1 if its stencil is off the grid (it then scatters nothing), else 0. On a FLIP grid (FLIP_CHANNELS)
    the impulse goes to its own channels, so that the grid update can keep the velocity before it, v_I^n.

    Crack-surface particles (particle_crack = 1; the array is empty without fracture) stay off the grid:
    they have their own integrator (section 6). Pinned particles bring their prescribed momentum but not their
    bond force: that force is the grip's reaction, and scattering it would pull their free neighbours.

    With crack fields (owner not empty, engine/crack.py) only the nodes where p lies on side `want` get its share;
    a particle whose stencil misses the split nodes' box `cbox` is all on side 0."""
    if particle_crack.shape[0] > 0 and particle_crack[p] != 0:
        return 0
    sided = owner.shape[0] > 0 and not stencil_off_box(particle_x, p, origin, inv_dx, cbox)
    if want == 1 and not sided:
        return 0
    fx, fy, fz, bx, by, bz = stencil(particle_x, p, origin, inv_dx, wx, wy, wz)
    if not stencil_on_grid(fx, fy, fz, g):
        return 1
    dx = 1.0 / inv_dx
    m = particle_mass[p]
    fdt = 0.0 if pin_mask.shape[0] > 0 and pin_mask[p] != 0 else dt
    flip = g.shape[3] > CHANNELS
    mdt = 0.0 if flip else fdt  # the impulse in the momentum channels, or (FLIP) in its own
    # Node momentum m (v + C (x_i - x_p)) + dt f, built up axis by axis: the affine part of axis 0 is added once
    # per i, of axis 1 once per j, so the innermost loop does four multiply-adds per node.
    p0 = m * particle_v[p, 0] + mdt * particle_force[p, 0]
    p1 = m * particle_v[p, 1] + mdt * particle_force[p, 1]
    p2 = m * particle_v[p, 2] + mdt * particle_force[p, 2]
    c00, c01, c02 = m * particle_C[p, 0, 0], m * particle_C[p, 0, 1], m * particle_C[p, 0, 2]
    c10, c11, c12 = m * particle_C[p, 1, 0], m * particle_C[p, 1, 1], m * particle_C[p, 1, 2]
    c20, c21, c22 = m * particle_C[p, 2, 0], m * particle_C[p, 2, 1], m * particle_C[p, 2, 2]
    for i in range(4):
        d0 = (bx + i - fx) * dx
        q0, q1, q2 = p0 + c00 * d0, p1 + c10 * d0, p2 + c20 * d0
        for j in range(4):
            d1 = (by + j - fy) * dx
            r0, r1, r2 = q0 + c01 * d1, q1 + c11 * d1, q2 + c21 * d1
            wij = wx[i] * wy[j]
            for k in range(4):
                if sided and node_side(p, owner[bx + i, by + j, bz + k], rest_x, crack_n, piece, half_h) != want:
                    continue
                d2 = (bz + k - fz) * dx
                w = wij * wz[k]
                scatter_node(g, bx + i, by + j, bz + k, w * m, w * (r0 + c02 * d2), w * (r1 + c12 * d2),
                             w * (r2 + c22 * d2))
    if flip and fdt != 0.0:
        f0, f1, f2 = fdt * particle_force[p, 0], fdt * particle_force[p, 1], fdt * particle_force[p, 2]
        for i in range(4):
            for j in range(4):
                wij = wx[i] * wy[j]
                for k in range(4):
                    if sided and node_side(p, owner[bx + i, by + j, bz + k], rest_x, crack_n, piece, half_h) != want:
                        continue
                    w = wij * wz[k]
                    scatter_impulse(g, bx + i, by + j, bz + k, w * f0, w * f1, w * f2)
    return 0


@njit(parallel=True, cache=True)
def p2g(particle_x, particle_v, particle_C, particle_mass, particle_force, particle_crack, pin_mask, dt, origin,
        inv_dx, box, grid_private, grid, owner, rest_x, crack_n, piece, half_h, cbox, want):
    """`p2g_at` for every particle -> grid: thread t scatters a fixed particle range into grid_private[t] (cleared
    on the node box), then the private grids are summed in thread order. Returns the number of particles off the
    grid. With crack fields, `grid` is side `want` of the body's field (engine/crack.py)."""
    nt = grid_private.shape[0]
    n = particle_x.shape[0]
    outside = 0
    for t in prange(nt):
        g = grid_private[t]
        for i in range(box[0], box[1]):
            for j in range(box[2], box[3]):
                for k in range(box[4], box[5]):
                    for q in range(g.shape[3]):
                        g[i, j, k, q] = 0.0
        wx = np.empty(4)
        wy = np.empty(4)
        wz = np.empty(4)
        for p in range(t * n // nt, (t + 1) * n // nt):
            outside += p2g_at(p, particle_x, particle_v, particle_C, particle_mass, particle_force, particle_crack,
                              pin_mask, dt, origin, inv_dx, g, wx, wy, wz, owner, rest_x, crack_n, piece, half_h,
                              cbox, want)
    for i in prange(box[0], box[1]):
        for j in range(box[2], box[3]):
            for k in range(box[4], box[5]):
                for q in range(grid.shape[3]):
                    s = 0.0
                    for t in range(nt):
                        s += grid_private[t, i, j, k, q]
                    grid[i, j, k, q] = s
    return outside


@njit(cache=True, inline="always")
def grid_node_update(i, j, k, grid, dt, gravity, wind, drag, origin, dx, t_new, colliders, wall_boundary,
                     wall_friction, v, nrm):
    """Node (i, j, k): momentum -> velocity, v_I += dt g (step 3) and the wind's drag towards `wind` at rate
    `drag` (implicit, stable for any dt), domain walls and colliders (step 4); in place. A FLIP grid keeps the
    velocity before all of it, v_I^n, in channels 4-6 (g2p_at's FLIP share reads it)."""
    m = grid[i, j, k, 0]
    if m <= 0.0:
        return
    relax = 1.0 / (1.0 + dt * drag)
    if grid.shape[3] > CHANNELS:
        for a in range(3):
            impulse = grid[i, j, k, 4 + a]
            grid[i, j, k, 4 + a] = grid[i, j, k, 1 + a] / m
            grid[i, j, k, 1 + a] += impulse
    for a in range(3):
        v[a] = (grid[i, j, k, 1 + a] / m + dt * (gravity[a] + drag * wind[a])) * relax
    for a in range(3):
        idx = i if a == 0 else (j if a == 1 else k)
        hi = (grid.shape[0] if a == 0 else (grid.shape[1] if a == 1 else grid.shape[2])) - 1 - WALL
        side = 1.0 if idx < WALL else (-1.0 if idx > hi else 0.0)
        if side != 0.0:
            nrm[0], nrm[1], nrm[2] = 0.0, 0.0, 0.0
            nrm[a] = side
            respond(v, 0.0, 0.0, 0.0, nrm, wall_boundary, wall_friction)
    if colliders.shape[0]:
        collide_all(colliders, origin[0] + i * dx, origin[1] + j * dx, origin[2] + k * dx, t_new, v, nrm)
    grid[i, j, k, 1], grid[i, j, k, 2], grid[i, j, k, 3] = v[0], v[1], v[2]


@njit(parallel=True, cache=True)
def grid_update(grid, dt, gravity, wind, drag, origin, dx, box, t_new, colliders, wall_boundary, wall_friction):
    """`grid_node_update` on every node of the box."""
    for i in prange(box[0], box[1]):
        v = np.empty(3)
        nrm = np.empty(3)
        for j in range(box[2], box[3]):
            for k in range(box[4], box[5]):
                grid_node_update(i, j, k, grid, dt, gravity, wind, drag, origin, dx, t_new, colliders,
                                 wall_boundary, wall_friction, v, nrm)


MIRROR_DEPTH = 3.0  # cells behind a clamped plane whose nodes are mirrored (the cubic B-spline reaches 2)


def has_clamped(colliders) -> bool:
    """Whether the packed collider table holds a clamped plane (then `mirror_clamped` follows each grid update)."""
    return any(int(colliders[c, 13]) == CLAMPED for c in header_rows(colliders))


@njit(cache=True, inline="always")
def behind_clamped(colliders, x0, x1, x2, t, n):
    """Whether point x is on or behind any clamped plane."""
    c = 0
    while c < colliders.shape[0]:
        if int(colliders[c, 13]) == CLAMPED and signed_distance(colliders, c, x0, x1, x2, t, n) <= 0.0:
            return True
        c += int(colliders[c, 15])
    return False


@njit(parallel=True, cache=True)
def mirror_clamped(grid, origin, dx, box, t_new, colliders):
    """After the grid update: each node with mass less than MIRROR_DEPTH cells behind a clamped plane takes
    v = 2 v_c - v(x_m), the odd reflection of the velocity at its mirror point x_m = x - 2 phi n (trilinear from the
    nodes in front of every clamped plane; one on or behind one, or without mass, counts as v_c). The projection
    has zeroed these nodes' relative velocity, which the particles near the plane had extrapolated through it (APIC's
    affine part), every step: an inelastic loss a clamped end must not have. Mirrored, the grid's velocity vanishes
    at the plane itself and the particles keep their affine motion; for a plane on a node plane with an axis normal
    the mirror point is a node, the exact reflection (docs/method.md, 'Clamped planes')."""
    inv = 1.0 / dx
    for i in prange(box[0], box[1]):
        n = np.empty(3)
        nc = np.empty(3)
        v = np.empty(3)
        for j in range(box[2], box[3]):
            for k in range(box[4], box[5]):
                if grid[i, j, k, 0] <= 0.0:
                    continue
                x0, x1, x2 = origin[0] + i * dx, origin[1] + j * dx, origin[2] + k * dx
                c = 0
                while c < colliders.shape[0]:
                    row = colliders[c]
                    phi = signed_distance(colliders, c, x0, x1, x2, t_new, n) if int(row[13]) == CLAMPED else 1.0
                    if -MIRROR_DEPTH * dx < phi < 0.0:
                        f0 = (x0 - 2.0 * phi * n[0] - origin[0]) * inv
                        f1 = (x1 - 2.0 * phi * n[1] - origin[1]) * inv
                        f2 = (x2 - 2.0 * phi * n[2] - origin[2]) * inv
                        i0, j0, k0 = int(math.floor(f0)), int(math.floor(f1)), int(math.floor(f2))
                        a0, a1, a2 = f0 - i0, f1 - j0, f2 - k0
                        v[0] = v[1] = v[2] = 0.0
                        for di in range(2):
                            for dj in range(2):
                                for dk in range(2):
                                    w = ((a0 if di else 1.0 - a0) * (a1 if dj else 1.0 - a1)
                                         * (a2 if dk else 1.0 - a2))
                                    if w == 0.0:
                                        continue
                                    ii, jj, kk = i0 + di, j0 + dj, k0 + dk
                                    front = (0 <= ii < grid.shape[0] and 0 <= jj < grid.shape[1]
                                             and 0 <= kk < grid.shape[2] and grid[ii, jj, kk, 0] > 0.0
                                             and not behind_clamped(colliders, origin[0] + ii * dx,
                                                                    origin[1] + jj * dx, origin[2] + kk * dx,
                                                                    t_new, nc))
                                    for a in range(3):
                                        v[a] += w * (grid[ii, jj, kk, 1 + a] if front else row[10 + a])
                        for a in range(3):
                            grid[i, j, k, 1 + a] = 2.0 * row[10 + a] - v[a]
                    c += int(row[15])


@njit(cache=True, inline="always")
def pin_share(stop, t_new, dt):
    """Share of the step t_new - dt .. t_new a pin that stops at `stop` still moves: its particles then travel
    velocity * stop exactly, whatever the steps (1 for a pin that never stops, stop = inf). Branches, not the
    builtin min and max, which numba 0.68's CUDA target cannot compile."""
    share = (stop - (t_new - dt)) / dt
    if share >= 1.0:
        return 1.0
    return share if share > 0.0 else 0.0


@njit(cache=True, inline="always")
def affine_sums(grid, grid1, c, bx, by, bz, fx, fy, fz, dx, wx, wy, wz, sided, p, owner, rest_x, crack_n, piece,
                half_h):
    """sum_i w_i u_i and sum_i w_i u_i (x_i - x_p)^T over a particle's 64 nodes, u the grid's channels c..c+2:
    the velocity and the affine moments B_p of APIC's G2P (step 5). `sided` (crack fields, engine/crack.py): u is
    read from grid1 at the nodes where particle p lies on side 1."""
    # The sums over the 64 nodes of w u and w u (x_i - x_p) factor axis by axis (w = wx wy wz, and each component
    # of x_i - x_p depends on one axis): sum over k first, then j, then i.
    v0 = v1 = v2 = 0.0
    b00 = b01 = b02 = b10 = b11 = b12 = b20 = b21 = b22 = 0.0
    for i in range(4):
        d0 = (bx + i - fx) * dx
        t0 = t1 = t2 = 0.0  # sum_jk wy wz u
        s0 = s1 = s2 = 0.0  # sum_jk wy wz u d1
        z0 = z1 = z2 = 0.0  # sum_jk wy wz u d2
        for j in range(4):
            d1 = (by + j - fy) * dx
            k0 = k1 = k2 = 0.0  # sum_k wz u
            e0 = e1 = e2 = 0.0  # sum_k wz u d2
            for k in range(4):
                d2 = (bz + k - fz) * dx
                w = wz[k]
                src = grid
                if sided and node_side(p, owner[bx + i, by + j, bz + k], rest_x, crack_n, piece, half_h) == 1:
                    src = grid1
                u0 = w * src[bx + i, by + j, bz + k, c]
                u1 = w * src[bx + i, by + j, bz + k, c + 1]
                u2 = w * src[bx + i, by + j, bz + k, c + 2]
                k0 += u0
                k1 += u1
                k2 += u2
                e0 += u0 * d2
                e1 += u1 * d2
                e2 += u2 * d2
            w = wy[j]
            t0 += w * k0
            t1 += w * k1
            t2 += w * k2
            s0 += w * d1 * k0
            s1 += w * d1 * k1
            s2 += w * d1 * k2
            z0 += w * e0
            z1 += w * e1
            z2 += w * e2
        w = wx[i]
        v0 += w * t0
        v1 += w * t1
        v2 += w * t2
        b00 += w * d0 * t0
        b10 += w * d0 * t1
        b20 += w * d0 * t2
        b01 += w * s0
        b11 += w * s1
        b21 += w * s2
        b02 += w * z0
        b12 += w * z1
        b22 += w * z2
    return v0, v1, v2, b00, b01, b02, b10, b11, b12, b20, b21, b22


@njit(cache=True, inline="always")
def grid_density(grid, bx, by, bz, wx, wy, wz):
    """sum_i w_i m_i over a particle's 64 nodes [kg] (the grid's mass channel 0)."""
    mass = 0.0
    for i in range(4):
        for j in range(4):
            wij = wx[i] * wy[j]
            for k in range(4):
                mass += wij * wz[k] * grid[bx + i, by + j, bz + k, 0]
    return mass


@njit(cache=True, inline="always")
def g2p_at(p, grid, dt, origin, inv_dx, t_new, colliders, pin_mask, pin_velocity, pin_stop, flip, particle_crack,
           particle_x, particle_v, particle_C, particle_rho, wx, wy, wz, v, nrm, grid1, owner, rest_x, crack_n, piece,
           half_h, cbox):
    """G2P of particle p: velocity and APIC affine matrix (step 5), pins, particle collisions (step 6), advection.
    Returns its speed, -1 when it is not finite, 0 for a crack-surface particle (left to its own integrator).

    On a FLIP grid (FLIP_CHANNELS) the new velocity and affine matrix are the grid's plus the share `flip` of what
    the particle carried and the grid did not, (v_p, C_p) - G2P(v_I^n) (Fei et al. 2021, eq. 9, applied to the
    affine matrix too: APIC's transfers are those of PIC for the pair (v, C) under the mass m_p diag(1, D_p)), and
    the particle does not move here: `advect_at` moves it with the re-mapped velocity (MUSL). With crack fields
    (owner not empty) grid and grid1 are the two sides of the body's field (engine/crack.py). Where particle_rho is
    allocated (a material reads it: MaterialKind.reads_grid_density) it gets the grid's mass density at the
    particle, sum_i w_i m_i / dx^3, from the nodes the velocity sums just read (pinned particles: not written)."""
    if particle_crack.shape[0] > 0 and particle_crack[p] != 0:
        return 0.0
    dx = 1.0 / inv_dx
    scale = 3.0 * inv_dx * inv_dx  # D_p^-1 for cubic B-splines (Jiang et al. 2015)
    sided = owner.shape[0] > 0 and not stencil_off_box(particle_x, p, origin, inv_dx, cbox)
    pinned = pin_mask.shape[0] > 0 and pin_mask[p] != 0
    remapped = grid.shape[3] > CHANNELS
    if pinned:  # the prescribed velocity, no affine part: the grid's are not read
        share = pin_share(pin_stop[p], t_new, dt)
        v0, v1, v2 = share * pin_velocity[p, 0], share * pin_velocity[p, 1], share * pin_velocity[p, 2]
        b00 = b01 = b02 = b10 = b11 = b12 = b20 = b21 = b22 = 0.0
    else:
        fx, fy, fz, bx, by, bz = stencil(particle_x, p, origin, inv_dx, wx, wy, wz)
        v0, v1, v2, b00, b01, b02, b10, b11, b12, b20, b21, b22 = affine_sums(grid, grid1, 1, bx, by, bz, fx, fy, fz,
                                                                             dx, wx, wy, wz, sided, p, owner, rest_x,
                                                                             crack_n, piece, half_h)
        if particle_rho.shape[0] > 0:
            particle_rho[p] = grid_density(grid, bx, by, bz, wx, wy, wz) * inv_dx * inv_dx * inv_dx
        if remapped:
            o0, o1, o2, a00, a01, a02, a10, a11, a12, a20, a21, a22 = affine_sums(grid, grid1, 4, bx, by, bz, fx, fy,
                                                                                 fz, dx, wx, wy, wz, sided, p, owner,
                                                                                 rest_x, crack_n, piece, half_h)
            v0 += flip * (particle_v[p, 0] - o0)
            v1 += flip * (particle_v[p, 1] - o1)
            v2 += flip * (particle_v[p, 2] - o2)
            g = flip / scale
            b00 += g * (particle_C[p, 0, 0] - a00 * scale)
            b01 += g * (particle_C[p, 0, 1] - a01 * scale)
            b02 += g * (particle_C[p, 0, 2] - a02 * scale)
            b10 += g * (particle_C[p, 1, 0] - a10 * scale)
            b11 += g * (particle_C[p, 1, 1] - a11 * scale)
            b12 += g * (particle_C[p, 1, 2] - a12 * scale)
            b20 += g * (particle_C[p, 2, 0] - a20 * scale)
            b21 += g * (particle_C[p, 2, 1] - a21 * scale)
            b22 += g * (particle_C[p, 2, 2] - a22 * scale)
        if colliders.shape[0]:
            v[0], v[1], v[2] = v0, v1, v2
            collide_all(colliders, particle_x[p, 0], particle_x[p, 1], particle_x[p, 2], t_new, v, nrm)
            v0, v1, v2 = v[0], v[1], v[2]
    particle_v[p, 0], particle_v[p, 1], particle_v[p, 2] = v0, v1, v2
    particle_C[p, 0, 0], particle_C[p, 0, 1], particle_C[p, 0, 2] = b00 * scale, b01 * scale, b02 * scale
    particle_C[p, 1, 0], particle_C[p, 1, 1], particle_C[p, 1, 2] = b10 * scale, b11 * scale, b12 * scale
    particle_C[p, 2, 0], particle_C[p, 2, 1], particle_C[p, 2, 2] = b20 * scale, b21 * scale, b22 * scale
    if remapped:
        return particle_speed(v0, v1, v2, particle_x, p)
    particle_x[p, 0] += dt * v0
    particle_x[p, 1] += dt * v1
    particle_x[p, 2] += dt * v2
    if colliders.shape[0] and not pinned:
        push_out(colliders, particle_x[p], t_new, nrm)
    return particle_speed(v0, v1, v2, particle_x, p)


@njit(parallel=True, cache=True)
def g2p(grid, dt, origin, inv_dx, t_new, colliders, pin_mask, pin_velocity, pin_stop, flip, particle_crack,
        particle_x, particle_v, particle_C, particle_rho, chunks, grid1, owner, rest_x, crack_n, piece, half_h, cbox):
    """`g2p_at` for every particle, in `chunks` static chunks, each with its own scratch. Returns (max particle
    speed, number of non-finite particles)."""
    n = particle_x.shape[0]
    chunk_vmax = np.zeros(chunks)
    chunk_bad = np.zeros(chunks, dtype=np.int64)
    for t in prange(chunks):
        wx = np.empty(4)
        wy = np.empty(4)
        wz = np.empty(4)
        v = np.empty(3)
        nrm = np.empty(3)
        for p in range(t * n // chunks, (t + 1) * n // chunks):
            s = g2p_at(p, grid, dt, origin, inv_dx, t_new, colliders, pin_mask, pin_velocity, pin_stop, flip,
                       particle_crack, particle_x, particle_v, particle_C, particle_rho, wx, wy, wz, v, nrm, grid1,
                       owner, rest_x, crack_n, piece, half_h, cbox)
            if s < 0.0:
                chunk_bad[t] += 1
            else:
                chunk_vmax[t] = max(chunk_vmax[t], s)
    return chunk_vmax.max(), chunk_bad.sum()


@njit(cache=True, inline="always")
def advect_at(p, grid, dt, origin, inv_dx, t_new, colliders, pin_mask, particle_crack, particle_x, particle_v, wx, wy,
              wz, nrm, grid1, owner, rest_x, crack_n, piece, half_h, cbox):
    """MUSL's position update of particle p (Sulsky et al. 1995), after G2P on a FLIP grid: x_p += dt sum_I w_Ip v_I
    with v_I the particles' new velocities mapped back to the grid (P2G with no force, then walls, colliders and
    contact), at the positions G2P read. With frozen weights the FLIP update and this one conserve the energy
    1/2 m_p (|v_p|^2 + D_p C_p : C_p) + W (Bardenhagen 2002); moving the particles with the grid velocity of the
    step (as g2p_at does for APIC) makes positions and velocities disagree by dt^2 per step, which damps elastic
    motion at any step size. Pinned particles travel their prescribed velocity. Returns the speed as g2p_at. Crack
    fields as in g2p_at."""
    sided = owner.shape[0] > 0 and not stencil_off_box(particle_x, p, origin, inv_dx, cbox)
    if particle_crack.shape[0] > 0 and particle_crack[p] != 0:
        return 0.0
    pinned = pin_mask.shape[0] > 0 and pin_mask[p] != 0
    if pinned:
        u0, u1, u2 = particle_v[p, 0], particle_v[p, 1], particle_v[p, 2]
    else:
        fx, fy, fz, bx, by, bz = stencil(particle_x, p, origin, inv_dx, wx, wy, wz)
        u0 = u1 = u2 = 0.0
        for i in range(4):
            for j in range(4):
                wij = wx[i] * wy[j]
                for k in range(4):
                    w = wij * wz[k]
                    src = grid
                    if sided and node_side(p, owner[bx + i, by + j, bz + k], rest_x, crack_n, piece, half_h) == 1:
                        src = grid1
                    u0 += w * src[bx + i, by + j, bz + k, 1]
                    u1 += w * src[bx + i, by + j, bz + k, 2]
                    u2 += w * src[bx + i, by + j, bz + k, 3]
    particle_x[p, 0] += dt * u0
    particle_x[p, 1] += dt * u1
    particle_x[p, 2] += dt * u2
    if colliders.shape[0] and not pinned:
        push_out(colliders, particle_x[p], t_new, nrm)
    return particle_speed(particle_v[p, 0], particle_v[p, 1], particle_v[p, 2], particle_x, p)


@njit(parallel=True, cache=True)
def advect(grid, dt, origin, inv_dx, t_new, colliders, pin_mask, particle_crack, particle_x, particle_v, chunks, grid1,
           owner, rest_x, crack_n, piece, half_h, cbox):
    """`advect_at` for every particle, in `chunks` static chunks. Returns (max particle speed, number of non-finite
    particles)."""
    n = particle_x.shape[0]
    chunk_vmax = np.zeros(chunks)
    chunk_bad = np.zeros(chunks, dtype=np.int64)
    for t in prange(chunks):
        wx = np.empty(4)
        wy = np.empty(4)
        wz = np.empty(4)
        nrm = np.empty(3)
        for p in range(t * n // chunks, (t + 1) * n // chunks):
            s = advect_at(p, grid, dt, origin, inv_dx, t_new, colliders, pin_mask, particle_crack, particle_x,
                          particle_v, wx, wy, wz, nrm, grid1, owner, rest_x, crack_n, piece, half_h,
                          cbox)
            if s < 0.0:
                chunk_bad[t] += 1
            else:
                chunk_vmax[t] = max(chunk_vmax[t], s)
    return chunk_vmax.max(), chunk_bad.sum()
