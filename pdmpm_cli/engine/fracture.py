"""Fracture (paper section 6, eq. 21): bond criterion, plane cuts through candidate clusters, damage,
and the grid-free integrator of crack-surface particles.

Criterion of bond p-q, read as a strain (eq. 21): l = (s - e_p) / (1 + p_inactive), s = |eta| / |xi| - 1,
where p_inactive is the fraction of broken bonds among all bonds of the particles in p's grid cell: a cell
that already holds a crack resists further breaking, which keeps the crack from turning into dust.
Particles with an active bond over the threshold are candidates. Candidates joined by active bonds whose
most deformed bonds point within 45 degrees of each other form a cluster; each cluster cuts its bonds by
one plane through its centroid, normal to its most deformed bond, so a crack grows as a surface.
Bonds are stored in both directions and are always cut in both.
"""

import math

import numpy as np
from numba import njit, prange
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from pdmpm_cli.engine.bonds import bond_vector
from pdmpm_cli.engine.colliders import collide_all, push_out
from pdmpm_cli.engine.kernel import Kernel
from pdmpm_cli.engine.transfer import SAME_CRACK_COS, particle_speed, stencil_on_grid, stencil_with_gradients

CONTACT_DAMAGE = 0.5  # crack particles with at least this damage (mostly detached) take part in grid contact
SPLIT_COS = SAME_CRACK_COS  # candidates whose bonds open in directions > 45 degrees apart: two cracks


def critical_stretch(energy: float, modulus: float, horizon: float) -> float:
    """Threshold s0 [-] whose bonds, all at s0, hold `energy` G_c [J/m^2] per unit area crossing them.

    Madenci & Oterkus' integral over the bonds crossing a plane, G_c = pi int_0^delta xi^3 phi_c(xi) dxi, with this
    engine's pair energy at stretch s0, phi_c = c M w s0^2 (c = 5 / omega = 15 / (pi delta^3), w = 1 - xi / delta):
    G_c = 3/4 M delta s0^2 (docs/method.md, 'Fracture energy')."""
    return math.sqrt(4.0 * energy / (3.0 * modulus * horizon))


@njit(cache=True, inline="always")
def cell_key(particle_x, p, origin, inv_dx, cells):
    """Linear index of particle p's grid cell (particles outside the grid count in the nearest boundary cell)."""
    k = 0
    for a in range(3):
        i = int(math.floor((particle_x[p, a] - origin[a]) * inv_dx))
        i = 0 if i < 0 else (cells[a] - 1 if i > cells[a] - 1 else i)
        k = k * cells[a] + i
    return k


@njit(cache=True, inline="always")
def broken_bonds(p, bond_start, bond_active):
    """Number of p's broken bonds."""
    nb = 0
    for b in range(bond_start[p], bond_start[p + 1]):
        if bond_active[b] == 0:
            nb += 1
    return nb


@njit(parallel=True, cache=True)
def inactive_fraction(particle_x, origin, inv_dx, cells, bond_start, bond_active, cell_bonds, cell_broken,
                      particle_inactive):
    """p_inactive of eq. 21: broken / all bonds of the particles in each particle's cell -> particle_inactive.

    The counts go into dense per-cell arrays (cell_bonds, cell_broken, as on the GPU), of which only the particles'
    own cells are cleared and summed: linear in the particles, with no sort. They are integers, summed serially, so
    the result depends neither on the thread count nor on the backend."""
    n = particle_x.shape[0]
    key = np.empty(n, np.int64)
    broken = np.empty(n, np.int64)
    total = 0
    for p in prange(n):
        key[p] = cell_key(particle_x, p, origin, inv_dx, cells)
        broken[p] = broken_bonds(p, bond_start, bond_active)
        total += broken[p]
    if total == 0:
        particle_inactive[:] = 0.0
        return
    for p in range(n):
        cell_bonds[key[p]] = 0
        cell_broken[key[p]] = 0
    for p in range(n):
        cell_bonds[key[p]] += bond_start[p + 1] - bond_start[p]
        cell_broken[key[p]] += broken[p]
    for p in prange(n):
        nt = cell_bonds[key[p]]
        particle_inactive[p] = cell_broken[key[p]] / nt if nt > 0 else 0.0


