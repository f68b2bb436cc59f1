"""Kinematic level-set colliders (plane, box, sphere, cylinder, closed mesh) and the Stomakhin et al. 2013 response.

Each collider is a header row of a float64 table (packed by pdmpm_cli.assemble), so a kernel loops over them without
objects and every kernel takes the one table:
  0 kind | 1-3 point/centre | 4-6 normal, box half-size or cylinder axis | 7 radius | 8 half height |
  9 sign (+1, or -1 inside-out) | 10-12 velocity | 13 boundary (0 sticky, 1 slip, 2 separate, 3 clamped: planes) |
  14 friction |
  15 rows the collider spans (1, or 1 + its data rows) | 16-18 mesh: distance samples per axis |
  19-21 mesh: first sample's position at time 0 [m] | 22 mesh: sample spacing [m] |
  23 penalty response: the depth [m] below which the projection backs it up (0: the projection from the surface) |
  24 penalty response: its stiffness k [-] (0: the projection alone)
A mesh collider's signed distances follow its header row by row, x slowest, ROW values to a row. The collider moves
with constant velocity: its centre (or its samples) at time t is the position at 0 + velocity t.
"""

import math

import numpy as np
from numba import njit, prange

from pdmpm_cli.engine.kernel import Kernel
from pdmpm_cli.engine.parallel import SCRATCH_CHUNKS

PLANE, BOX, SPHERE, CYLINDER, MESH = 0, 1, 2, 3, 4
STICKY, SLIP, SEPARATE, CLAMPED = 0, 1, 2, 3
BOUNDARY_CODES = {"sticky": STICKY, "slip": SLIP, "separate": SEPARATE, "clamped": CLAMPED}
ROW = 25
PENALTY_BACKSTOP = 2.0  # penalty colliders: nodes and particles deeper than this project as before [cells]


def header_rows(table):
    """Indices of the colliders' header rows (the rows a kernel reads first) in a packed table."""
    out, c = [], 0
    while c < len(table):
        out.append(c)
        c += int(table[c, 15])
    return out


def mesh_samples(table, c):
    """Mesh collider c's signed distance samples as an (nx, ny, nz) array [m]."""
    shape = tuple(int(v) for v in table[c, 16:19])
    return table[c + 1:c + int(table[c, 15])].ravel()[:int(np.prod(shape))].reshape(shape)


