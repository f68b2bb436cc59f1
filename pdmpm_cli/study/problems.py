"""Verification problems with analytic answers (Sulsky 1995, Timoshenko, the self-weight column, free fall),
each a scene built from a cell size.

A `Problem` turns a grid cell size dx [m] (particle spacing dx / 2, horizon 2 spacings: the defaults) into a scene
dict, and measures an array from the finished run (a number, or a signal at the frame times) that has an analytic
value. The error of a run is the RMS difference from that value (or from another run) over the problem's scale.
Moduli follow our calibration (docs/method.md): a cloud body with lam = mu = M / 3 has E = 5 M / 6 and nu = 1/4;
a laterally confined column's modulus is M = lam + 2 mu.
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import spsolve

from pdmpm_cli.engine.bspline import cubic_weights
from pdmpm_cli.study.sim import Sim

G = 9.81
RHO = 1000.0


@dataclass(frozen=True)
class Problem:
    """A built-in study problem: its scene for a cell size, the quantity it measures and its analytic value."""

    name: str
    description: str
    quantity: str  # what `summary` returns, with its unit (the CSV's value column)
    reference: np.ndarray  # the analytic value of what `measure` returns
    reference_name: str
    scale: float  # errors are RMS differences over this
    finest: float  # default finest cell size [m]
    ratio: float  # default ratio of successive cell sizes [-]
    scene: Callable[[float], dict]
    measure: Callable[[Sim], np.ndarray]  # runs the prepared Sim to the scene's duration and measures it
    summary: Callable[[np.ndarray], float] = lambda a: float(a[0])

    def error(self, measured: np.ndarray, against: np.ndarray | None = None) -> float:
        """RMS difference from the analytic value (or from another run's measurement) over the scale [-]."""
        ref = self.reference if against is None else against
        return float(np.sqrt(np.mean((np.asarray(measured) - ref) ** 2)) / self.scale)


# ---------------------------------------------------------------- vibrating bar (Sulsky 1995)

BAR_LENGTH, BAR_E, BAR_V0 = 25.0, 100.0, 0.1
BAR_PERIOD = 4 * BAR_LENGTH / BAR_E**0.5  # 10 s: omega = (pi / 2L) sqrt(E / rho)


def bar_scene(cell: float, periods: float = 2.0) -> dict:
    """Sulsky's bar as a laterally confined column: L = 25, E = 100 (lam = 0, mu = 50 gives M = E), rho = 1,
    fixed (sticky) at x = x0, slip walls on the four long sides. With nu = 0 the bar's 1-D wave equation is the
    confined column's. The column is 4 cells (8 particles) wide: thinner columns are stiffer (truncated families,
    docs/method.md) and shorten the period by 3 % at 2 cells. Every wall lies on a grid node plane, computed as
    the same product k * cell as the node's coordinate: a wall one rounding error off its node plane leaves that
    plane's nodes free, which changed the bar's error from 0.077 to 0.28 at one cell size."""
    x0, y0, y1 = 5 * cell, 5 * cell, 9 * cell
    return {
        "simulation": {"duration": BAR_PERIOD * periods, "fps": 20},
        "grid": {"cell_size": cell, "domain": {"min": [0, 0, 0], "max": [x0 + BAR_LENGTH + 6 * cell,
                                                                          14 * cell, 14 * cell]}},
        "gravity": [0, 0, 0],
        "bodies": [{"name": "bar",
                    "geometry": {"mode": "cloud", "sampling": "jittered",
                                 "shape": {"type": "box", "center": [x0 + BAR_LENGTH / 2, 7 * cell, 7 * cell],
                                           "size": [BAR_LENGTH, 4 * cell, 4 * cell]}},
                    "material": {"model": "elastic", "density": 1.0, "lam": 0.0, "mu": BAR_E / 2}}],
        "colliders": [{"type": "plane", "point": [x0, 0, 0], "normal": [1, 0, 0], "boundary": "sticky"}]
        + [{"type": "plane", "point": p, "normal": n, "boundary": "slip"} for p, n in [
            ([0, y0, 0], [0, 1, 0]), ([0, y1, 0], [0, -1, 0]),
            ([0, 0, y0], [0, 0, 1]), ([0, 0, y1], [0, 0, -1])]],
    }


def bar_start(sim: Sim):
    """Give the bar its first mode, v = v0 sin(pi x / 2L), measured from the fixed end."""
    x0 = sim.scene.colliders[0].point[0]
    sim.state.particle_v[:, 0] = BAR_V0 * np.sin(np.pi * (sim.state.particle_x[:, 0] - x0) / (2 * BAR_LENGTH))
    sim.solver.start(sim.state)


def bar_com_velocity(sim: Sim) -> np.ndarray:
    """Start the bar and run it: its centre-of-mass velocity at every frame after t = 0
    (analytic: (2 v0 / pi) cos(omega t))."""
    bar_start(sim)
    mass, out = sim.model.particle_mass.sum(), []
    for t in bar_frames(sim.scene.simulation.duration):
        sim.advance(t)
        out.append(sim.momentum()[0] / mass)
    return np.array(out)


def bar_frames(duration: float, fps: float = 20.0) -> np.ndarray:
    return np.arange(1, int(round(duration * fps)) + 1) / fps


def bar_exact(t: np.ndarray) -> np.ndarray:
    return 2 * BAR_V0 / np.pi * np.cos(2 * np.pi * t / BAR_PERIOD)


def period(t: np.ndarray, v: np.ndarray) -> float:
    """Twice the mean spacing of the zero crossings of v (linear interpolation between samples)."""
    s = np.sign(v)
    i = np.flatnonzero(s[:-1] * s[1:] < 0)
    crossings = t[i] - v[i] * (t[i + 1] - t[i]) / (v[i + 1] - v[i])
    return float(2 * np.mean(np.diff(crossings)))


BAR_TIMES = bar_frames(1.5 * BAR_PERIOD)
BAR = Problem(
    name="bar", description="vibrating bar (Sulsky 1995), confined column 4 cells wide, 1.5 periods: v_com(t)",
    quantity="period [s]", reference=bar_exact(BAR_TIMES),
    reference_name="(2 v0 / pi) cos(omega t), RMS over amplitude",
    scale=2 * BAR_V0 / np.pi, finest=1.25 / np.sqrt(2), ratio=np.sqrt(2),
    scene=lambda dx: bar_scene(dx, periods=1.5), measure=bar_com_velocity,
    summary=lambda v: period(BAR_TIMES, v))


# ---------------------------------------------------------------- cantilever under gravity


def beam_geometry(mode: str, L: float, H: float, h: float) -> dict:
    """A square beam of free length L along +x from x = 0, with a 0.1 m root in x < 0 that the pin holds."""
    box = {"type": "box", "center": [L / 2 - 0.05, 0, 0], "size": [L + 0.1, H, H]}
    if mode == "cloud":
        return {"mode": "cloud", "shape": box, "spacing": h}
    if mode == "shell":  # layers from all faces meet in the middle: the shell fills the beam
        return {"mode": "shell", "surface": box, "spacing": h, "layers": int(round(H / (2 * h)))}
    return {"mode": "voronoi", "shape": box, "spacing": h}


def beam_omega(L: float, H: float, E: float) -> float:
    """First bending frequency of the clamped beam [rad/s]: 1.8751^2 sqrt(E I / (rho A)) / L^2."""
    return 1.875**2 * np.sqrt(E * H**2 / 12 / RHO) / L**2


def euler_bernoulli(L: float, H: float, E: float) -> float:
    """Static tip deflection q L^4 / (8 E I) of a square beam under its weight [m]."""
    return RHO * G * H * H * L**4 / (8 * E * H**4 / 12)


def timoshenko(L: float, H: float, E: float, nu: float = 0.25) -> float:
    """Euler-Bernoulli plus the shear deflection q L^2 / (2 kappa G A), kappa = 5/6 (rectangle) [m]."""
    return euler_bernoulli(L, H, E) + RHO * G * L**2 / (2 * 5 / 6 * E / (2 * (1 + nu)))


def cantilever_scene(mode: str, L: float, H: float, dx: float, E: float, periods: float = 1.5) -> dict:
    """A beam clamped at x = 0 under gravity in still air: a wind of speed 0 whose drag 2 omega_1 damps the first
    mode critically (drag does not change the static state). After 1.5 periods that mode is within 0.1 % of rest,
    but the beam still creeps for tens of periods, slower at smaller dt; `rest_tip_sag` solves for the state it
    creeps towards (docs/results.md, 'Cantilever'). lam = mu = M / 3 with M = 6 E / 5 gives E_eff = E, nu = 1/4."""
    M = 6 * E / 5
    omega = beam_omega(L, H, E)
    return {
        "simulation": {"duration": periods * 2 * np.pi / omega, "fps": 400},
        "grid": {"cell_size": dx, "domain": {"min": [-0.3, -0.4, -0.3], "max": [L + 0.3, 0.3, 0.3]}},
        "gravity": [0, -G, 0],
        "wind": {"velocity": [0, 0, 0], "drag": 2 * omega},
        "bodies": [{"name": "beam", "geometry": beam_geometry(mode, L, H, dx / 2),
                    "material": {"model": "elastic", "density": RHO, "lam": M / 3, "mu": M / 3},
                    "pins": [{"region": {"type": "box", "center": [-0.1, 0, 0], "size": [0.2, 1, 1]}}]}],
    }


def tip_sag(sim: Sim, L: float) -> np.ndarray:
    """Run the cantilever to its end: mean downward displacement of the particles within 0.6 cells of the tip at
    x = L [m]."""
    x0 = sim.model.rest_x
    tip = np.flatnonzero(x0[:, 0] > L - 0.6 * sim.scene.grid.cell_size)
    sim.advance(sim.scene.simulation.duration)
    return np.array([-(sim.state.particle_x[tip, 1] - x0[tip, 1]).mean()])


# ---------------------------------------------------------------- rest state under gravity, solved directly


def bond_stiffness(sim: Sim) -> sparse.csr_matrix:
    """K = -df/dx of the bond forces at the rest configuration [N/m] (3n x 3n; row 3p + a is force component a on
    particle p), one column per probe that moves one coordinate by 1e-6 of the spacing. The force at rest is
    exactly zero (docs/method.md) and linear to 1e-6 there, so one-sided probes suffice."""
    state, solver = sim.state, sim.solver
    x0 = state.particle_x.copy()
    eps = 1e-6 * float(np.min(sim.model.body_spacing))
    rows, cols, vals = [], [], []
    for p in range(sim.model.n_particles):
        for a in range(3):
            state.particle_x[p, a] = x0[p, a] + eps
            solver.bond_forces(0.0)
            f = state.particle_force.ravel()
            nz = np.flatnonzero(f)
            rows.append(nz)
            cols.append(np.full(len(nz), 3 * p + a))
            vals.append(-f[nz] / eps)
            state.particle_x[p, a] = x0[p, a]
    solver.bond_forces(0.0)
    n3 = 3 * sim.model.n_particles
    return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n3, n3))


