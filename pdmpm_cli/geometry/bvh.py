"""Triangle bounding-volume hierarchy: the inside test (generalized winding number) and ray hits.

Inside test (:func:`inside_mesh`, :func:`winding_number`)
    The generalized winding number w(q) = sum of the triangles' signed solid angles / 4 pi
    (Van Oosterom-Strackee formula); w > 0.5 means inside. The Numba kernel evaluates it
    exactly (no far-field approximation) but hierarchically (Jacobson et al. 2013, section
    3.3): triangles are grouped in a bounding-volume hierarchy and, for a query point
    outside the box of a group, the group's contribution equals that of a fan of triangles
    spanning the group's boundary loop (patch + reversed fan is a closed surface inside the
    box, whose winding number vanishes outside it). Boundary loops have O(sqrt(m)) edges for
    m triangles, so a query costs O(sqrt(nt)) solid angles instead of nt (1e5 points against
    1e4 triangles: ~0.6 s on 2 cores instead of ~20 s). The half solid angles are summed as
    a product of complex numbers with a branch-cut counter, one atan2 per point. Points near
    (but not on) the surface get their exact winding number (agrees with the brute-force sum,
    kept as ``_winding_number_bruteforce``, to ~1e-13); exactly on the surface w = 0.5.

Ray hits (:func:`ray_hits`)
    The distance along each ray to the first triangle beyond a minimum distance
    (Moeller-Trumbore against the same hierarchy's boxes); the shell sampler measures the
    body's local thickness with it.

The hierarchy is built once per :class:`~pdmpm_cli.geometry.mesh.SurfaceMesh` and cached on it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from pdmpm_cli.geometry.mesh import SurfaceMesh

__all__ = ["hierarchy", "winding_number", "inside_mesh", "ray_hits"]

#: triangles per BVH leaf of the winding-number hierarchy
BVH_LEAF_SIZE = 8


@njit(cache=True)
def _num_den(ax, ay, az, la, bx, by, bz, lb, cx, cy, cz, lc):
    """Van Oosterom-Strackee: tan(omega / 2) = num / den for corner vectors a, b, c (lengths l)."""
    num = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
    den = (
        la * lb * lc
        + (ax * bx + ay * by + az * bz) * lc
        + (bx * cx + by * cy + bz * cz) * la
        + (cx * ax + cy * ay + cz * az) * lb
    )
    return num, den


@njit(cache=True)
def _half_solid_angle(qx, qy, qz, V, i0, i1, i2):
    """Half the signed solid angle of triangle (i0, i1, i2) seen from q (reference, with atan2)."""
    num, den = _triangle_num_den(qx, qy, qz, V, i0, i1, i2)
    return math.atan2(num, den)


@njit(cache=True, inline="always")
def _triangle_num_den(qx, qy, qz, V, i0, i1, i2):
    """Numerator and denominator of tan(Omega/2) for triangle (i0, i1, i2) seen from q."""
    ax = V[i0, 0] - qx
    ay = V[i0, 1] - qy
    az = V[i0, 2] - qz
    bx = V[i1, 0] - qx
    by = V[i1, 1] - qy
    bz = V[i1, 2] - qz
    cx = V[i2, 0] - qx
    cy = V[i2, 1] - qy
    cz = V[i2, 2] - qz
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    return _num_den(ax, ay, az, la, bx, by, bz, lb, cx, cy, cz, lc)


@njit(cache=True)
def _accumulate(zr, zi, wraps, num, den):
    """Add the angle arg(den + i num) to the running angle  arg(z) + 2 pi wraps.

    Angles are summed by multiplying unit-ish complex numbers (no atan2 per triangle);
    ``wraps`` counts the crossings of the branch cut so that the total is recovered
    exactly at the end by :func:`_total_angle`. Convention: arg is in (-pi, pi], points of
    the negative real axis (imaginary part +-0) have arg +pi.
    """
    s = max(abs(num), abs(den))
    if s == 0.0:  # atan2(0, 0) = 0: the point is a corner of the triangle
        return zr, zi, wraps
    qr = den / s
    qi = num / s
    nr = zr * qr - zi * qi
    ni = zr * qi + zi * qr
    if zi >= 0.0 and qi >= 0.0:  # both angles in [0, pi]: the sum is in [0, 2 pi]
        if ni < 0.0 or (ni == 0.0 and nr > 0.0 and zr < 0.0):
            wraps += 1
    elif zi < 0.0 and qi < 0.0:  # both in (-pi, 0): the sum is in (-2 pi, 0)
        if ni >= 0.0:
            wraps -= 1
    if abs(nr) > 1e200 or abs(ni) > 1e200:  # |q| is in [1, sqrt 2]: rescale now and then
        nr *= 1e-200
        ni *= 1e-200
    return nr, ni, wraps


@njit(cache=True)
def _total_angle(zr, zi, wraps):
    ang = math.pi if (zi == 0.0 and zr < 0.0) else math.atan2(zi, zr)
    return ang + 2.0 * math.pi * wraps


@njit(parallel=True, cache=True)
def _winding_number_bruteforce(points, V, T):
    """Reference: w(q) = sum over all triangles of solid angle / 4 pi (O(n nt), atan2 each)."""
    n = points.shape[0]
    out = np.empty(n)
    for i in prange(n):
        qx, qy, qz = points[i, 0], points[i, 1], points[i, 2]
        s = 0.0
        for t in range(T.shape[0]):
            s += _half_solid_angle(qx, qy, qz, V, T[t, 0], T[t, 1], T[t, 2])
        out[i] = s / (2.0 * math.pi)
    return out


@njit(cache=True)
def _argsort(keys):
    """Stable argsort (bottom-up merge sort), hand-written because it compiles much faster."""
    n = keys.shape[0]
    idx = np.arange(n)
    tmp = np.empty(n, np.int64)
    width = 1
    while width < n:
        lo = 0
        while lo < n:
            mid = min(lo + width, n)
            hi = min(lo + 2 * width, n)
            i = lo
            j = mid
            k = lo
            while i < mid and j < hi:
                if keys[idx[j]] < keys[idx[i]]:
                    tmp[k] = idx[j]
                    j += 1
                else:
                    tmp[k] = idx[i]
                    i += 1
                k += 1
            while i < mid:
                tmp[k] = idx[i]
                i += 1
                k += 1
            while j < hi:
                tmp[k] = idx[j]
                j += 1
                k += 1
            lo = hi
        idx, tmp = tmp, idx
        width *= 2
    return idx


@njit(cache=True)
def _reduce_chain(E, nv):
    """Net 1-chain of directed edges E (m, 2), ordered into walks.

    (u, v) cancels (v, u), multiplicities are kept. The result is ordered so that consecutive
    edges mostly share a vertex (end of one = start of the next), which the kernel exploits.
    """
    m = E.shape[0]
    keys = np.empty(m, np.int64)
    sgn = np.empty(m, np.int64)
    for k in range(m):
        u, v = E[k, 0], E[k, 1]
        if u < v:
            keys[k] = u * nv + v
            sgn[k] = 1
        else:
            keys[k] = v * nv + u
            sgn[k] = -1
    order = _argsort(keys)
    net_edges = np.empty((m, 2), np.int64)
    n = 0
    k = 0
    while k < m:
        key = keys[order[k]]
        net = 0
        j = k
        while j < m and keys[order[j]] == key:
            net += sgn[order[j]]
            j += 1
        a = key // nv
        b = key - a * nv
        for _ in range(abs(net)):
            if net > 0:
                net_edges[n, 0] = a
                net_edges[n, 1] = b
            else:
                net_edges[n, 0] = b
                net_edges[n, 1] = a
            n += 1
        k = j
    # order into walks: follow end vertex -> an unused edge starting there
    starts = np.empty(n, np.int64)
    for k in range(n):
        starts[k] = net_edges[k, 0]
    by_start = _argsort(starts)
    sorted_starts = starts[by_start]
    used = np.zeros(n, np.bool_)
    out = np.empty((n, 2), np.int64)
    r = 0
    for s0 in range(n):
        cur = by_start[s0]
        if used[cur]:
            continue
        while True:
            used[cur] = True
            out[r, 0] = net_edges[cur, 0]
            out[r, 1] = net_edges[cur, 1]
            r += 1
            v = net_edges[cur, 1]
            j0 = 0  # first index with sorted_starts[j] >= v (binary search)
            j1 = n
            while j0 < j1:
                jm = (j0 + j1) // 2
                if sorted_starts[jm] < v:
                    j0 = jm + 1
                else:
                    j1 = jm
            j = j0
            while j < n and sorted_starts[j] == v and used[by_start[j]]:
                j += 1
            if j < n and sorted_starts[j] == v:
                cur = by_start[j]
            else:
                break
    return out


@njit(cache=True)
def _build_hierarchy(V, T, leaf_size):
    """Median-split BVH over triangles + boundary chain (directed edges) of every node.

    Returns (T_sorted, node_lo, node_hi, start, end, left, bptr, bedges, n_nodes) (node
    arrays over-allocated: only the first n_nodes entries are meaningful): node k covers
    T_sorted[start[k]:end[k]]; left[k] = -1 for leaves, else its children are left[k] and
    left[k] + 1; its boundary edges are bedges[bptr[k]:bptr[k + 1]].
    """
    nt = T.shape[0]
    nv = V.shape[0]
    tlo = np.empty((nt, 3))
    thi = np.empty((nt, 3))
    cen = np.empty((nt, 3))
    for t in range(nt):
        for d in range(3):
            a = V[T[t, 0], d]
            b = V[T[t, 1], d]
            c = V[T[t, 2], d]
            tlo[t, d] = min(a, min(b, c))
            thi[t, d] = max(a, max(b, c))
            cen[t, d] = (a + b + c) / 3.0
    max_nodes = 2 * nt + 1
    node_lo = np.empty((max_nodes, 3))
    node_hi = np.empty((max_nodes, 3))
    start = np.empty(max_nodes, np.int64)
    end = np.empty(max_nodes, np.int64)
    left = np.full(max_nodes, -1, np.int64)
    order = np.arange(nt)
    stack = np.empty(max_nodes, np.int64)
    clo = np.empty(3)
    chi = np.empty(3)
    start[0] = 0
    end[0] = nt
    n_nodes = 1
    sp = 1
    stack[0] = 0
    while sp > 0:
        sp -= 1
        k = stack[sp]
        s = start[k]
        e = end[k]
        for d in range(3):
            node_lo[k, d] = np.inf
            node_hi[k, d] = -np.inf
            clo[d] = np.inf
            chi[d] = -np.inf
        for j in range(s, e):
            t = order[j]
            for d in range(3):
                node_lo[k, d] = min(node_lo[k, d], tlo[t, d])
                node_hi[k, d] = max(node_hi[k, d], thi[t, d])
                clo[d] = min(clo[d], cen[t, d])
                chi[d] = max(chi[d], cen[t, d])
        if e - s <= leaf_size:
            continue
        axis = 0
        for d in range(1, 3):
            if chi[d] - clo[d] > chi[axis] - clo[axis]:
                axis = d
        seg = np.empty(e - s, np.int64)
        keys = np.empty(e - s)
        for j in range(e - s):
            seg[j] = order[s + j]
            keys[j] = cen[seg[j], axis]
        perm = _argsort(keys)
        for j in range(e - s):
            order[s + j] = seg[perm[j]]
        mid = (s + e) // 2
        left[k] = n_nodes
        start[n_nodes] = s
        end[n_nodes] = mid
        start[n_nodes + 1] = mid
        end[n_nodes + 1] = e
        stack[sp] = n_nodes
        stack[sp + 1] = n_nodes + 1
        sp += 2
        n_nodes += 2

    Ts = np.empty((nt, 3), np.int64)
    for j in range(nt):
        for d in range(3):
            Ts[j, d] = T[order[j], d]

    # boundary chains bottom-up (children have larger indices than their parent), kept in a
    # growable flat buffer: node k's chain is buf[cstart[k]:cstart[k] + clen[k]]
    buf = np.empty((6 * nt + 16, 2), np.int64)
    used = 0
    cstart = np.zeros(n_nodes, np.int64)
    clen = np.zeros(n_nodes, np.int64)
    for k in range(n_nodes - 1, -1, -1):
        if left[k] < 0:
            m = end[k] - start[k]
            E = np.empty((3 * m, 2), np.int64)
            for j in range(m):
                t = start[k] + j
                for q in range(3):
                    E[3 * j + q, 0] = Ts[t, q]
                    E[3 * j + q, 1] = Ts[t, (q + 1) % 3]
        else:
            a = left[k]
            b = a + 1
            na = clen[a]
            E = np.empty((na + clen[b], 2), np.int64)
            for j in range(na):
                E[j, 0] = buf[cstart[a] + j, 0]
                E[j, 1] = buf[cstart[a] + j, 1]
            for j in range(clen[b]):
                E[na + j, 0] = buf[cstart[b] + j, 0]
                E[na + j, 1] = buf[cstart[b] + j, 1]
        C = _reduce_chain(E, nv)
        if used + C.shape[0] > buf.shape[0]:
            bigger = np.empty((2 * buf.shape[0] + C.shape[0], 2), np.int64)
            for j in range(used):
                bigger[j, 0] = buf[j, 0]
                bigger[j, 1] = buf[j, 1]
            buf = bigger
        for j in range(C.shape[0]):
            buf[used + j, 0] = C[j, 0]
            buf[used + j, 1] = C[j, 1]
        cstart[k] = used
        clen[k] = C.shape[0]
        used += C.shape[0]
    bptr = np.zeros(n_nodes + 1, np.int64)
    for k in range(n_nodes):
        bptr[k + 1] = bptr[k] + clen[k]
    bedges = np.empty((bptr[n_nodes], 2), np.int64)
    for k in range(n_nodes):
        for j in range(clen[k]):
            bedges[bptr[k] + j, 0] = buf[cstart[k] + j, 0]
            bedges[bptr[k] + j, 1] = buf[cstart[k] + j, 1]
    return Ts, node_lo, node_hi, start, end, left, bptr, bedges, n_nodes


@njit(parallel=True, cache=True)
def _winding_number_kernel(points, V, Ts, node_lo, node_hi, start, end, left, bptr, bedges, pad):
    """Exact generalized winding number of every point, hierarchically (see module doc).

    For each point (prange), walk the BVH: a node whose (padded) box contains the point is
    opened (its children, or at a leaf its triangles); otherwise the node's triangles
    contribute the same as the fan (o, u, v) over its boundary edges u -> v (o = the first
    boundary vertex); whichever of the two is shorter is summed. The half solid angles are
    summed with :func:`_accumulate` (complex products, one atan2 per point).
    """
    n = points.shape[0]
    out = np.empty(n)
    for i in prange(n):
        qx, qy, qz = points[i, 0], points[i, 1], points[i, 2]
        stack = np.empty(128, np.int64)
        stack[0] = 0
        sp = 1
        zr = 1.0
        zi = 0.0
        wraps = 0
        while sp > 0:
            sp -= 1
            k = stack[sp]
            contains = (
                qx >= node_lo[k, 0] - pad
                and qx <= node_hi[k, 0] + pad
                and qy >= node_lo[k, 1] - pad
                and qy <= node_hi[k, 1] + pad
                and qz >= node_lo[k, 2] - pad
                and qz <= node_hi[k, 2] + pad
            )
            if contains and left[k] >= 0:
                stack[sp] = left[k]
                stack[sp + 1] = left[k] + 1
                sp += 2
                continue
            nb = bptr[k + 1] - bptr[k]
            if contains or end[k] - start[k] <= nb:
                for t in range(start[k], end[k]):
                    num, den = _triangle_num_den(qx, qy, qz, V, Ts[t, 0], Ts[t, 1], Ts[t, 2])
                    zr, zi, wraps = _accumulate(zr, zi, wraps, num, den)
            elif nb > 0:
                b0 = bptr[k]
                o = bedges[b0, 0]
                ax = V[o, 0] - qx
                ay = V[o, 1] - qy
                az = V[o, 2] - qz
                la = math.sqrt(ax * ax + ay * ay + az * az)
                prev = -1
                bx = by = bz = lb = 0.0
                for b in range(b0, bptr[k + 1]):
                    u = bedges[b, 0]
                    w = bedges[b, 1]
                    if u != prev:  # walks: usually the previous edge ended at u
                        bx = V[u, 0] - qx
                        by = V[u, 1] - qy
                        bz = V[u, 2] - qz
                        lb = math.sqrt(bx * bx + by * by + bz * bz)
                    cx = V[w, 0] - qx
                    cy = V[w, 1] - qy
                    cz = V[w, 2] - qz
                    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
                    if u != o and w != o:
                        num, den = _num_den(ax, ay, az, la, bx, by, bz, lb, cx, cy, cz, lc)
                        zr, zi, wraps = _accumulate(zr, zi, wraps, num, den)
                    prev = w
                    bx = cx
                    by = cy
                    bz = cz
                    lb = lc
        out[i] = _total_angle(zr, zi, wraps) / (2.0 * math.pi)
    return out


def hierarchy(mesh: SurfaceMesh):
    """The mesh's BVH arrays (T sorted, node boxes, ranges, children, boundary chains) and the box padding,
    built on first use and cached on the mesh."""
    fp = (id(mesh.vertices), id(mesh.triangles), mesh.vertices.shape, mesh.triangles.shape)
    if mesh._bvh is None or mesh._bvh[0] != fp:
        Ts, lo, hi, start, end, left, bptr, bedges, nn = _build_hierarchy(
            mesh.vertices, mesh.triangles, BVH_LEAF_SIZE
        )
        h = (Ts, lo[:nn].copy(), hi[:nn].copy(), start[:nn].copy(), end[:nn].copy(), left[:nn].copy(), bptr, bedges)
        diag = float(np.linalg.norm(mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)))
        mesh._bvh = (fp, h, 1e-7 * diag)
    return mesh._bvh[1], mesh._bvh[2]


def winding_number(mesh: SurfaceMesh, points) -> np.ndarray:
    """Generalized winding number (n,) of each point: 1 inside, 0 outside, 0.5 on the surface."""
    P = np.ascontiguousarray(points, dtype=np.float64)
    if P.ndim == 1 and P.shape[0] == 3:
        P = P[None, :]
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {P.shape}")
    if P.shape[0] == 0 or mesh.triangles.shape[0] == 0:
        return np.zeros(P.shape[0])
    (Ts, lo, hi, start, end, left, bptr, bedges), pad = hierarchy(mesh)
    return _winding_number_kernel(P, mesh.vertices, Ts, lo, hi, start, end, left, bptr, bedges, pad)


def inside_mesh(mesh: SurfaceMesh, points) -> np.ndarray:
    """Bool mask (n,): generalized winding number > 0.5."""
    return winding_number(mesh, points) > 0.5


@njit(parallel=True, cache=True)
def _first_hits(orig, dirs, V, Ts, node_lo, node_hi, start, end, left, pad, tmin):
    """Distance along each ray to the first triangle beyond tmin (inf if none)."""
    n = orig.shape[0]
    out = np.empty(n)
    for i in prange(n):
        ox, oy, oz = orig[i, 0], orig[i, 1], orig[i, 2]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        ix = 1.0 / dx if abs(dx) > 1e-300 else math.copysign(1e300, dx)
        iy = 1.0 / dy if abs(dy) > 1e-300 else math.copysign(1e300, dy)
        iz = 1.0 / dz if abs(dz) > 1e-300 else math.copysign(1e300, dz)
        best = np.inf
        stack = np.empty(128, np.int64)
        stack[0] = 0
        sp = 1
        while sp > 0:
            sp -= 1
            k = stack[sp]
            t0 = (node_lo[k, 0] - pad - ox) * ix
            t1 = (node_hi[k, 0] + pad - ox) * ix
            tn, tf = min(t0, t1), max(t0, t1)
            t0 = (node_lo[k, 1] - pad - oy) * iy
            t1 = (node_hi[k, 1] + pad - oy) * iy
            tn, tf = max(tn, min(t0, t1)), min(tf, max(t0, t1))
            t0 = (node_lo[k, 2] - pad - oz) * iz
            t1 = (node_hi[k, 2] + pad - oz) * iz
            tn, tf = max(tn, min(t0, t1)), min(tf, max(t0, t1))
            if tf < max(tn, 0.0) or tn > best:
                continue
            if left[k] >= 0:
                stack[sp] = left[k]
                stack[sp + 1] = left[k] + 1
                sp += 2
                continue
            for t in range(start[k], end[k]):
                a, b, c = Ts[t, 0], Ts[t, 1], Ts[t, 2]
                e1x, e1y, e1z = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
                e2x, e2y, e2z = V[c, 0] - V[a, 0], V[c, 1] - V[a, 1], V[c, 2] - V[a, 2]
                px = dy * e2z - dz * e2y
                py = dz * e2x - dx * e2z
                pz = dx * e2y - dy * e2x
                det = e1x * px + e1y * py + e1z * pz
                if det == 0.0:
                    continue
                idet = 1.0 / det
                sx, sy, sz = ox - V[a, 0], oy - V[a, 1], oz - V[a, 2]
                uu = (sx * px + sy * py + sz * pz) * idet
                if uu < -1e-12 or uu > 1.0 + 1e-12:
                    continue
                qx = sy * e1z - sz * e1y
                qy = sz * e1x - sx * e1z
                qz = sx * e1y - sy * e1x
                vv = (dx * qx + dy * qy + dz * qz) * idet
                if vv < -1e-12 or uu + vv > 1.0 + 1e-12:
                    continue
                tt = (e2x * qx + e2y * qy + e2z * qz) * idet
                if tt > tmin and tt < best:
                    best = tt
        out[i] = best
    return out


def ray_hits(mesh: SurfaceMesh, origins, directions, tmin: float) -> np.ndarray:
    """Distance along each ray (origin, unit direction) to the first triangle beyond ``tmin``; inf if none."""
    (Ts, lo, hi, start, end, left, _, _), pad = hierarchy(mesh)
    return _first_hits(np.ascontiguousarray(origins, dtype=np.float64),
                       np.ascontiguousarray(directions, dtype=np.float64),
                       mesh.vertices, Ts, lo, hi, start, end, left, pad, tmin)
