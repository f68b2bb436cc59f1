"""Predicted stability limit of the explicit step: linear stability of the engine's own operators.

Symplectic Euler, v += dt a(x), x += dt v, on a linear system a = -A u is stable for dt < 2 / omega_max with
omega_max^2 the largest eigenvalue of A. Two systems step that way here:

- the grid (eq. 7 and the transfers): nodes carry mass m_I and the force f_I = sum_p N_Ip f_p of the particles
  that move with them, u_p = sum_I N_Ip U_I, so A = M_I^-1 N K N^T with K = -df/dx the bond stiffness;
- crack particles, which integrate their own bonds off the grid (section 6): A = M_p^-1 K.

omega_max comes from Arnoldi (scipy eigs) on the mass-scaled operator M^-1/2 ... M^-1/2, K applied by finite
differences of the engine's force phases about the current state, so it holds for any material, family and
discretisation, pre-stretched or not. Since sum_I N_Ip = 1 and N_Ip >= 0, u^T M_p u <= U^T M_I U (Jensen): the grid limit is
never below the particle limit, which the Silling & Askari bond bound (the automatic step's) bounds from below.

A third limit is geometric: a particle that crosses a collider's solid in one step passes through it
(`tunnel_depth`).
"""

import dataclasses
import math

import numpy as np
from numba import njit
from scipy.sparse.linalg import ArpackNoConvergence, LinearOperator, eigs

from pdmpm_cli.engine.colliders import BOX, CYLINDER, MESH, PLANE, SPHERE, header_rows, mesh_samples
from pdmpm_cli.engine.state import State
from pdmpm_cli.engine.transfer import WALL, stencil

PROBE = 1e-7  # finite-difference displacement, in units of the smallest particle spacing [-]
TOLERANCE = 1e-4  # relative accuracy of omega_max^2 asked of Arnoldi [-]


@njit(cache=True)
def stencils(x, origin, inv_dx, shape):
    """Flat node index and cubic B-spline weight of the 64 nodes of each particle's stencil (P2G's weights)."""
    n = x.shape[0]
    node = np.empty((n, 64), dtype=np.int64)
    weight = np.empty((n, 64))
    wx, wy, wz = np.empty(4), np.empty(4), np.empty(4)
    for p in range(n):
        bx, by, bz = stencil(x, p, origin, inv_dx, wx, wy, wz)[3:]
        k = 0
        for i in range(4):
            for j in range(4):
                for m in range(4):
                    node[p, k] = ((bx + i) * shape[1] + by + j) * shape[2] + bz + m
                    weight[p, k] = wx[i] * wy[j] * wz[m]
                    k += 1
    return node, weight


@njit(cache=True)
def interpolate(node, weight, U, u):
    """u_p = sum_I N_Ip U_I (G2P of a nodal field)."""
    for p in range(node.shape[0]):
        for a in range(3):
            s = 0.0
            for k in range(64):
                s += weight[p, k] * U[node[p, k], a]
            u[p, a] = s


@njit(cache=True)
def scatter(node, weight, f, F):
    """F_I = sum_p N_Ip f_p (P2G of a particle field); serial, so no thread races."""
    F[:] = 0.0
    for p in range(node.shape[0]):
        for k in range(64):
            for a in range(3):
                F[node[p, k], a] += weight[p, k] * f[p, a]


@dataclasses.dataclass(frozen=True)
class CriticalSteps:
    """Largest stable constant steps of the linearised systems [s] (inf where a system is absent)."""

    grid: float  # 2 / omega_max of the grid operator
    particles: float  # 2 / omega_max of the particles of fracture bodies, integrated off the grid
    tunnel_depth: float  # thinnest collider solid a particle must not cross in one step [m]

    def predicted(self, vmax: float, cracks: bool) -> float:
        """The predicted limit at largest speed vmax [m/s], with crack particles holding bonds or not."""
        out = self.grid if not cracks else min(self.grid, self.particles)
        return min(out, self.tunnel_depth / vmax) if vmax > 0 else out