def grid_weights(sim: Sim) -> sparse.csr_matrix:
    """N_Ip, the cubic B-spline weight of node I at particle p's rest position (nodes x particles)."""
    m = sim.model
    f = (m.rest_x - m.origin) / m.dx
    base = np.empty(f.shape, dtype=np.int64)
    w = np.empty(f.shape + (4,))  # (n, 3 axes, 4 nodes): the engine's own weights
    for p, a in np.ndindex(f.shape):
        base[p, a] = cubic_weights(f[p, a], w[p, a])
    idx = base[:, None, :] + np.arange(4)[None, :, None]  # (n, 4 nodes, 3 axes)
    w = w.transpose(0, 2, 1)
    _, ny, nz = m.grid_shape
    node = (idx[:, :, None, None, 0] * ny + idx[:, None, :, None, 1]) * nz + idx[:, None, None, :, 2]
    wt = w[:, :, None, None, 0] * w[:, None, :, None, 1] * w[:, None, None, :, 2]
    part = np.repeat(np.arange(m.n_particles), 64)
    return sparse.csr_matrix((wt.ravel(), (node.ravel(), part)), shape=(int(np.prod(m.grid_shape)), m.n_particles))


def rest_state(sim: Sim, ridges=(1e-9, 1e-12), bonds: bool = True) -> tuple[list[np.ndarray], np.ndarray | None]:
    """Small-displacement rest displacements under gravity, pinned particles held [m]: ([MPM per ridge], bonds).

    An explicit run does not reach this state in any affordable time (docs/results.md, 'Cantilever'): it creeps
    towards it along grid modes that the particles barely resist and the transfers damp every step. So we solve
    for it. MPM: particles move with the grid, u_p = sum_I N_Ip U_I, and at rest the grid force vanishes on
    every node a free particle touches, N_f K_ff N_f^T U = m_I g (m_I counts pinned mass: P2G scatters it). That
    matrix is nearly singular (the creeping modes), so it gets a ridge r mean(diag) I; the tip converges from
    below as r falls until round-off takes over (below 1e-12). Bonds: K_ff u_f = m_f g, the peridynamic body
    without the grid (a direct factorisation of 3n unknowns: out of memory beyond about 2500 particles on 23 GB;
    bonds=False skips it)."""
    m = sim.model
    free = ~m.pin_mask if len(m.pin_mask) else np.ones(m.n_particles, bool)
    dof = np.flatnonzero(np.repeat(free, 3))
    K = bond_stiffness(sim)[dof][:, dof]
    weight = np.tile(m.gravity, m.n_particles) * np.repeat(m.particle_mass, 3)
    u_bonds = None
    if bonds:
        u_bonds = np.zeros((m.n_particles, 3))
        u_bonds.reshape(-1)[dof] = spsolve(K.tocsc(), weight[dof])
    N = grid_weights(sim)
    nodes = np.flatnonzero(np.asarray(N[:, free].sum(axis=1)).ravel() > 0)
    Nf = sparse.kron(N[nodes], sparse.identity(3), format="csr")[:, dof]
    A = (Nf @ K @ Nf.T).tocsc()
    load = np.kron(N[nodes] @ m.particle_mass, m.gravity)
    out = []
    for r in ridges:
        u = np.zeros(3 * m.n_particles)
        u[dof] = Nf.T @ spsolve(A + r * A.diagonal().mean() * sparse.identity(A.shape[0], format="csc"), load)
        out.append(u.reshape(-1, 3))
    return out, u_bonds


