"""Meshes carried by the material points: shell surfaces and Voronoi cell polyhedra (paper section 7).

Each mesh vertex v is tied to particles i with weights w_vi (EmbeddedMesh) and placed at
    x_v = sum_i w_vi (x_i + F_i (X_v - X_i)),
exact for any affine motion of the particles. F_i is the particle's local deformation over its INTACT bonds,
    F_i = (A_i + eps tr(K_i) I)(K_i + eps tr(K_i) I)^-1,  A_i = sum_q w V_q eta (x) xi,  K_i = sum_q w V_q xi (x) xi,
so a fragment carries its cells along rigidly, directions a family does not span (a cloth's normal, a particle
with one bond left) map to themselves, and a particle with no bond left just translates its cell. The singular
values of F are clamped to [1/2, 2]: a family that barely spans a direction (a torn cell's few nearly coplanar
bonds) would otherwise amplify a small misalignment into a vertex thrown metres away.
"""

import numpy as np
from numba import njit, prange

from pdmpm_cli.engine.bonds import bond_vector, influence

REGULARISATION = 1e-6  # eps: a relative stiffness of 1e-6 pulls missing directions to the identity
STRETCH_LIMIT = 2.0  # singular values of F stay within [1 / STRETCH_LIMIT, STRETCH_LIMIT]


@njit(parallel=True, cache=True)
def local_deformation(particle_x, rest_x, particle_volume, bond_start, bond_nbr, bond_active, particle_body,
                      body_horizon, particle_F):
    """F_i over intact bonds (module docstring) for every particle -> particle_F."""
    has_active = bond_active.shape[0] > 0
    for p in prange(rest_x.shape[0]):
        delta = body_horizon[particle_body[p]]
        a = np.zeros((3, 3))
        k = np.zeros((3, 3))
        for b in range(bond_start[p], bond_start[p + 1]):
            if has_active and bond_active[b] == 0:
                continue
            q = bond_nbr[b]
            x0, x1, x2, r = bond_vector(rest_x, p, q)
            e0, e1, e2, _ = bond_vector(particle_x, p, q)
            wv = max(influence(r, delta), 0.0) * particle_volume[q]
            xi = (x0, x1, x2)
            eta = (e0, e1, e2)
            for i in range(3):
                for c in range(3):
                    a[i, c] += wv * eta[i] * xi[c]
                    k[i, c] += wv * xi[i] * xi[c]
        reg = REGULARISATION * (k[0, 0] + k[1, 1] + k[2, 2])
        if reg <= 0.0:
            particle_F[p] = np.eye(3)
            continue
        for i in range(3):
            a[i, i] += reg
            k[i, i] += reg
        u, sv, vt = np.linalg.svd(a @ np.linalg.inv(k))
        for i in range(3):
            sv[i] = min(max(sv[i], 1.0 / STRETCH_LIMIT), STRETCH_LIMIT)
        particle_F[p] = u @ np.diag(sv) @ vt


@njit(parallel=True, cache=True)
def embedded_positions(vertices, particles, weights, particle_x, rest_x, particle_F, out):
    """x_v = sum_i w_vi (x_i + F_i (X_v - X_i)) for every vertex -> out."""
    for v in prange(vertices.shape[0]):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for j in range(particles.shape[1]):
            i = particles[v, j]
            w = weights[v, j]
            d0 = vertices[v, 0] - rest_x[i, 0]
            d1 = vertices[v, 1] - rest_x[i, 1]
            d2 = vertices[v, 2] - rest_x[i, 2]
            f = particle_F[i]
            s0 += w * (particle_x[i, 0] + f[0, 0] * d0 + f[0, 1] * d1 + f[0, 2] * d2)
            s1 += w * (particle_x[i, 1] + f[1, 0] * d0 + f[1, 1] * d1 + f[1, 2] * d2)
            s2 += w * (particle_x[i, 2] + f[2, 0] * d0 + f[2, 1] * d1 + f[2, 2] * d2)
        out[v, 0] = s0
        out[v, 1] = s1
        out[v, 2] = s2


def mesh_positions(model, state, meshes) -> list[np.ndarray]:
    """Current vertex positions of each embedded mesh (one local-deformation pass shared by all)."""
    if not meshes:
        return []
    F = np.empty((model.n_particles, 3, 3))
    local_deformation(state.particle_x, model.rest_x, model.particle_volume, state.bond_start, state.bond_nbr,
                      state.bond_active, model.particle_body, model.body_horizon, F)
    out = []
    for m in meshes:
        x = np.empty_like(m.vertices)
        embedded_positions(m.vertices, m.particles, m.weights, state.particle_x, model.rest_x, F, x)
        out.append(x)
    return out