class _Stiffness:
    """f(x0 + eps u) - f(x0) by the engine's force phases, on a copy of the state whose per-particle and per-bond
    arrays are reset before each probe (the viscoelastic forces are incremental), stepped by a CPU Solver of its own.
    The grids and the families are shared, not copied: the force phases never touch them."""

    SHARED = ("grid", "grid_private", "bond_start", "bond_nbr")

    def __init__(self, solver, state):
        from pdmpm_cli.engine.backends.cpu import CpuBackend
        from pdmpm_cli.engine.solver import Solver

        state = solver.sync(state)
        self.reset = [name for name in state.arrays if name not in self.SHARED]
        self.base = self._copy(state)
        self.work = self._copy(state)
        self.probe = Solver(solver.model, solver.plan, CpuBackend())
        self.probe.bind(self.work)
        self.x0 = state.particle_x.copy()
        self.eps = PROBE * float(np.min(solver.model.body_spacing))
        self.f0 = self.force(self.x0)

    def _copy(self, state):
        """A copy the probes can change, in float64 whatever simulation.precision stores: K u is a difference of
        forces 1e-7 of the spacing apart."""
        return State(state.declared, {n: (a if n in self.SHARED else a.astype(np.float64) if a.dtype == np.float32
                                          else a.copy()) for n, a in state.arrays.items()}, **state.scalars)

    def force(self, x) -> np.ndarray:
        w = self.work
        for name in self.reset:
            np.copyto(getattr(w, name), getattr(self.base, name))
        w.particle_x[:] = x
        self.probe.bond_forces(0.0)
        return w.particle_force.copy()

    def apply(self, u) -> np.ndarray:
        """K u = -df/dx u [N], probed with the largest displacement eps."""
        scale = self.eps / max(float(np.abs(u).max()), 1e-300)
        return -(self.force(self.x0 + scale * u) - self.f0) / scale


def _largest(apply_scaled, n: int, seed: int = 0) -> float:
    """Largest eigenvalue magnitude of an operator of size n (Arnoldi). The Fbar term's force is not the gradient
    of an energy, so K is not symmetric (by 30 % on a small block) and Lanczos would be off by about 0.2 %."""
    if n == 0:
        return 0.0
    op = LinearOperator((n, n), matvec=apply_scaled, dtype=np.float64)
    v0 = np.random.default_rng(seed).standard_normal(n)
    try:
        values = eigs(op, k=1, which="LM", tol=TOLERANCE, v0=v0, return_eigenvectors=False)
    except ArpackNoConvergence as e:  # the best Ritz value so far
        values = e.eigenvalues
    return float(np.abs(values).max()) if len(values) else math.nan


def grid_omega2(solver, state, stiffness: _Stiffness | None = None) -> float:
    """omega_max^2 of the grid operator M_I^-1 N K N^T [1/s^2]; pinned particles hold still and scatter no force."""
    m = solver.model
    stiffness = stiffness or _Stiffness(solver, state)
    on_grid = np.ones(m.n_particles, bool) if not len(state.particle_crack) else state.particle_crack == 0
    free = on_grid & (m.pin_mask == 0) if len(m.pin_mask) else on_grid
    shape = np.asarray(m.grid_shape, dtype=np.int64)
    node, weight = stencils(state.particle_x, m.origin, 1.0 / m.dx, shape)
    n_nodes = int(np.prod(shape))
    mass = np.zeros((n_nodes, 3))
    scatter(node, weight, np.repeat((m.particle_mass * on_grid)[:, None], 3, axis=1), mass)
    used = np.unique(node[free][weight[free] > 0])
    inv_sqrt_m = 1.0 / np.sqrt(mass[used, 0])
    U = np.zeros((n_nodes, 3))
    u = np.zeros((m.n_particles, 3))
    F = np.zeros((n_nodes, 3))

    def apply_scaled(y):
        U[used] = y.reshape(-1, 3) * inv_sqrt_m[:, None]
        interpolate(node, weight, U, u)
        u[~free] = 0.0
        f = stiffness.apply(u)
        f[~free] = 0.0
        scatter(node, weight, f, F)
        return (F[used] * inv_sqrt_m[:, None]).ravel()

    return _largest(apply_scaled, 3 * len(used))