@njit(cache=True)
def criterion_at(p, threshold, resistance, particle_x, rest_x, bond_start, bond_nbr, bond_active, bond_ep,
                 particle_inactive, particle_lmax, particle_bmax):
    """Largest eq. 21 criterion over p's active bonds -> particle_lmax[p], its bond -> particle_bmax[p] (0 and -1
    without active bonds); returns 1 if it is over the threshold (a fracture candidate), else 0.

    `resistance` k weighs p_inactive: l = (s - e_p) / (1 + k p_inactive); k = 1 is eq. 21. bond_ep of shape (0,)
    means no plasticity (e_p = 0)."""
    has_ep = bond_ep.shape[0] > 0
    scale = 1.0 / (1.0 + resistance * particle_inactive[p])
    best = -math.inf
    arg = -1
    for b in range(bond_start[p], bond_start[p + 1]):
        if bond_active[b] == 0:
            continue
        q = bond_nbr[b]
        s = bond_vector(particle_x, p, q)[3] / bond_vector(rest_x, p, q)[3] - 1.0
        if has_ep:
            s -= bond_ep[b]
        if s * scale > best:
            best = s * scale
            arg = b
    if arg < 0:
        best = 0.0
    particle_lmax[p] = best
    particle_bmax[p] = arg
    return 1 if arg >= 0 and best > threshold else 0


@njit(parallel=True, cache=True)
def bond_criterion(start, end, threshold, resistance, particle_x, rest_x, bond_start, bond_nbr, bond_active,
                   bond_ep, particle_inactive, particle_lmax, particle_bmax):
    """`criterion_at` for particles start..end-1; returns the number of candidates."""
    count = 0
    for p in prange(start, end):
        count += criterion_at(p, threshold, resistance, particle_x, rest_x, bond_start, bond_nbr, bond_active,
                              bond_ep, particle_inactive, particle_lmax, particle_bmax)
    return count


CRITERION = Kernel(criterion_at, bond_criterion, reduce="sum")


@njit(cache=True)
def cut_pair(b, p, bond_start, bond_nbr, bond_active):
    """Break bond b (p -> q) and its reverse q -> p in bond_active; returns 1 if it was intact, else 0."""
    if bond_active[b] == 0:
        return 0
    bond_active[b] = 0
    q = bond_nbr[b]
    for r in range(bond_start[q], bond_start[q + 1]):
        if bond_nbr[r] == p:
            bond_active[r] = 0
    return 1


@njit(cache=True)
def candidate_edges(start, end, cand, particle_x, bond_start, bond_nbr, bond_active, particle_bmax):
    """Edges (i < j, indices into cand) of active bonds between candidates whose most deformed bonds are
    within 45 degrees of each other: the graph whose connected components are the crack clusters."""
    local = np.full(end - start, -1, np.int64)
    dirs = np.empty((cand.shape[0], 3))
    size = 0
    for i in range(cand.shape[0]):
        p = cand[i]
        local[p - start] = i
        d0, d1, d2, ln = bond_vector(particle_x, p, bond_nbr[particle_bmax[p]])
        ln = max(ln, np.finfo(np.float64).tiny)
        dirs[i, 0], dirs[i, 1], dirs[i, 2] = d0 / ln, d1 / ln, d2 / ln
        size += bond_start[p + 1] - bond_start[p]
    src = np.empty(size, np.int64)
    dst = np.empty(size, np.int64)
    count = 0
    for i in range(cand.shape[0]):
        p = cand[i]
        for b in range(bond_start[p], bond_start[p + 1]):
            j = local[bond_nbr[b] - start]
            if j > i and bond_active[b] == 1 and abs(dirs[i, 0] * dirs[j, 0] + dirs[i, 1] * dirs[j, 1]
                                                     + dirs[i, 2] * dirs[j, 2]) >= SPLIT_COS:
                src[count] = i
                dst[count] = j
                count += 1
    return src[:count], dst[:count]


@njit(cache=True, inline="always")
def side(x, p, c, n0, n1, n2):
    """Signed distance of particle p from the plane through c with unit normal n."""
    return (x[p, 0] - c[0]) * n0 + (x[p, 1] - c[1]) * n1 + (x[p, 2] - c[2]) * n2


@njit(cache=True, inline="always")
def mark(u, tag, stamp, near, count):
    """Append particle u to near[:count] unless stamp already holds tag; returns the new count."""
    if stamp[u] != tag:
        stamp[u] = tag
        near[count] = u
        count += 1
    return count