def rest_tip_sag(sim: Sim, L: float, ridges=(1e-9, 1e-12), bonds: bool = True) -> tuple[list[float], float | None]:
    """Tip deflection at rest (rest_state) [m]: ([MPM per ridge], bonds alone or None), the tip of tip_sag."""
    tip = np.flatnonzero(sim.model.rest_x[:, 0] > L - 0.6 * sim.scene.grid.cell_size)
    mpm, u_bonds = rest_state(sim, ridges, bonds)
    return [float(-u[tip, 1].mean()) for u in mpm], None if u_bonds is None else float(-u_bonds[tip, 1].mean())


def whole_layers(dx: float, H: float) -> float:
    """The cell size nearest dx whose spacing dx / 2 fits a whole number of times into the thickness H [m]: with a
    partial layer of jittered cells, 4.8 particles through H bend 2x further from the beam value than 5 do."""
    return 2 * H / max(2, round(2 * H / dx))


CANTILEVER_L, CANTILEVER_H, CANTILEVER_E = 0.5, 0.1, 1e7
CANTILEVER_REF = timoshenko(CANTILEVER_L, CANTILEVER_H, CANTILEVER_E)
CANTILEVER = Problem(
    name="cantilever",
    description=f"cloud cantilever L/H = {CANTILEVER_L / CANTILEVER_H:g} under gravity, settled: tip deflection",
    quantity="tip deflection [m]", reference=np.array([CANTILEVER_REF]),
    reference_name="Timoshenko q L^4/(8 E I) + q L^2/(2 kappa G A)", scale=CANTILEVER_REF, finest=0.02,
    ratio=1.25,
    scene=lambda dx: cantilever_scene("cloud", CANTILEVER_L, CANTILEVER_H, whole_layers(dx, CANTILEVER_H),
                                      CANTILEVER_E),
    measure=lambda sim: tip_sag(sim, CANTILEVER_L))