def particle_omega2(solver, state, bodies, stiffness: _Stiffness | None = None) -> float:
    """omega_max^2 of M_p^-1 K over the particles of `bodies` (the rest held) [1/s^2]."""
    m = solver.model
    stiffness = stiffness or _Stiffness(solver, state)
    sel = np.concatenate([np.arange(*m.body_ranges[b]) for b in bodies]) if bodies else np.zeros(0, np.int64)
    inv_sqrt_m = 1.0 / np.sqrt(m.particle_mass[sel])
    u = np.zeros((m.n_particles, 3))

    def apply_scaled(y):
        u[sel] = y.reshape(-1, 3) * inv_sqrt_m[:, None]
        return (stiffness.apply(u)[sel] * inv_sqrt_m[:, None]).ravel()

    return _largest(apply_scaled, 3 * len(sel))


def ridge_depth(samples: np.ndarray, spacing: float) -> float:
    """Smallest depth [m] of the inside samples that are at least as deep as their six neighbours (the medial
    ridge; samples on the surface, where edges flatten the depth, do not count): half the thinnest wall of a mesh
    solid, to within a sample."""
    depth = np.pad(-samples, 1, constant_values=-np.inf)
    core = depth[1:-1, 1:-1, 1:-1]
    ridge = core > 0.5 * spacing
    for axis in range(3):
        for shift in (-1, 1):
            ridge &= core >= np.roll(depth, shift, axis=axis)[1:-1, 1:-1, 1:-1]
    return float(core[ridge].min()) if ridge.any() else 0.5 * spacing


def tunnel_depth(model) -> float:
    """Thinnest solid of a collider within the valid domain [m]: a plane's depth behind it (to the region particles
    may occupy, >= 1 cell inside the domain), a sphere's or cylinder's diameter, a box's smallest side, a mesh's
thinnest wall (twice the depth of its shallowest ridge sample). Inside-out
    colliders are containers and have no solid to cross (inf when nothing applies)."""
    nodes = np.asarray(model.grid_shape)
    lo = model.origin + model.dx
    hi = model.origin + (nodes - WALL) * model.dx
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    depth = math.inf
    for c in header_rows(model.colliders):
        row = model.colliders[c]
        if row[9] < 0:
            continue
        kind = int(row[0])
        if kind == PLANE:
            behind = -((corners - row[1:4]) @ row[4:7])
            d = float(behind.max())
        elif kind == SPHERE:
            d = 2 * row[7]
        elif kind == BOX:
            d = 2 * float(row[4:7].min())
        elif kind == CYLINDER:
            d = 2 * min(row[7], row[8])
        elif kind == MESH:
            d = 2 * ridge_depth(mesh_samples(model.colliders, c), row[22])
        else:
            continue
        if d > 0:
            depth = min(depth, d)
    return depth


def critical_steps(solver, state) -> CriticalSteps:
    """The predicted stability limits of the scene in its current state (a copy of it is probed)."""
    stiffness = _Stiffness(solver, state)
    w2 = grid_omega2(solver, state, stiffness)
    fracture = solver.fracture_bodies
    p2 = particle_omega2(solver, state, fracture, stiffness) if fracture else 0.0
    return CriticalSteps(grid=2 / math.sqrt(w2) if w2 > 0 else math.inf,
                         particles=2 / math.sqrt(p2) if p2 > 0 else math.inf,
                         tunnel_depth=tunnel_depth(solver.model))