@njit(cache=True, inline="always")
def sliver(particle_cut, p, sp, n0, n1, n2):
    """Whether particle p, at signed distance sp from a cut's plane with unit normal n (in the reference frame), has a
    cutout within 45 degrees of n on its far side from the plane (particle_cut[p, :3] points from p into it): cutting
    p's bonds across the plane would cut a second crack along the cutout's face, less than a horizon from it, which
    a free face's zero normal stress does not open (where the plane of a cluster at a notch's tip reaches back over
    the faces)."""
    c0, c1, c2 = particle_cut[p, 0], particle_cut[p, 1], particle_cut[p, 2]
    a = c0 * n0 + c1 * n1 + c2 * n2
    m = SPLIT_COS * math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    return m > 0.0 and abs(a) >= m and (a < 0.0) == (sp < 0.0)


@njit(cache=True)
def cut_clusters(delta, members, cluster_start, particle_x, bond_start, bond_nbr, particle_lmax, particle_bmax,
                 bond_active, rest_x, particle_cut):
    """Plane cut of each cluster (section 6) -> bond_active; returns the number of undirected bonds cut.

    Clusters run in order and see the cuts of the ones before: a cluster whose most deformed bond is
    already broken is skipped, so each crack is cut once per call and re-evaluated at the next one.
    particle_cut (n, 4): per particle the sum of X_q - X_p over the bonds a cutout took and their count (discretize;
    (0, 4) without cutouts): a bond is left when one of its ends has a cutout within 45 degrees of the plane's normal
    (in the reference frame, rest_x's) on its far side from the plane (`sliver`)."""
    sided = particle_cut.shape[0] > 0
    stamp = np.zeros(particle_x.shape[0], np.int64)
    near = np.empty(particle_x.shape[0], np.int64)
    c = np.empty(3)
    cut = 0
    for k in range(cluster_start.shape[0] - 1):
        mem = members[cluster_start[k]:cluster_start[k + 1]]
        top = mem[0]
        for p in mem:
            if particle_lmax[p] > particle_lmax[top]:
                top = p
        b0 = particle_bmax[top]
        if bond_active[b0] == 0:
            continue
        n0, n1, n2, ln = bond_vector(particle_x, top, bond_nbr[b0])
        if ln == 0.0:  # its ends coincide (both pushed onto one collider point): no direction to cut along yet
            continue
        n0, n1, n2 = n0 / ln, n1 / ln, n2 / ln
        r0, r1, r2, rl = bond_vector(rest_x, top, bond_nbr[b0])
        r0, r1, r2 = r0 / rl, r1 / rl, r2 / rl
        c[:] = 0.0
        for p in mem:
            c += particle_x[p]
        c /= mem.shape[0]
        reach = 0.0
        for p in mem:
            reach = max(reach, (particle_x[p, 0] - c[0]) ** 2 + (particle_x[p, 1] - c[1]) ** 2
                        + (particle_x[p, 2] - c[2]) ** 2)
        reach = (math.sqrt(reach) + delta) ** 2
        cut += cut_pair(b0, top, bond_start, bond_nbr, bond_active)
        # The cluster and its families: every bond with an endpoint there is owned by one of them.
        count = 0
        for p in mem:
            count = mark(p, k + 1, stamp, near, count)
            for b in range(bond_start[p], bond_start[p + 1]):
                count = mark(bond_nbr[b], k + 1, stamp, near, count)
        for m in range(count):
            p = near[m]
            sp = side(particle_x, p, c, n0, n1, n2)
            for b in range(bond_start[p], bond_start[p + 1]):
                if bond_active[b] == 0:
                    continue
                q = bond_nbr[b]
                sq = side(particle_x, q, c, n0, n1, n2)
                if (sp < 0.0) == (sq < 0.0):
                    continue
                if sided and (sliver(particle_cut, p, sp, r0, r1, r2) or sliver(particle_cut, q, sq, r0, r1, r2)):
                    continue
                t = sp / (sp - sq)
                d = 0.0
                for a in range(3):
                    d += (particle_x[p, a] + t * (particle_x[q, a] - particle_x[p, a]) - c[a]) ** 2
                if d <= reach:
                    cut += cut_pair(b, p, bond_start, bond_nbr, bond_active)
    return cut