# ---------------------------------------------------------------- free fall

FALL_TIME = 0.3


def free_fall_scene(cell: float) -> dict:
    """An elastic sphere (r = 0.1 m) released at rest under gravity, nothing to hit."""
    return {
        "simulation": {"duration": FALL_TIME, "fps": 10},
        "grid": {"cell_size": cell, "domain": {"min": [-0.5, -1, -0.5], "max": [1.5, 1.5, 1.5]}},
        "gravity": [0, -G, 0],
        "bodies": [{"name": "ball", "geometry": {"mode": "cloud", "sampling": "jittered",
                                                 "shape": {"type": "sphere", "center": [0.5, 0.6, 0.5],
                                                           "radius": 0.1}},
                    "material": {"model": "elastic", "density": RHO, "lam": 1e5, "mu": 1e5}}],
    }


def fall_drop(sim: Sim) -> np.ndarray:
    """Run to the end: how far the centre of mass fell [m] (exact: g t^2 / 2)."""
    y0 = sim.com()[1]
    sim.advance(sim.scene.simulation.duration)
    return np.array([y0 - sim.com()[1]])


FREE_FALL = Problem(
    name="free_fall", description=f"elastic ball falling freely for {FALL_TIME} s: centre-of-mass drop",
    quantity="drop [m]", reference=np.array([0.5 * G * FALL_TIME**2]), reference_name="g t^2 / 2",
    scale=0.5 * G * FALL_TIME**2, finest=0.025, ratio=np.sqrt(2),
    scene=free_fall_scene, measure=fall_drop)

