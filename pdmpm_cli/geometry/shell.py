"""Shell geometry (paper section 7): material points on a surface and in layers under it.

Sampling (:func:`shell_particles`)
    Layer 0 is a blue-noise set on the surface: uniform area-weighted candidates (about
    ``CANDIDATES_PER_POINT`` per wanted point) are accepted in random order when no accepted
    point lies closer than a radius ``r`` (dart throwing on a hash grid, Numba). The accepted
    count falls like 1 / r^2, so ``r`` is re-tuned from the count (same candidates every pass)
    until it is within ``COUNT_TOLERANCE`` of area / h^2; ``r`` never drops below
    ``MIN_SEPARATION * h``.

    Layer k is the same samples at depth k h: each sample keeps its triangle and barycentric
    coordinates on the surface offset by moving every vertex v by ``-k h d_v``. Where the
    face normals at a vertex differ (a crease or corner), ``d_v`` moves every adjacent face
    plane inwards by one unit (least squares, angle-weighted; e.g. (1, 1, 1) at a box
    corner); its remaining, tangential freedom is the smoothest field over the surface
    (harmonic, cotangent weights). On smooth parts d_v is about the vertex normal; on a box
    face it is (1, 2y/b, 2z/c): each layer is the face uniformly shrunk to the offset box, at
    depth exactly k h, rather than folding near the edges (which interpolating the mitre
    only across the triangles at the crease does once k h exceeds the triangle size). A
    sample's ``normal`` is the barycentric mean of the angle-weighted vertex normals,
    normalised. Each point of layer k stands for ``A_k h / n0``, A_k the area of the offset
    surface (triangle areas projected on the original normals): a layer-0 point stands for
    the slab [-h/2, h/2] around the surface, so the total approximates the shell between the
    surface offset by h/2 outwards and by (layers - 1/2) h inwards (exact for a box, up to
    the midpoint rule), and a flat sheet gets exactly area * layers * h. An open surface gets
    its layers on the side opposite its normals.

    Checks (InputError): layers >= 1; at least 4 points; at most ``MAX_POINTS``.

    Where the body is thinner than its layers (measured per sample by two ray casts: along
    the inward normal the layers from opposite sides must stay ``MIN_INNER_GAP h`` apart,
    and the sample's offset path must not leave the body or pass where its triangle's offset
    turns over), the sample keeps only the layers that fit. Its deepest point then stands
    for the material down to the middle of the body and sits at the centre of that slab.
    Volumes are then taken per triangle: a point stands for its slab under its sample's
    share of the surface (the area nearer to it than to other samples) times the integral of
    the triangle's offset area ratio (a quadratic in the depth) over the slab, so the total
    stays the volume under the surface (a plate thinner than its layers gets its own volume,
    not the layers'). Bodies thick enough everywhere keep the per-layer volumes above.
    ``ShellSample.notes`` says where layers were cut.

    Option ``first_depth`` (default 0, as above) moves every layer deeper by first_depth h;
    with 0.5 layer k sits at (k + 1/2) h and the layers' slabs fill [0, layers h] inside the
    surface (A_k is then taken at the slab centre, so the total approximates the shell's own
    volume instead of one reaching h/2 outside).

The surfaces of built-in shapes come from :mod:`pdmpm_cli.geometry.primitive_surfaces`; the vertices of
the surface are tied to the particles by :mod:`pdmpm_cli.geometry.embed`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from pdmpm_cli.errors import InputError
from pdmpm_cli.geometry.bvh import inside_mesh, ray_hits
from pdmpm_cli.geometry.mesh import SurfaceMesh, _fmt_point
from pdmpm_cli.geometry.shapes import _positive

__all__ = ["ShellSample", "shell_particles", "thin_crowded"]

#: refuse shells with more material points than this
MAX_POINTS = 5_000_000
#: minimum distance between layer-0 points, in units of h
MIN_SEPARATION = 0.6
#: uniform candidates drawn per wanted layer-0 point (more: closer to a maximal packing)
CANDIDATES_PER_POINT = 10
#: accepted relative deviation of the layer-0 count from area / h^2 (then tuning stops)
COUNT_TOLERANCE = 0.02
#: eigen-directions of the normal tensor weaker than this fraction are treated as smooth
CREASE_RATIO = 0.15
#: cap on the length of a vertex offset direction (a 39 degree wedge); sharper edges are under-offset
MAX_OFFSET = 3.0
#: conjugate-gradient iterations for the smooth offset field (one mesh ring of reach each)
OFFSET_CG_ITERATIONS = 1000
#: the deepest layers from opposite sides of the body must stay this far apart [h]
MIN_INNER_GAP = 0.5
_CHUNK = 1 << 20



# ----------------------------------------------------------------------------------------
# vertex normals and offset directions
# ----------------------------------------------------------------------------------------
def _vertex_frames(V: np.ndarray, T: np.ndarray, offsets: bool):
    """(unit vertex normals, vertex offset directions or None, unit triangle normals).

    Normals are angle-weighted (independent of how a flat region is triangulated). Offset
    directions: see :func:`_offset_directions`.
    """
    nv = V.shape[0]
    P = V[T]  # (nt, 3, 3)
    fn = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    fl = np.linalg.norm(fn, axis=1)
    fn = fn / np.where(fl > 0.0, fl, 1.0)[:, None]
    ang = np.empty(T.shape)
    cot = np.zeros(T.shape)  # cotangent of each corner's angle
    for q in range(3):
        a = P[:, (q + 1) % 3] - P[:, q]
        b = P[:, (q + 2) % 3] - P[:, q]
        dot = np.einsum("ij,ij->i", a, b)
        ang[:, q] = np.arctan2(fl, dot)
        np.divide(dot, fl, out=cot[:, q], where=fl > 0.0)
    ang[fl == 0.0] = 0.0
    vid = T.reshape(-1)
    wn = (ang[:, :, None] * fn[:, None, :]).reshape(-1, 3)  # angle-weighted normal per corner
    b = np.stack([np.bincount(vid, wn[:, d], nv) for d in range(3)], 1)
    bl = np.linalg.norm(b, axis=1)
    n = b / np.where(bl > 0.0, bl, 1.0)[:, None]
    if not offsets:
        return n, None, fn
    outer = (ang[:, :, None, None] * (fn[:, :, None] * fn[:, None, :])[:, None]).reshape(-1, 9)
    Mt = np.stack([np.bincount(vid, outer[:, d], nv) for d in range(9)], 1).reshape(nv, 3, 3)
    return n, _offset_directions(T, Mt, b, cot), fn


def _offset_directions(T: np.ndarray, Mt: np.ndarray, b: np.ndarray, cot: np.ndarray) -> np.ndarray:
    """Per-vertex displacement per unit depth (nv, 3): the face planes move in by one unit.

    At each vertex, ``Mt = sum angle * n n^T`` and ``b = sum angle * n`` over the adjacent
    faces. Along the eigen-directions of Mt with a strong eigenvalue (the face normals there
    differ: a crease or corner, or the normal itself) d solves the least-squares system
    n_f . d = 1 (e.g. (1, 1, 1) at a box corner). The remaining (tangential) freedom is
    filled by the smoothest field: minimum of the Dirichlet energy sum over mesh edges
    w_ij |d_i - d_j|^2 (cotangent weights, conjugate gradients). On a box face this gives
    d = (1, 2y/b, 2z/c): every layer is a uniformly shrunk copy of the face, whereas
    interpolating the mitre only across the triangles at the crease would fold them once the
    depth exceeds the triangle size. On smooth surfaces it stays (close to) the vertex normal.
    """
    from scipy import sparse
    from scipy.sparse.linalg import cg

    nv = Mt.shape[0]
    lam, E = np.linalg.eigh(Mt)  # ascending eigenvalues, eigenvectors in the columns
    keep = lam >= CREASE_RATIO * np.maximum(lam[:, 2:3], 1e-300)
    coef = np.where(keep, np.einsum("vdk,vd->vk", E, b) / np.where(keep, lam, 1.0), 0.0)
    d0 = np.einsum("vdk,vk->vd", E, coef)
    vi, ki = np.nonzero(~keep)
    nz = vi.shape[0]
    d = d0
    if nz:
        Bm = sparse.csr_matrix(
            (E[vi, :, ki].ravel(), ((3 * vi[:, None] + np.arange(3)).ravel(), np.repeat(np.arange(nz), 3))),
            shape=(3 * nv, nz),
        )
        # intrinsic cotangent weights (isotropic; a linear field on an unfolded face is harmonic),
        # clipped at 0 for obtuse pairs to keep the system positive definite
        i = T[:, [1, 2, 0]].reshape(-1)
        j = T[:, [2, 0, 1]].reshape(-1)
        adj = sparse.coo_matrix((0.5 * cot.reshape(-1), (i, j)), shape=(nv, nv)).tocsr()
        adj = adj + adj.T
        adj.data = np.maximum(adj.data, 0.0)
        lap = sparse.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj
        LB = sparse.kron(lap, sparse.identity(3), format="csr") @ Bm
        K = (Bm.T @ LB).tocsr() + sparse.identity(nz) * 1e-8  # tiny: pins constant tangential fields (a flat sheet)
        rhs = -(LB.T @ d0.ravel())
        if np.any(rhs != 0.0):
            z, _ = cg(K, rhs, rtol=1e-6, maxiter=OFFSET_CG_ITERATIONS, M=sparse.diags(1.0 / K.diagonal()))
            d = d0 + (Bm @ z).reshape(nv, 3)
    dl = np.linalg.norm(d, axis=1)
    return d * np.minimum(1.0, MAX_OFFSET / np.where(dl > 0.0, dl, 1.0))[:, None]


def _offset_area(V: np.ndarray, T: np.ndarray, fn: np.ndarray) -> float:
    """Area of the surface V (same triangles), each triangle projected on its original normal fn."""
    P = V[T]
    return 0.5 * float(np.einsum("ij,ij->", np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), fn))


# ----------------------------------------------------------------------------------------
# blue-noise sampling of the surface (dart throwing on a hash grid)
# ----------------------------------------------------------------------------------------
_KEY_BITS = 21  # cell coordinates are packed into one int64 (wrapped: a clash only costs a distance test)
_KEY_MASK = (1 << _KEY_BITS) - 1


@njit(cache=True, inline="always")
def _slot(keys, key, mask):
    """Open-addressing slot of a packed cell key (splitmix64 hash, linear probing); keys < 0 are empty."""
    z = np.uint64(key) + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    s = np.int64(z & np.uint64(mask))
    while keys[s] >= 0 and keys[s] != key:
        s = (s + 1) & mask
    return s


@njit(cache=True, inline="always")
def _pack(ix, iy, iz):
    return ((ix & _KEY_MASK) << (2 * _KEY_BITS)) | ((iy & _KEY_MASK) << _KEY_BITS) | (iz & _KEY_MASK)


_NEIGHBOURS = np.array(
    sorted(((a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)), key=lambda o: sum(map(abs, o))),
    dtype=np.int64,
)


@njit(cache=True)
def _dart_chunk(V, T, tri, u, v, r, lo, keys, head, nxt, pos, acc_tri, acc_bary, count):
    """Accept each candidate with no accepted point closer than r; returns the count (-1: full)."""
    cap = pos.shape[0]
    mask = keys.shape[0] - 1
    inv = 1.0 / r
    r2 = r * r
    for c in range(tri.shape[0]):
        t = tri[c]
        b1 = u[c]
        b2 = v[c]
        if b1 + b2 > 1.0:
            b1 = 1.0 - b1
            b2 = 1.0 - b2
        b0 = 1.0 - b1 - b2
        i0, i1, i2 = T[t, 0], T[t, 1], T[t, 2]
        px = b0 * V[i0, 0] + b1 * V[i1, 0] + b2 * V[i2, 0]
        py = b0 * V[i0, 1] + b1 * V[i1, 1] + b2 * V[i2, 1]
        pz = b0 * V[i0, 2] + b1 * V[i1, 2] + b2 * V[i2, 2]
        ix = np.int64((px - lo[0]) * inv)
        iy = np.int64((py - lo[1]) * inv)
        iz = np.int64((pz - lo[2]) * inv)
        ok = True
        for o in range(27):  # own cell first: most candidates are rejected there, cheaply
            s = _slot(keys, _pack(ix + _NEIGHBOURS[o, 0], iy + _NEIGHBOURS[o, 1], iz + _NEIGHBOURS[o, 2]), mask)
            k = head[s] if keys[s] >= 0 else -1
            while k >= 0:
                ex = pos[k, 0] - px
                ey = pos[k, 1] - py
                ez = pos[k, 2] - pz
                if ex * ex + ey * ey + ez * ez < r2:
                    ok = False
                    break
                k = nxt[k]
            if not ok:
                break
        if not ok:
            continue
        if count >= cap:
            return -1
        key = _pack(ix, iy, iz)
        s = _slot(keys, key, mask)
        if keys[s] < 0:
            keys[s] = key
            head[s] = -1
        pos[count, 0] = px
        pos[count, 1] = py
        pos[count, 2] = pz
        acc_tri[count] = t
        acc_bary[count, 0] = b0
        acc_bary[count, 1] = b1
        acc_bary[count, 2] = b2
        nxt[count] = head[s]
        head[s] = count
        count += 1
    return count


def _dart_throw(V, T, cum, n_cand, r, cap, seed):
    """One dart-throwing pass with radius r over the candidates of `seed`; None if over `cap`."""
    rng = np.random.default_rng(seed)
    size = 1 << max(4, int(math.ceil(math.log2(2 * cap + 1))))
    keys = np.full(size, -1, np.int64)
    head = np.empty(size, np.int32)
    nxt = np.empty(cap, np.int32)
    pos = np.empty((cap, 3))
    acc_tri = np.empty(cap, np.int64)
    acc_bary = np.empty((cap, 3))
    lo = V.min(axis=0) - 2.0 * r
    total = cum[-1]
    count = 0
    for start in range(0, n_cand, _CHUNK):
        k = min(_CHUNK, n_cand - start)
        tri = np.minimum(np.searchsorted(cum, rng.random(k) * total, side="right"), T.shape[0] - 1)
        u = rng.random(k)
        v = rng.random(k)
        count = _dart_chunk(V, T, tri, u, v, r, lo, keys, head, nxt, pos, acc_tri, acc_bary, count)
        if count < 0:
            return None
    return pos[:count], acc_tri[:count], acc_bary[:count]


def _blue_noise(V, T, area, n_target, h, rng):
    """Layer-0 samples (points, triangle, barycentric) with about n_target points, spacing >= 0.6 h."""
    cum = np.cumsum(area)
    n_cand = int(CANDIDATES_PER_POINT * n_target) + 64
    cap = int(1.5 * n_target) + 16
    seed = int(rng.integers(0, 2**63 - 1))
    r_min = MIN_SEPARATION * h
    r = 0.748 * h  # gives about area / h^2 points at this many candidates (measured on a plane and a sphere)
    best = None
    for _ in range(10):
        res = _dart_throw(V, T, cum, n_cand, r, cap, seed)
        n = cap + 1 if res is None else res[0].shape[0]
        if res is not None and (best is None or abs(n - n_target) < abs(best[0].shape[0] - n_target)):
            best = res
        if abs(n - n_target) <= COUNT_TOLERANCE * n_target or (r <= r_min and n < n_target):
            break
        r = max(r_min, r * math.sqrt(max(n, 1) / n_target))
    if best is None:  # pragma: no cover - the first passes always fit
        best = _dart_throw(V, T, cum, n_cand, 2.0 * h, 10 * cap, seed)
    pts, tri, bary = best
    order = np.argsort(tri, kind="stable")  # memory locality: triangles are usually spatially coherent
    return pts[order], tri[order], bary[order]


# ----------------------------------------------------------------------------------------
# local thickness: first hit along the inward normal (rays against the mesh's BVH)
# ----------------------------------------------------------------------------------------
def _available_depth(mesh, pts0, tri, dirs, fn, depths, h) -> tuple[np.ndarray, np.ndarray]:
    """How deep each sample's layers may go: (deepest layer centre, depth of material on this side) [m].

    Two ray casts per sample against the mesh. Along the inward normal of its triangle the body is t thick: a
    layer centred at depth d fits if 2 d + MIN_INNER_GAP h <= t (the deepest layers from opposite sides stay h/2 apart), and this
    side's material reaches t / 2. Along the sample's offset path the surface must lie beyond the layer: that is
    the inside test of the inner points (the path starts into the body, since it moves every adjacent face plane
    inwards, and does not cross the surface), except for the few samples whose path starts otherwise (degenerate
    spots), which get the winding-number test of each layer point instead.
    """
    tmin = 1e-6 * h
    half = 0.5 * ray_hits(mesh, pts0, -fn[tri], tmin)
    centre = half - 0.5 * MIN_INNER_GAP * h
    dl = np.linalg.norm(dirs, axis=1)
    unit = dirs / np.where(dl > 0.0, dl, 1.0)[:, None]
    exit_depth = ray_hits(mesh, pts0, -unit, tmin) / np.where(dl > 0.0, dl, np.inf)
    if mesh.closed:
        odd = np.flatnonzero(np.einsum("ij,ij->i", unit, fn[tri]) <= 0.0)
        inner = depths[depths > 0.0]
        exit_depth[odd] = np.inf
        if odd.size and inner.size:
            pts = np.concatenate([pts0[odd] - d * dirs[odd] for d in inner])
            inside = inside_mesh(mesh, pts).reshape(inner.shape[0], -1)
            first_out = np.argmin(np.vstack([inside, np.zeros((1, odd.size), bool)]), axis=0)
            exit_depth[odd] = np.where(first_out < inner.shape[0], inner[np.minimum(first_out, inner.size - 1)],
                                       np.inf)
    exit_depth *= 1.0 - 1e-9
    return np.minimum(centre, exit_depth), np.minimum(half, exit_depth)


def _area_polynomials(V: np.ndarray, T: np.ndarray, vd: np.ndarray, fn: np.ndarray) -> np.ndarray:
    """(nt, 3) coefficients c of each triangle's area at depth s, c0 + c1 s + c2 s^2: the triangle with its
    vertices moved by -s d_v, projected on its original normal (as _offset_area sums them)."""
    P, D = V[T], vd[T]
    e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    g1, g2 = D[:, 1] - D[:, 0], D[:, 2] - D[:, 0]
    dot = lambda u, w: 0.5 * np.einsum("ij,ij->i", np.cross(u, w), fn)  # noqa: E731
    return np.stack([dot(e1, e2), -(dot(e1, g2) + dot(g1, e2)), dot(g1, g2)], axis=1)


def _first_root(c: np.ndarray) -> np.ndarray:
    """Smallest positive s where c0 + c1 s + c2 s^2 falls to (nearly) zero: the offset triangle turns over, or
    shrinks to a point and grows again turned by half a turn (a square face shrinking evenly: a double root, which
    the 1e-6 margin splits); inf if none."""
    c0, c1, c2 = c[:, 0] * (1.0 - 1e-6), c[:, 1], c[:, 2]
    out = np.full(c.shape[0], np.inf)
    lin = np.abs(c2) <= 1e-12 * np.maximum(np.abs(c1), 1e-300) * np.maximum(np.abs(c0 / np.where(c1 != 0, c1, 1)), 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = -c0 / c1
        out[lin & (r > 0)] = r[lin & (r > 0)]
        disc = c1 * c1 - 4.0 * c2 * c0
        sq = np.sqrt(np.maximum(disc, 0.0))
        for root in ((-c1 - sq) / (2.0 * c2), (-c1 + sq) / (2.0 * c2)):
            ok = ~lin & (disc >= 0.0) & (root > 0.0)
            out[ok] = np.minimum(out[ok], root[ok])
    return out


def _slab_area(c: np.ndarray, s0: np.ndarray, s1: np.ndarray) -> np.ndarray:
    """Integral of c0 + c1 s + c2 s^2 over [s0, s1] (the volume under a triangle between two depths)."""
    return c[:, 0] * (s1 - s0) + c[:, 1] * (s1**2 - s0**2) / 2.0 + c[:, 2] * (s1**3 - s0**3) / 3.0


# ----------------------------------------------------------------------------------------
# shell sampling
# ----------------------------------------------------------------------------------------
@dataclass
class ShellSample:
    """Material points of a shell body, layer by layer (layer 0 first; where the body is thin a sample has fewer
    layers than asked for, so deeper layers hold fewer points)."""

    points: np.ndarray  # (n, 3) material points [m]
    volumes: np.ndarray  # (n,) volume of each point [m^3]
    layer: np.ndarray  # (n,) int32, 0 = on the surface, k = depth k*h (plus first_depth * h if given)
    normals: np.ndarray  # (n, 3) outward unit normal of the surface at the point's surface location
    thin: np.ndarray = None  # (n,) bool: the deepest point of a sample whose layers were cut short (body too thin)
    notes: list[str] = field(default_factory=list)  # where the shell differs from what was asked (fewer layers)

    def __post_init__(self):
        if self.thin is None:
            self.thin = np.zeros(len(self.points), dtype=bool)


def shell_particles(mesh: SurfaceMesh, h: float, layers: int, rng: np.random.Generator,
                    what: str = "shell body", *, first_depth: float = 0.0) -> ShellSample:
    """Blue-noise points on `mesh` (about one per h^2) repeated in `layers` layers h apart inwards.

    See the module doc for the construction, the volumes and the checks; an open mesh
    (``mesh.closed`` False) puts its layers on the side opposite its normals.
    ``first_depth`` (in units of h) shifts every layer deeper: layer k lies at depth
    (k + first_depth) h. 0 (default) puts layer 0 on the surface; 0.5 centres the layers'
    slabs in [0, layers h], so that they fill the body's shell exactly (no half slab outside).
    """
    h = _positive(h, f"{what}: particle spacing h")
    if isinstance(layers, bool) or not isinstance(layers, (int, np.integer)) or layers < 1:
        raise InputError(f"{what}: layers must be a whole number >= 1 (1 = a cloth on the surface), got {layers!r}")
    layers = int(layers)
    try:
        first_depth = float(first_depth)
    except (TypeError, ValueError):
        first_depth = float("nan")
    if not (math.isfinite(first_depth) and first_depth >= 0.0):
        raise InputError(f"{what}: the depth of the first layer must be >= 0 (in units of h), got {first_depth!r}")
    depths = (np.arange(layers) + first_depth) * h
    V, T = mesh.vertices, mesh.triangles
    if T.shape[0] == 0:
        raise InputError(f"{what}: the surface has no triangles")
    P = V[T]
    area = 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
    A = float(area.sum())
    n_target = A / (h * h)
    if n_target * layers > MAX_POINTS:
        raise InputError(
            f"{what}: spacing h = {h:g} m on a surface of {A:.4g} m^2 with {layers} layers needs about "
            f"{n_target * layers:,.0f} material points (limit {MAX_POINTS:,}); use a larger spacing, at least "
            f"h = {math.sqrt(A * layers / MAX_POINTS):.3g} m, or fewer layers"
        )
    too_small = (
        f"{what}: the surface ({A:.3g} m^2) is too small for the spacing h = {h:g} m: it would get fewer than 4 "
        f"points per layer; use a spacing of at most {math.sqrt(A / 4.0):.3g} m or a larger surface"
    )
    if n_target < 4.0:
        raise InputError(too_small)
    pts0, tri, bary = _blue_noise(V, T, area, n_target, h, rng)
    n0 = pts0.shape[0]
    if n0 < 4:
        raise InputError(too_small)

    deep = depths[-1] > 0.0
    vn, vd, fn = _vertex_frames(V, T, offsets=deep)
    nrm = np.einsum("ik,ikd->id", bary, vn[T[tri]])
    nl = np.linalg.norm(nrm, axis=1)
    nrm /= np.where(nl > 0.0, nl, 1.0)[:, None]
    if not deep:
        return ShellSample(pts0, np.full(n0, A * h / n0), np.zeros(n0, np.int32), nrm)
    dirs = np.einsum("ik,ikd->id", bary, vd[T[tri]])  # displacement per unit depth of each sample
    coef = _area_polynomials(V, T, vd, fn)
    limit, material = _available_depth(mesh, pts0, tri, dirs, fn, depths, h)
    turn = _first_root(coef)[tri] - 0.01 * h  # where the sample's offset triangle turns over: no point there
    limit, material = np.minimum(limit, turn), np.minimum(material, turn)
    kept = np.maximum(1, (depths[None, :] <= limit[:, None]).sum(axis=1))  # layers are consecutive from 0
    if np.all(kept == layers):
        areas = np.array([_offset_area(V - d * vd, T, fn) if d > 0.0 else A for d in depths])
        sample = ShellSample(np.concatenate([pts0 - d * dirs for d in depths]), np.repeat(areas * h / n0, n0),
                             np.repeat(np.arange(layers, dtype=np.int32), n0), np.tile(nrm, (layers, 1)))
    else:
        share = _surface_shares(V, T, area, fn, pts0, tri, h, rng)
        sample = _cut_layers(pts0, dirs, nrm, coef[tri], kept, material, depths, h, share)
        cut = kept < layers
        at = pts0[np.flatnonzero(cut)[np.argmin(kept[cut])]]
        sample.notes.append(
            f"the body is thinner than its {layers} layers x 2 sides x h = {2 * layers * h:.3g} m in places (e.g. "
            f"near {_fmt_point(at)}): {int(cut.sum())} of {n0} surface points have fewer layers there (down to "
            f"{int(kept.min())}), their deepest point filling the body to its middle")
    if sample.points.shape[0] > MAX_POINTS:
        raise InputError(
            f"{what}: {sample.points.shape[0]:,} material points (limit {MAX_POINTS:,}); use a larger spacing than "
            f"h = {h:g} m or fewer layers"
        )
    return sample


def _surface_shares(V, T, area, fn, pts0, tri, h, rng, per_point: int = 16) -> np.ndarray:
    """The surface area each sample stands for: uniform points on the surface (per_point per sample) go to their
    nearest sample, in position and face normal (h n), so that across a crease a point goes to the samples of its
    own face. Dart throwing leaves narrow strips (a plate's rim) with fewer samples than their area's share, so
    A / n0 per sample would overweight the faces next to them."""
    cum = np.cumsum(area)
    m = per_point * pts0.shape[0]
    t = np.minimum(np.searchsorted(cum, rng.random(m) * cum[-1], side="right"), T.shape[0] - 1)
    u, v = rng.random(m), rng.random(m)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    P = V[T[t, 0]] + u[:, None] * (V[T[t, 1]] - V[T[t, 0]]) + v[:, None] * (V[T[t, 2]] - V[T[t, 0]])
    nearest = cKDTree(np.hstack([pts0, h * fn[tri]])).query(np.hstack([P, h * fn[t]]))[1]
    return cum[-1] * np.bincount(nearest, minlength=pts0.shape[0]) / m


def _cut_layers(pts0, dirs, nrm, coef, kept, material, depths, h, share) -> ShellSample:
    """Layers of samples that keep only kept[i] of them: every point stands for its slab of the offset surface,
    its sample's surface share times the integral of its triangle's area ratio over the slab (which keeps the total
    the volume under the surface, per triangle); the deepest point of a cut sample takes the slab down to the middle of the
    body (`material`) and sits at its centre."""
    half = 0.5 * h
    pts, vols, lay, nrms, thin = [], [], [], [], []
    a0 = np.where(coef[:, 0] > 0.0, coef[:, 0], 1.0)
    for k, d in enumerate(depths):
        i = np.flatnonzero(kept > k)
        if i.size == 0:
            break
        s0 = np.full(i.size, d - half)
        s1 = np.full(i.size, d + half)
        last = (kept[i] == k + 1) & (kept[i] < depths.size)
        s1[last] = np.maximum(material[i[last]], s0[last] + 1e-6 * h)
        centre = np.where(last, 0.5 * (s0 + s1), d)
        pts.append(pts0[i] - centre[:, None] * dirs[i])
        vols.append(share[i] * np.maximum(_slab_area(coef[i], s0, s1), 0.0) / a0[i])
        lay.append(np.full(i.size, k, np.int32))
        nrms.append(nrm[i])
        thin.append(last)
    return ShellSample(np.concatenate(pts), np.concatenate(vols), np.concatenate(lay), np.concatenate(nrms),
                       np.concatenate(thin))


#: inner-layer points closer than this to a point already kept are merged into it [h]
THIN_SEPARATION = 0.5


def thin_crowded(sample: ShellSample, h: float, min_sep: float = THIN_SEPARATION) -> ShellSample:
    """Merge inner-layer points that crowd: where layers shrink (a box's faces meet inside a thin body) a
    point closer than min_sep h to one already kept, layer by layer from the surface, is dropped and its
    volume given to the nearest kept point. Crowded pairs would otherwise set a tiny bond time step and
    add hundreds of bonds per point; the total volume is unchanged."""
    r = min_sep * h
    keep = (sample.layer == 0) & ~sample.thin  # points moved to the middle of a thin part may crowd too
    for k in range(0, int(sample.layer.max(initial=0)) + 1):
        idx = np.flatnonzero((sample.layer == k) & ~keep)
        if idx.size == 0:
            continue
        if np.any(keep):
            near = cKDTree(sample.points[keep]).query(sample.points[idx], distance_upper_bound=r)[0]
            idx = idx[~np.isfinite(near)]
        ok = np.ones(len(idx), dtype=bool)
        for i, j in cKDTree(sample.points[idx]).query_pairs(r, output_type="ndarray"):
            if ok[i] and ok[j]:
                ok[j] = False
        keep[idx[ok]] = True
    if keep.all():
        return sample
    volumes = sample.volumes[keep].copy()
    dropped = np.flatnonzero(~keep)
    into = cKDTree(sample.points[keep]).query(sample.points[dropped])[1]
    np.add.at(volumes, into, sample.volumes[dropped])
    return ShellSample(sample.points[keep], volumes, sample.layer[keep], sample.normals[keep], sample.thin[keep],
                       sample.notes)