def fracture_update(threshold, delta, start, end, particle_x, rest_x, bond_start, bond_nbr, bond_active,
                    particle_lmax, particle_bmax, particle_cut=None) -> int:
    """Cluster the candidates of one body (particles start..end-1) and cut each cluster's fracture plane.

    Reads particle_lmax / particle_bmax from bond_criterion; updates bond_active in place (section 6).
    Returns the number of undirected bonds cut."""
    cand = start + np.flatnonzero((particle_lmax[start:end] > threshold) & (particle_bmax[start:end] >= 0))
    if len(cand) == 0:
        return 0
    src, dst = candidate_edges(start, end, cand, particle_x, bond_start, bond_nbr, bond_active, particle_bmax)
    graph = coo_matrix((np.ones(len(src)), (src, dst)), shape=(len(cand), len(cand)))
    n_clusters, labels = connected_components(graph, directed=False)
    order = np.argsort(labels, kind="stable")
    cluster_start = np.zeros(n_clusters + 1, dtype=np.int64)
    np.cumsum(np.bincount(labels, minlength=n_clusters), out=cluster_start[1:])
    return cut_clusters(delta, cand[order], cluster_start, particle_x, bond_start, bond_nbr, particle_lmax,
                        particle_bmax, bond_active, rest_x,
                        np.zeros((0, 4)) if particle_cut is None else particle_cut)


def pieces(bond_start, bond_nbr, intact, start: int, end: int) -> np.ndarray:
    """Piece label of each particle start..end-1: the connected components over the bonds `intact` marks (one
    bool per bond; bonds leaving the range are ignored). How fragments are counted (tests, bench/wall_pieces.py)."""
    owner = np.repeat(np.arange(len(bond_start) - 1), np.diff(bond_start))
    sel = intact & (owner >= start) & (owner < end) & (bond_nbr >= start) & (bond_nbr < end)
    n = end - start
    graph = coo_matrix((np.ones(sel.sum()), (owner[sel] - start, bond_nbr[sel] - start)), shape=(n, n))
    return connected_components(graph, directed=False)[1]


@njit(cache=True)
def damage_at(p, bond_start, bond_active, particle_damage, particle_crack):
    """Damage = broken / initial bonds -> particle_damage[p]; 1 if any bond is broken -> particle_crack[p]."""
    broken = broken_bonds(p, bond_start, bond_active)
    initial = bond_start[p + 1] - bond_start[p]
    particle_damage[p] = broken / initial if initial > 0 else 0.0
    particle_crack[p] = 1 if broken > 0 else 0


@njit(parallel=True, cache=True)
def damage(bond_start, bond_active, particle_damage, particle_crack):
    """`damage_at` for every particle."""
    for p in prange(bond_start.shape[0] - 1):
        damage_at(p, bond_start, bond_active, particle_damage, particle_crack)


@njit(cache=True)
def crack_contact_at(p, grid, dt, gravity, origin, inv_dx, particle_damage, particle_mass, particle_volume,
                     particle_force, particle_x, particle_v, wx, wy, wz, gx, gy, gz):
    """Crack-surface particle p: v += dt (f / m + g) by its own bond force, then an inelastic normal contact with the
    material on the grid (intact particles, other bodies) -> particle_v[p] and the grid velocities.

    With damage >= CONTACT_DAMAGE, inside the grid's material (interpolated mass m_g over half a cell of its own
    density) and approaching it along n = -grad m_g, it loses its normal velocity relative to the grid's, v_g, as
    in a perfectly inelastic collision of m_p with m_g; the grid takes the opposite impulse J, node velocities
    changing by -w_i J / m_g. Momentum is conserved exactly and the kinetic energy cannot grow (docs/method.md,
    'Fracture'). Each contact reads the grid the previous ones changed: run in particle order (`crack_contact`)."""
    mp = particle_mass[p]
    for a in range(3):
        particle_v[p, a] += dt * (particle_force[p, a] / mp + gravity[a])
    if particle_damage[p] < CONTACT_DAMAGE:
        return
    fx, fy, fz, bx, by, bz = stencil_with_gradients(particle_x, p, origin, inv_dx, wx, wy, wz, gx, gy, gz)
    if not stencil_on_grid(fx, fy, fz, grid):
        return
    mg = 0.0
    g0 = g1 = g2 = 0.0
    m0 = m1 = m2 = 0.0
    for i in range(4):
        for j in range(4):
            for k in range(4):
                m = grid[bx + i, by + j, bz + k, 0]
                if m <= 0.0:
                    continue
                w = wx[i] * wy[j] * wz[k]
                mg += w * m
                g0 += gx[i] * wy[j] * wz[k] * m
                g1 += wx[i] * gy[j] * wz[k] * m
                g2 += wx[i] * wy[j] * gz[k] * m
                m0 += w * m * grid[bx + i, by + j, bz + k, 1]
                m1 += w * m * grid[bx + i, by + j, bz + k, 2]
                m2 += w * m * grid[bx + i, by + j, bz + k, 3]
    g = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    dx3 = 1.0 / (inv_dx * inv_dx * inv_dx)
    if mg < 0.5 * mp / particle_volume[p] * dx3 or g == 0.0:
        return
    rel = 0.0
    rel -= (particle_v[p, 0] - m0 / mg) * g0 / g
    rel -= (particle_v[p, 1] - m1 / mg) * g1 / g
    rel -= (particle_v[p, 2] - m2 / mg) * g2 / g
    if rel >= 0.0:
        return
    impulse = -rel * mp * mg / (mp + mg)  # > 0, along n = -grad / |grad|
    particle_v[p, 0] -= impulse / mp * g0 / g
    particle_v[p, 1] -= impulse / mp * g1 / g
    particle_v[p, 2] -= impulse / mp * g2 / g
    for i in range(4):
        for j in range(4):
            for k in range(4):
                if grid[bx + i, by + j, bz + k, 0] <= 0.0:
                    continue
                w = wx[i] * wy[j] * wz[k]
                grid[bx + i, by + j, bz + k, 1] += w * impulse / mg * g0 / g
                grid[bx + i, by + j, bz + k, 2] += w * impulse / mg * g1 / g
                grid[bx + i, by + j, bz + k, 3] += w * impulse / mg * g2 / g


