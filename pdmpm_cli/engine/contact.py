"""Contact between bodies through separate grid velocity fields (multi-field MPM; not in the paper).

With one grid velocity per node, two bodies that share a node move together there: they stick on touching and
cannot slide or come apart (they weld). Here every body scatters into its own field (`grid_field[f]`, mass and
momentum, by the same `transfer.p2g_at`), is updated on its own (gravity, walls, colliders: `grid_node_update`),
and reads its particles back from its own field (`transfer.g2p_at`). Where two or more fields have mass at a node,
`contact_node_at` compares each field's velocity with the node's centre-of-mass velocity (Bardenhagen et al. 2000,
2001): a field that approaches the others along the contact normal loses its normal velocity relative to the
centre of mass (no interpenetration) and Coulomb friction acts on its tangential part (the friction of that body
pair); a field that moves away is left free, so bodies separate. The normal is the normalised difference of the
fields' outward mass gradients, n_f ~ G_f - sum_{g != f} G_g with G_f = sum_p m_p grad N_I(x_p) (Huang et al.
2011), so two fields get exactly opposite normals and the correction conserves momentum.

The cubic B-spline reaches two cells on each side, so the fields of two bodies share nodes while they are still
up to four cells apart; contact there would start early. A node applies contact only where the bodies' material
actually meets (a position check, after Nairn 2013): the centres of mass of the fields' particles seen by the node,
c_f = sum_p m_p N_I (x_p - x_I) / m_f, must lie closer than `CONTACT_GAP` cells along the normal. For two half
spaces in contact that distance is 0.93 cells at a node on their interface (and larger at nodes inside either
body); a gap g between them adds g.

The projection is an inelastic impact of the nodes' masses at every step of an approach, so colliding bodies lose
much of their kinetic energy. `contact.model: penalty` replaces it with an elastic push along the normal wherever
the mass centres are closer than on the interface of touching bodies (`PENALTY_GAP`), proportional to how much
closer, while the bodies approach and while they separate, so its work comes back (docs/method.md).

Bodies that meet too fast for either to stop them within a cell interpenetrate, and inside each other the mass
gradients give no normal: they passed through each other. Where the fields' mass centres at a node are closer than
`DEEP_GAP` the fields stick (take the centre-of-mass velocity), as on one shared field.

`grid_surface[f]` holds per node G_f (0..2, [kg/m]) and m_f (c_f - x_I) (3..5, [kg m]).

Contact can only act where two fields have mass, i.e. where the node boxes of two bodies (their particles' stencils)
overlap: the surfaces and the contact pass cover only `overlap_box` of those, not the whole P2G box, so a small
contact zone in a large scene costs little (every node outside it has at most one field's mass: no change). The CPU
narrows it after P2G to the nodes where two fields do have mass (`meeting_box`): none while bodies are apart.
"""

import math

import numpy as np
from numba import njit, prange

from pdmpm_cli.engine.transfer import node_side, stencil_off_box, stencil_on_grid, stencil_with_gradients

CONTACT_GAP = 1.25  # contact acts where the fields' mass centres at a node are closer than this along n [cells]
DEEP_GAP = 0.25  # fields whose mass centres at a node are closer than this have interpenetrated: they stick [cells]
PENALTY_GAP = 1.0  # penalty: the fields' mass centres at a node closer than this overlap [cells] (0.93 on the
# interface of two touching half spaces, so bodies set down touching start unpushed)
SURFACE = 6  # components of grid_surface: mass gradient, mass-weighted offset of the particles from the node


@njit(cache=True, inline="always")
def scatter_surface(g, i, j, k, g0, g1, g2, s0, s1, s2):
    """g[i, j, k] += (G, S): on the CPU into the thread's private grid; the CUDA backend swaps in atomic adds."""
    g[i, j, k, 0] += g0
    g[i, j, k, 1] += g1
    g[i, j, k, 2] += g2
    g[i, j, k, 3] += s0
    g[i, j, k, 4] += s1
    g[i, j, k, 5] += s2