# ---------------------------------------------------------------- self-weight column

COLUMN_H, COLUMN_M = 1.0, 1e6  # height [m], confined modulus lam + 2 mu [Pa]
COLUMN_SETTLE = G * RHO * COLUMN_H**2 / (2 * COLUMN_M)  # top settlement: integral of rho g (H0 - Y) / M [m]


def column_scene(cell: float, periods: float = 1.5) -> dict:
    """A laterally confined column (slip walls, 4 cells wide) standing on a sticky floor under gravity, released
    from its unstressed shape. sigma_yy(Y) = -rho g (H0 - Y) exactly, so the top settles rho g H0^2 / (2 M). Still
    air at drag 2 omega_1 (omega_1 = pi c / 2 H0) damps the first mode critically. Walls and floor lie on node
    planes, computed as the nodes' coordinates are (see bar_scene)."""
    y0, x0, x1 = 5 * cell, 5 * cell, 9 * cell
    omega = np.pi / (2 * COLUMN_H) * np.sqrt(COLUMN_M / RHO)
    return {
        "simulation": {"duration": periods * 2 * np.pi / omega, "fps": 200},
        "grid": {"cell_size": cell, "domain": {"min": [0, 0, 0], "max": [14 * cell, y0 + COLUMN_H + 6 * cell,
                                                                          14 * cell]}},
        "gravity": [0, -G, 0],
        "wind": {"velocity": [0, 0, 0], "drag": 2 * omega},
        "bodies": [{"name": "column",
                    "geometry": {"mode": "cloud", "sampling": "jittered",
                                 "shape": {"type": "box", "center": [7 * cell, y0 + COLUMN_H / 2, 7 * cell],
                                           "size": [4 * cell, COLUMN_H, 4 * cell]}},
                    "material": {"model": "elastic", "density": RHO, "lam": 0.0, "mu": COLUMN_M / 2}}],
        "colliders": [{"type": "plane", "point": [0, y0, 0], "normal": [0, 1, 0], "boundary": "sticky"}]
        + [{"type": "plane", "point": p, "normal": n, "boundary": "slip"} for p, n in [
            ([x0, 0, 0], [1, 0, 0]), ([x1, 0, 0], [-1, 0, 0]),
            ([0, 0, x0], [0, 0, 1]), ([0, 0, x1], [0, 0, -1])]],
    }


def top_settlement(sim: Sim) -> np.ndarray:
    """Run the column to its end: mean downward displacement of the particles within 0.6 cells of the top [m]."""
    x0 = sim.model.rest_x
    top = np.flatnonzero(x0[:, 1] > sim.scene.colliders[0].point[1] + COLUMN_H - 0.6 * sim.scene.grid.cell_size)
    sim.advance(sim.scene.simulation.duration)
    return np.array([-(sim.state.particle_x[top, 1] - x0[top, 1]).mean()])


COLUMN = Problem(
    name="column", description="self-weight column (confined, 4 cells wide) on a sticky floor, settled: top drop",
    quantity="top settlement [m]", reference=np.array([COLUMN_SETTLE]), reference_name="rho g H0^2 / (2 M)",
    scale=COLUMN_SETTLE, finest=0.0625, ratio=np.sqrt(2), scene=column_scene, measure=top_settlement)

PROBLEMS = {p.name: p for p in (BAR, CANTILEVER, COLUMN, FREE_FALL)}