@njit(cache=True)
def crack_contact(grid, dt, gravity, origin, inv_dx, crack_index, particle_damage, particle_mass, particle_volume,
                  particle_force, particle_x, particle_v):
    """`crack_contact_at` for the crack particles in crack_index, serially in that order: each contact writes grid
    nodes that the next may read."""
    wx, wy, wz = np.empty(4), np.empty(4), np.empty(4)
    gx, gy, gz = np.empty(4), np.empty(4), np.empty(4)
    for i in range(crack_index.shape[0]):
        crack_contact_at(crack_index[i], grid, dt, gravity, origin, inv_dx, particle_damage, particle_mass,
                         particle_volume, particle_force, particle_x, particle_v, wx, wy, wz, gx, gy, gz)


@njit(cache=True)
def crack_update_at(p, dt, t_new, colliders, lo, hi, particle_x, particle_v, particle_C, v, nrm):
    """Grid-free symplectic Euler of crack-surface particle p (end of section 6), after the contact set its velocity
    -> particle_x, _v, _C. Collider response, x += dt v, then push-out and the box [lo, hi] (a separating wall).
    C = 0: the particle takes no affine motion from a grid. Returns its speed, or -1 if it is not finite."""
    for a in range(3):
        v[a] = particle_v[p, a]
    if colliders.shape[0]:
        collide_all(colliders, particle_x[p, 0], particle_x[p, 1], particle_x[p, 2], t_new, v, nrm)
    for a in range(3):
        particle_x[p, a] += dt * v[a]
    if colliders.shape[0]:
        push_out(colliders, particle_x[p], t_new, nrm)
    for a in range(3):
        if particle_x[p, a] < lo[a]:
            particle_x[p, a] = lo[a]
            v[a] = v[a] if v[a] > 0.0 else 0.0
        elif particle_x[p, a] > hi[a]:
            particle_x[p, a] = hi[a]
            v[a] = v[a] if v[a] < 0.0 else 0.0
        particle_v[p, a] = v[a]
        for c in range(3):
            particle_C[p, a, c] = 0.0
    return particle_speed(v[0], v[1], v[2], particle_x, p)


@njit(parallel=True, cache=True)
def crack_particle_update(dt, t_new, colliders, lo, hi, crack_index, particle_x, particle_v, particle_C):
    """`crack_update_at` for the crack particles in crack_index. Returns (max speed, non-finite count), like g2p."""
    n = crack_index.shape[0]
    speed = np.zeros(n)
    for i in prange(n):
        v = np.empty(3)
        nrm = np.empty(3)
        speed[i] = crack_update_at(crack_index[i], dt, t_new, colliders, lo, hi, particle_x, particle_v, particle_C,
                                   v, nrm)
    bad = 0
    vmax = 0.0
    for i in range(n):
        if speed[i] < 0.0:
            bad += 1
        else:
            vmax = max(vmax, speed[i])
    return vmax, bad