@njit(cache=True, inline="always")
def surface_at(p, particle_x, particle_mass, particle_crack, origin, inv_dx, g, box, wx, wy, wz, gx, gy, gz, owner,
               rest_x, crack_n, piece, half_h, cbox, want):
    """Particle p's share of its field's mass gradient m_p grad N_I(x_p) [kg/m] and of the mass-weighted offset
    m_p N_I (x_p - x_I) [kg m] -> g on the nodes of its stencil within the node box `box` (the particles P2G
    scatters: crack particles and off-grid ones do not; with crack fields, at the nodes where p lies on side `want`,
    as transfer.p2g_at)."""
    if particle_crack.shape[0] > 0 and particle_crack[p] != 0:
        return
    sided = owner.shape[0] > 0 and not stencil_off_box(particle_x, p, origin, inv_dx, cbox)
    if want == 1 and not sided:
        return
    fx, fy, fz, bx, by, bz = stencil_with_gradients(particle_x, p, origin, inv_dx, wx, wy, wz, gx, gy, gz)
    if not stencil_on_grid(fx, fy, fz, g):
        return
    dx = 1.0 / inv_dx
    m = particle_mass[p]
    for i in range(max(box[0] - bx, 0), min(box[1] - bx, 4)):
        d0 = (fx - bx - i) * dx
        for j in range(max(box[2] - by, 0), min(box[3] - by, 4)):
            d1 = (fy - by - j) * dx
            for k in range(max(box[4] - bz, 0), min(box[5] - bz, 4)):
                if sided and node_side(p, owner[bx + i, by + j, bz + k], rest_x, crack_n, piece, half_h) != want:
                    continue
                d2 = (fz - bz - k) * dx
                w = m * wx[i] * wy[j] * wz[k]
                scatter_surface(g, bx + i, by + j, bz + k, m * inv_dx * gx[i] * wy[j] * wz[k],
                                m * inv_dx * wx[i] * gy[j] * wz[k], m * inv_dx * wx[i] * wy[j] * gz[k], w * d0,
                                w * d1, w * d2)


def overlap_box(boxes) -> np.ndarray:
    """Node box [i0, i1) x [j0, j1) x [k0, k1) around every overlap of two of the fields' node boxes (None: a field
    without particles); empty (i0 = i1 = 0) when no two overlap."""
    lo, hi = np.full(3, np.iinfo(np.int64).max), np.full(3, -1)
    live = [b for b in boxes if b is not None]
    for f, a in enumerate(live):
        for b in live[f + 1:]:
            o_lo, o_hi = np.maximum(a[0::2], b[0::2]), np.minimum(a[1::2], b[1::2])
            if (o_lo < o_hi).all():
                lo, hi = np.minimum(lo, o_lo), np.maximum(hi, o_hi)
    if (hi < 0).any():
        return np.zeros(6, dtype=np.int64)
    return np.array([lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]], dtype=np.int64)


@njit(cache=True)
def meeting_box(grid_field, box) -> np.ndarray:
    """Node box around the nodes of `box` where two or more fields have mass, after P2G: the only nodes where
    `contact_node_at` acts (it leaves a node with one field's mass alone), so the surfaces and the contact pass need
    no more (the CPU's; empty, i0 = i1 = 0, when there is none). One serial pass over the box's masses: a small
    box, as `overlap_box` is."""
    lo = np.full(3, np.iinfo(np.int64).max)
    hi = np.full(3, -1)
    for i in range(box[0], box[1]):
        for j in range(box[2], box[3]):
            for k in range(box[4], box[5]):
                count = 0
                for f in range(grid_field.shape[0]):
                    if grid_field[f, i, j, k, 0] > 0.0:
                        count += 1
                if count >= 2:
                    lo[0], lo[1], lo[2] = min(lo[0], i), min(lo[1], j), min(lo[2], k)
                    hi[0], hi[1], hi[2] = max(hi[0], i + 1), max(hi[1], j + 1), max(hi[2], k + 1)
    out = np.zeros(6, dtype=np.int64)
    if hi[0] >= 0:
        out[0], out[1], out[2], out[3], out[4], out[5] = lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
    return out