@njit(cache=True)
def sample_at(table, first, ny, nz, i, j, k):
    """Signed distance sample (i, j, k) of a mesh collider whose samples start at table row `first`."""
    flat = (i * ny + j) * nz + k
    return table[first + flat // ROW, flat % ROW]


@njit(cache=True)
def mesh_distance(table, c, p0, p1, p2, n):
    """Signed distance [m] at p (relative to the first sample) from the trilinear interpolant of mesh collider c's
    samples, and its gradient, normalised, in n. Outside the sampled box: the distance at the nearest point of the
    box plus the distance to the box (the box reaches a few samples past the mesh, so that stays positive)."""
    row = table[c]
    nx, ny, nz, h = int(row[16]), int(row[17]), int(row[18]), row[22]
    q0, q1, q2 = p0 / h, p1 / h, p2 / h
    c0 = min(max(q0, 0.0), nx - 1.0)
    c1 = min(max(q1, 0.0), ny - 1.0)
    c2 = min(max(q2, 0.0), nz - 1.0)
    outside = h * math.sqrt((q0 - c0) ** 2 + (q1 - c1) ** 2 + (q2 - c2) ** 2)
    i = min(int(math.floor(c0)), nx - 2)
    j = min(int(math.floor(c1)), ny - 2)
    k = min(int(math.floor(c2)), nz - 2)
    f0, f1, f2 = c0 - i, c1 - j, c2 - k
    first = c + 1
    phi = 0.0
    g0, g1, g2 = 0.0, 0.0, 0.0
    for a in range(2):
        w0 = f0 if a else 1.0 - f0
        d0 = 1.0 if a else -1.0
        for b in range(2):
            w1 = f1 if b else 1.0 - f1
            d1 = 1.0 if b else -1.0
            for e in range(2):
                w2 = f2 if e else 1.0 - f2
                d2 = 1.0 if e else -1.0
                v = sample_at(table, first, ny, nz, i + a, j + b, k + e)
                phi += w0 * w1 * w2 * v
                g0 += d0 * w1 * w2 * v
                g1 += w0 * d1 * w2 * v
                g2 += w0 * w1 * d2 * v
    if outside > 0.0:  # along a clamped axis the gradient [1] is the distance to the box's
        g0 = (q0 - c0) * h / outside if q0 != c0 else g0 / h
        g1 = (q1 - c1) * h / outside if q1 != c1 else g1 / h
        g2 = (q2 - c2) * h / outside if q2 != c2 else g2 / h
    g = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    if g > 0.0:
        n[0], n[1], n[2] = g0 / g, g1 / g, g2 / g
    else:
        n[0], n[1], n[2] = 0.0, 1.0, 0.0
    return phi + outside


@njit(cache=True)
def signed_distance(table, c, x0, x1, x2, t, n):
    """Signed distance of point x to collider c (the header row `table[c]`) at time t (negative inside); writes
    the unit normal to n."""
    row = table[c]
    p0 = x0 - (row[1] + row[10] * t)
    p1 = x1 - (row[2] + row[11] * t)
    p2 = x2 - (row[3] + row[12] * t)
    kind = int(row[0])
    if kind == PLANE:
        n[0], n[1], n[2] = row[4], row[5], row[6]
        phi = p0 * n[0] + p1 * n[1] + p2 * n[2]
    elif kind == SPHERE:
        r = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        if r > 0.0:
            n[0], n[1], n[2] = p0 / r, p1 / r, p2 / r
        else:
            n[0], n[1], n[2] = 0.0, 1.0, 0.0
        phi = r - row[7]
    elif kind == MESH:
        phi = mesh_distance(table, c, x0 - (row[19] + row[10] * t), x1 - (row[20] + row[11] * t),
                            x2 - (row[21] + row[12] * t), n)
    elif kind == BOX:
        q0 = abs(p0) - row[4]
        q1 = abs(p1) - row[5]
        q2 = abs(p2) - row[6]
        o0, o1, o2 = max(q0, 0.0), max(q1, 0.0), max(q2, 0.0)
        out = math.sqrt(o0 * o0 + o1 * o1 + o2 * o2)
        if out > 0.0:
            n[0] = math.copysign(o0 / out, p0)
            n[1] = math.copysign(o1 / out, p1)
            n[2] = math.copysign(o2 / out, p2)
            phi = out
        else:
            n[0], n[1], n[2] = 0.0, 0.0, 0.0
            if q0 >= q1 and q0 >= q2:
                n[0], phi = math.copysign(1.0, p0), q0
            elif q1 >= q2:
                n[1], phi = math.copysign(1.0, p1), q1
            else:
                n[2], phi = math.copysign(1.0, p2), q2
    else:
        a0, a1, a2 = row[4], row[5], row[6]
        y = p0 * a0 + p1 * a1 + p2 * a2
        r0, r1, r2 = p0 - y * a0, p1 - y * a1, p2 - y * a2
        r = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        if r > 0.0:
            r0, r1, r2 = r0 / r, r1 / r, r2 / r
        else:
            r0, r1, r2 = 0.0, 0.0, 0.0
        dr = r - row[7]
        dy = abs(y) - row[8]
        sy = math.copysign(1.0, y)
        if dr > 0.0 and dy > 0.0:
            d = math.sqrt(dr * dr + dy * dy)
            n[0] = (dr * r0 + dy * sy * a0) / d
            n[1] = (dr * r1 + dy * sy * a1) / d
            n[2] = (dr * r2 + dy * sy * a2) / d
            phi = d
        elif dr > dy:
            n[0], n[1], n[2] = r0, r1, r2
            phi = dr
        else:
            n[0], n[1], n[2] = sy * a0, sy * a1, sy * a2
            phi = dy
    s = row[9]
    n[0] *= s
    n[1] *= s
    n[2] *= s
    return phi * s


@njit(cache=True)
def respond(v, vc0, vc1, vc2, n, boundary, friction):
    """Project velocity v (in place) against a surface with normal n moving at vc (Stomakhin 2013, sec. 8)."""
    r0, r1, r2 = v[0] - vc0, v[1] - vc1, v[2] - vc2
    if boundary == STICKY or boundary == CLAMPED:  # a clamped plane's nodes are mirrored after (mirror_clamped)
        r0, r1, r2 = 0.0, 0.0, 0.0
    else:
        vn = r0 * n[0] + r1 * n[1] + r2 * n[2]
        if boundary == SEPARATE and vn >= 0.0:
            return
        t0, t1, t2 = r0 - vn * n[0], r1 - vn * n[1], r2 - vn * n[2]
        tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        drop = friction * abs(vn)
        if tn <= drop:
            r0, r1, r2 = 0.0, 0.0, 0.0
        elif drop > 0.0:
            s = 1.0 - drop / tn
            r0, r1, r2 = t0 * s, t1 * s, t2 * s
        else:
            r0, r1, r2 = t0, t1, t2
    v[0], v[1], v[2] = r0 + vc0, r1 + vc1, r2 + vc2


@njit(cache=True, inline="always")
def collide_all(table, x0, x1, x2, t, v, n):
    """Apply every collider whose level set is <= 0 at x (a penalty collider's: below its backstop depth) to the
    velocity v (in place)."""
    c = 0
    while c < table.shape[0]:
        row = table[c]
        if signed_distance(table, c, x0, x1, x2, t, n) <= -row[23]:
            respond(v, row[10], row[11], row[12], n, int(row[13]), row[14])
        c += int(row[15])


@njit(cache=True, inline="always")
def push_out(table, x, t, n):
    """Move point x (in place) out of any collider it penetrates, to the surface along the normal (a penalty
    collider's: to its backstop depth)."""
    c = 0
    while c < table.shape[0]:
        phi = signed_distance(table, c, x[0], x[1], x[2], t, n) + table[c, 23]
        if phi < 0.0:
            x[0] -= phi * n[0]
            x[1] -= phi * n[1]
            x[2] -= phi * n[2]
        c += int(table[c, 15])


# signed_distance compiled into the penalty pass (penalty_at is inlined too), which calls it once per particle and
# collider: as calls, with their array arguments, the pass cost 70 ns per particle on a plane
inlined_signed_distance = njit(cache=True, inline="always")(signed_distance.py_func)


@njit(cache=True, inline="always")
def penalty_at(p, table, t, dt, wave, skin, pin_mask, particle_x, particle_v, particle_mass, particle_force, n):
    """Particle p against every penalty collider (table[c, 24] > 0): where its centre lies closer than `skin` (half
    its spacing: its material touches) to the surface, an elastic force m_p k c^2 / dx^2 (skin - phi) along the
    normal (k the collider's stiffness, `wave` = c^2 / dx^2 [1/s^2]), whether it approaches or leaves, so the work
    comes back; Coulomb friction up to mu times it against the slip relative to the collider, at most what stops
    the slip in dt -> particle_force. Pinned particles move as prescribed. Branches, not the builtin min, which
    numba's CUDA target cannot compile."""
    if pin_mask.shape[0] > 0 and pin_mask[p] != 0:
        return
    c = 0
    while c < table.shape[0]:
        row = table[c]
        if row[24] > 0.0:
            phi = inlined_signed_distance(table, c, particle_x[p, 0], particle_x[p, 1], particle_x[p, 2], t, n)
            if phi < skin:
                m = particle_mass[p]
                push = m * row[24] * wave * (skin - phi)
                r0, r1, r2 = particle_v[p, 0] - row[10], particle_v[p, 1] - row[11], particle_v[p, 2] - row[12]
                vn = r0 * n[0] + r1 * n[1] + r2 * n[2]
                t0, t1, t2 = r0 - vn * n[0], r1 - vn * n[1], r2 - vn * n[2]
                slip = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
                drag = 0.0
                if slip > 0.0:
                    drag = row[14] * push
                    if drag > m * slip / dt:
                        drag = m * slip / dt
                    drag /= slip
                particle_force[p, 0] += push * n[0] - drag * t0
                particle_force[p, 1] += push * n[1] - drag * t1
                particle_force[p, 2] += push * n[2] - drag * t2
        c += int(row[15])


@njit(parallel=True, cache=True)
def penalties(start, end, table, t, dt, wave, skin, pin_mask, particle_x, particle_v, particle_mass, particle_force):
    """`penalty_at` for the particles start..end-1 (one body's), in SCRATCH_CHUNKS chunks with one normal scratch
    each (an allocation per particle cost more than the push)."""
    size = end - start
    for c in prange(SCRATCH_CHUNKS):
        n = np.empty(3)
        for p in range(start + c * size // SCRATCH_CHUNKS, start + (c + 1) * size // SCRATCH_CHUNKS):
            penalty_at(p, table, t, dt, wave, skin, pin_mask, particle_x, particle_v, particle_mass, particle_force,
                       n)


PENALTY = Kernel(penalty_at, penalties, scratch=(("n", 3),))