@njit(parallel=True, cache=True)
def surfaces(particle_x, particle_mass, particle_crack, origin, inv_dx, box, private, out, owner, rest_x, crack_n,
             piece, half_h, cbox, want):
    """`surface_at` for every particle whose stencil meets the node box (`overlap_box`) -> out on the box: thread t
    scatters a fixed particle range into private[t], then the private grids are summed in thread order (as
    transfer.p2g, so runs are reproducible); a particle scatters only onto its nodes within the box."""
    nt = private.shape[0]
    n = particle_x.shape[0]
    for t in prange(nt):
        g = private[t]
        for i in range(box[0], box[1]):
            for j in range(box[2], box[3]):
                for k in range(box[4], box[5]):
                    for q in range(SURFACE):
                        g[i, j, k, q] = 0.0
        wx, wy, wz = np.empty(4), np.empty(4), np.empty(4)
        gx, gy, gz = np.empty(4), np.empty(4), np.empty(4)
        for p in range(t * n // nt, (t + 1) * n // nt):
            if stencil_off_box(particle_x, p, origin, inv_dx, box):
                continue
            surface_at(p, particle_x, particle_mass, particle_crack, origin, inv_dx, g, box, wx, wy, wz, gx, gy, gz,
                       owner, rest_x, crack_n, piece, half_h, cbox, want)
    for i in prange(box[0], box[1]):
        for j in range(box[2], box[3]):
            for k in range(box[4], box[5]):
                for q in range(SURFACE):
                    s = 0.0
                    for t in range(nt):
                        s += private[t, i, j, k, q]
                    out[i, j, k, q] = s


@njit(cache=True, inline="always")
def contact_node_at(i, j, k, grid_field, grid_surface, friction, stiffness, dx, dt):
    """Node (i, j, k), after every field's grid update. Projection (stiffness 0 for the pair with the heaviest other
    field; -1: the two sides of a crack, engine/crack.py): each field that has mass here, approaches the others
    along its contact normal and meets them (position
    check) loses its normal velocity relative to the centre of mass, and Coulomb friction (coefficient of that
    pair) acts on the tangential part: it sticks (takes the centre-of-mass velocity) while the tangential slip is
    at most mu times the normal one. Penalty (stiffness > 0): a field whose mass centre is closer to the others'
    than PENALTY_GAP is pushed back along its normal for dt, with friction up to mu times the push. Either way,
    fields whose mass centres are within DEEP_GAP have interpenetrated and take the centre-of-mass velocity."""
    nf = grid_field.shape[0]
    count = 0
    mt = p0 = p1 = p2 = g0 = g1 = g2 = s0 = s1 = s2 = 0.0
    for f in range(nf):
        m = grid_field[f, i, j, k, 0]
        if m > 0.0:
            count += 1
            mt += m
            p0 += m * grid_field[f, i, j, k, 1]
            p1 += m * grid_field[f, i, j, k, 2]
            p2 += m * grid_field[f, i, j, k, 3]
            g0 += grid_surface[f, i, j, k, 0]
            g1 += grid_surface[f, i, j, k, 1]
            g2 += grid_surface[f, i, j, k, 2]
            s0 += grid_surface[f, i, j, k, 3]
            s1 += grid_surface[f, i, j, k, 4]
            s2 += grid_surface[f, i, j, k, 5]
    if count < 2:
        return
    c0, c1, c2 = p0 / mt, p1 / mt, p2 / mt
    for f in range(nf):
        m = grid_field[f, i, j, k, 0]
        if m <= 0.0:
            continue
        heaviest, mh = f, 0.0
        for o in range(nf):
            if o != f and grid_field[o, i, j, k, 0] > mh:
                heaviest, mh = o, grid_field[o, i, j, k, 0]
        kp = stiffness[f, heaviest] if stiffness.shape[0] > 0 else 0.0
        # normal: the outward mass gradient of whichever side has the larger one, this field's or the others'
        # (pointing into this body); at a body's edge or corner its own gradient tilts, a flat face's does not.
        # A tie goes to field 0's, so two fields always get opposite normals. The two sides of a crack (kp < 0)
        # take the difference: near a free surface both gradients point into the body, and only the difference
        # is across the crack.
        a0, a1, a2 = grid_surface[f, i, j, k, 0], grid_surface[f, i, j, k, 1], grid_surface[f, i, j, k, 2]
        o0, o1, o2 = g0 - a0, g1 - a1, g2 - a2
        aa, oo = a0 * a0 + a1 * a1 + a2 * a2, o0 * o0 + o1 * o1 + o2 * o2
        if kp < 0.0:
            n0, n1, n2 = a0 - o0, a1 - o1, a2 - o2
        elif aa > oo or (aa == oo and f == 0):
            n0, n1, n2 = a0, a1, a2
        else:
            n0, n1, n2 = -o0, -o1, -o2
        nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if nn <= 0.0:
            continue
        n0, n1, n2 = n0 / nn, n1 / nn, n2 / nn
        d0 = grid_field[f, i, j, k, 1] - c0
        d1 = grid_field[f, i, j, k, 2] - c1
        d2 = grid_field[f, i, j, k, 3] - c2
        dn = d0 * n0 + d1 * n1 + d2 * n2
        # the distance between this field's mass centre and the others' at the node: the materials meet here
        mo = mt - m
        if mo <= 0.0:
            continue  # the others' mass is below this field's rounding: nothing to meet
        e0 = (s0 - grid_surface[f, i, j, k, 3]) / mo - grid_surface[f, i, j, k, 3] / m
        e1 = (s1 - grid_surface[f, i, j, k, 4]) / mo - grid_surface[f, i, j, k, 4] / m
        e2 = (s2 - grid_surface[f, i, j, k, 5]) / mo - grid_surface[f, i, j, k, 5] / m
        ee = e0 * e0 + e1 * e1 + e2 * e2
        if kp >= 0.0 and ee < (DEEP_GAP * dx) ** 2:
            grid_field[f, i, j, k, 1], grid_field[f, i, j, k, 2], grid_field[f, i, j, k, 3] = c0, c1, c2
            continue
        mu = friction[f, heaviest]
        t0, t1, t2 = d0 - dn * n0, d1 - dn * n1, d2 - dn * n2
        tt = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        if kp > 0.0:
            # penalty: the mass centres closer than on the interface of touching half spaces -> an elastic push
            # along -n, F = kp m_red overlap / dx^2 (equal and opposite for two fields: their e and n are), whether
            # they approach or separate; friction up to mu F.
            overlap = PENALTY_GAP * dx - math.sqrt(ee)
            if overlap <= 0.0:
                continue
            push = kp * mo / mt * overlap * dt / (dx * dx)  # F dt / m [m/s]
            r = 1.0 if tt <= mu * push else mu * push / tt
            grid_field[f, i, j, k, 1] -= push * n0 + r * t0
            grid_field[f, i, j, k, 2] -= push * n1 + r * t1
            grid_field[f, i, j, k, 3] -= push * n2 + r * t2
            continue
        if dn <= 0.0:
            continue  # moving away from the others: free
        if ee > (CONTACT_GAP * dx) ** 2:
            continue
        if tt <= mu * dn:
            grid_field[f, i, j, k, 1], grid_field[f, i, j, k, 2], grid_field[f, i, j, k, 3] = c0, c1, c2
        else:
            r = mu * dn / tt
            grid_field[f, i, j, k, 1] -= dn * n0 + r * t0
            grid_field[f, i, j, k, 2] -= dn * n1 + r * t1
            grid_field[f, i, j, k, 3] -= dn * n2 + r * t2


@njit(parallel=True, cache=True)
def contact_update(grid_field, grid_surface, friction, stiffness, dx, dt, box):
    """`contact_node_at` on every node of the box (`overlap_box`; dt 0: MUSL's second pass, where a penalty pushes
    nothing)."""
    for i in prange(box[0], box[1]):
        for j in range(box[2], box[3]):
            for k in range(box[4], box[5]):
                contact_node_at(i, j, k, grid_field, grid_surface, friction, stiffness, dx, dt)
