"""Viscoelastic liquids keep their volume (the volume-ratio pressure, docs/method.md): the MLS-MPM pressure term's
virial, a column at rest (hydrostatics: height, volume and spacing kept), a dam break (volume kept) and start-up
Couette flow (the analytic series with the stated viscosity). The longer versions are marked slow; bench/fluids.py
prints the figures in docs/results.md."""

from types import SimpleNamespace

import numpy as np
import pytest

from pdmpm_cli.checkpoint import restore, snapshot
from pdmpm_cli.engine.backends.cpu import UNSPLIT
from pdmpm_cli.engine.materials.viscoelastic import grid_volume_ratios, volume_pressures
from pdmpm_cli.engine.transfer import grid_density, p2g_at, stencil
from tests import fluid_cases as F
from tests.conftest import merge


def test_pressure_term_is_the_stress_virial():
    """J advances by det(I + dt C), and the pressure folded into C makes P2G push the nodes apart with the virial of
    the stress, sum_i (x_i - x_p) . dp_i = -dt V tr(sigma) = 3 dt V p, adding no net momentum (Hu et al. 2018)."""
    dx, dt, dt_prev, bulk = 0.1, 1e-3, 2e-3, 1e5
    x = np.array([[0.537, 0.412, 0.466]])
    v = np.array([[0.3, -0.2, 0.1]])
    grad = np.array([[[1.0, 0.2, 0.0], [0.1, -3.0, 0.4], [0.0, 0.3, -2.0]]])  # tr = -4 1/s
    mass, volume = np.array([2.0]), np.array([1e-3])
    j = np.array([1.0])

    def scatter(c):
        g = np.zeros((10, 10, 10, 4))
        p2g_at(0, x, v, c, mass, np.zeros((1, 3)), np.zeros(0, np.uint8), np.zeros(0, np.uint8), dt,
               np.zeros(3), 1 / dx, g, np.empty(4), np.empty(4), np.empty(4), *UNSPLIT, 0)
        return g

    before = scatter(grad.copy())
    c = grad.copy()
    volume_pressures(0, 1, bulk, dt_prev, dt, 1 / dx, np.zeros(0, np.uint8), volume, mass, j, c)
    assert j[0] == pytest.approx(np.linalg.det(np.eye(3) + dt_prev * grad[0]), rel=1e-14)
    pressure = bulk * (1.0 - j[0])
    extra = scatter(c) - before
    nodes = np.stack(np.meshgrid(*[np.arange(10) * dx] * 3, indexing="ij"), axis=-1)
    virial = np.einsum("ijka,ijka->", nodes - x[0], extra[..., 1:])
    np.testing.assert_allclose(extra[..., 1:].sum(axis=(0, 1, 2)), 0.0, atol=1e-15)
    assert virial == pytest.approx(3.0 * dt * volume[0] * j[0] * pressure, rel=1e-9)


def test_grid_volume_ratio_lowers_j_only_where_particles_crowd():
    """J <- min(J, rho0 / rho_grid) (grid_volume_ratio_at, rho_grid as G2P gathers it: transfer.grid_density): a
    lattice at the rest spacing keeps J = 1 everywhere (inside, the grid density is rho0; at its faces less, which
    must not pull); the same lattice squeezed to 0.98 of the spacing gets J = 0.98^3 where the stencil is full, and
    its faces keep J = 1."""
    dx, n = 0.1, 20
    h, rho0 = dx / 2, 1000.0
    for scale in (1.0, 0.98):
        x = (np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), axis=-1).reshape(-1, 3) - (n - 1) / 2) \
            * h * scale + 1.2
        mass = np.full(len(x), rho0 * h**3)
        g = np.zeros((24, 24, 24, 4))
        for p in range(len(x)):
            p2g_at(p, x, np.zeros_like(x), np.zeros((len(x), 3, 3)), mass, np.zeros_like(x), np.zeros(0, np.uint8),
                   np.zeros(0, np.uint8), 0.0, np.zeros(3), 1 / dx, g, np.empty(4), np.empty(4), np.empty(4),
                   *UNSPLIT, 0)
        rho, w = np.empty(len(x)), [np.empty(4) for _ in range(3)]
        for p in range(len(x)):
            bx, by, bz = stencil(x, p, np.zeros(3), 1 / dx, *w)[3:]
            rho[p] = grid_density(g, bx, by, bz, *w) / dx**3
        j = np.ones(len(x))
        grid_volume_ratios(0, len(x), rho0, np.zeros(0, np.uint8), rho, j)
        depth = np.min(np.minimum(np.arange(n), n - 1 - np.arange(n))[np.indices((n,) * 3).reshape(3, -1)], axis=0)
        inside, face = depth >= 8, depth == 0
        assert inside.any() and np.all(j[face] == 1.0)
        np.testing.assert_allclose(j[inside], scale**3, rtol=1e-3 if scale < 1.0 else 1e-12)


def shift_once(sim):
    """One particle shift (shift:viscoelastic) of the first body on the current positions; returns the raw shifts."""
    sim.solver.kinds[0].after_move(sim.solver, 0, 0.0)
    return sim.state.particle_shift.copy()


def test_shift_leaves_a_relaxed_lattice_and_separates_a_pair(sim_factory):
    """The particle shift (Lind et al. 2012, docs/method.md): a lattice at the rest spacing is not moved at all; an
    interior particle moved 0.6 h towards its neighbour is pushed back apart, and x_prev moves with it (the bonds see
    no increment); a top-surface particle whose neighbour below moved up to 0.5 h gets no shift along the surface's
    normal, while that neighbour is pushed down."""
    sim = sim_factory(base=F.column(1000.0, 0.1, tau=0.001))
    h = sim.model.bodies[0].spacing
    x0 = sim.state.particle_x.copy()
    shift_once(sim)
    assert np.array_equal(sim.state.particle_x, x0)
    p = int(np.argmin(np.linalg.norm(x0 - x0.mean(axis=0), axis=1)))  # an interior particle
    q = int(np.argmin(np.linalg.norm(x0 - (x0[p] + [h, 0, 0]), axis=1)))
    sim.state.particle_x[p] += [0.6 * h, 0, 0]
    sim.state.particle_x_prev[:] = sim.state.particle_x
    shift_once(sim)
    x = sim.state.particle_x
    assert np.linalg.norm(x[q] - x[p]) > 0.4 * h * 1.05
    np.testing.assert_array_equal(sim.state.particle_x_prev, x)
    top = int(np.argmax(np.where(np.abs(x0[:, 0] - x0[p, 0]) + np.abs(x0[:, 2] - x0[p, 2]) < 1e-9, x0[:, 1], -1)))
    below = int(np.argmin(np.linalg.norm(x0 - (x0[top] - [0, h, 0]), axis=1)))
    sim.state.particle_x[:] = x0
    sim.state.particle_x[below, 1] += 0.5 * h
    raw = shift_once(sim)
    assert abs(raw[top, 1]) < 1e-12 * h and raw[below, 1] < 0.0


def test_only_liquids_pay_for_the_shift(sim_factory):
    """The Plan lists shift:viscoelastic for a liquid (relaxing_fraction 1) only: not for a body that keeps some
    shear (cream) or sets shift_distance 0, nor for an elastic scene."""
    scene = F.column(1000.0, 0.1, tau=0.001)
    assert "shift:viscoelastic" in sim_factory(base=scene).plan.phases
    for change in ({"relaxing_fraction": 0.5}, {"shift_distance": 0.0}):
        other = merge(scene, {"bodies": [merge(scene["bodies"][0], {"material": change})]})
        sim = sim_factory(base=other)
        assert not any(p.startswith("shift") for p in sim.plan.phases) and not sim.solver.movers
    assert not any(p.startswith("shift") for p in sim_factory().plan.phases)


def column_history(sim_factory, scene, samples=10):
    """Height, volume and nearest spacing relative to the start, at `samples` times over the run."""
    sim = sim_factory(base=scene)
    h = sim.model.bodies[0].spacing
    x0 = sim.state.particle_x.copy()
    start = (F.surface_height(x0, h, 0.1), F.occupied_volume(x0, h), F.nearest_spacing(x0))
    rows = []
    for t in np.linspace(0, scene["simulation"]["duration"], samples + 1)[1:]:
        sim.advance(t)
        x = sim.state.particle_x
        rows.append((t, F.surface_height(x, h, 0.1) / start[0], F.occupied_volume(x, h) / start[1],
                     F.nearest_spacing(x) / start[2]))
    return np.array(rows)


def check_column(rows, label):
    worst = np.abs(rows[:, 1:] - 1.0).max(axis=0)
    print(f"\n{label}: worst height {worst[0]:.2%}, volume {worst[1]:.2%}, nearest spacing {worst[2]:.2%}")
    assert worst[0] < 0.01 and worst[1] < 0.01 and worst[2] < 0.10


@pytest.mark.parametrize("density", [1000.0, 1400.0])
def test_column_at_rest_keeps_height_volume_and_spacing(sim_factory, density):
    """A liquid column at rest in a tank, over 100 relaxation times: height and particle volume within 1 %, nearest
    spacing within 10 % of the start (hydrostatic compression rho g H / 2K is 0.15 % with the default K)."""
    check_column(column_history(sim_factory, F.column(density, 0.1, tau=0.001)), f"{density:.0f} kg/m^3")


def test_column_without_the_pressure_collapses(sim_factory):
    """The check above can fail: with a negligible bulk modulus the bonds alone let the column sink."""
    scene = F.column(1000.0, 0.1, tau=0.001)
    scene = merge(scene, {"bodies": [merge(scene["bodies"][0], {"material": {"bulk_modulus": 1.0}})]})
    rows = column_history(sim_factory, scene, samples=1)
    print(f"\nwithout the pressure: height {rows[-1, 1]:.1%}, volume {rows[-1, 2]:.1%} of the start")
    assert rows[-1, 1] < 0.95


@pytest.mark.slow
@pytest.mark.parametrize("density", [1000.0, 1400.0])
def test_column_at_rest_long(sim_factory, density):
    """As above over 100 relaxation times of 0.01 s (1 s) and a taller column."""
    rows = column_history(sim_factory, F.column(density, 1.0, size=(0.08, 0.2, 0.08), tau=0.01))
    check_column(rows, f"{density:.0f} kg/m^3, 1 s")


def dam_volumes(sim_factory, duration, samples, dx=0.02):
    sim = sim_factory(base=F.dam_break(duration, dx=dx))
    h = sim.model.bodies[0].spacing
    v0 = F.occupied_volume(sim.state.particle_x, h)
    out = []
    for t in np.linspace(0, duration, samples + 1)[1:]:
        sim.advance(t)
        out.append(F.occupied_volume(sim.state.particle_x, h) / v0)
    return np.array(out), sim


def test_dam_break_keeps_volume(sim_factory):
    """A released block of liquid spreads (its surface falls) and keeps its volume within 2 %."""
    ratios, sim = dam_volumes(sim_factory, 0.12, 4)
    h = sim.model.bodies[0].spacing
    height = F.surface_height(sim.state.particle_x, h, 0.1)
    print(f"\nvolume / start: {np.round(ratios, 4).tolist()}; surface height {height * 1e3:.1f} mm (from 120)")
    assert height < 0.9 * 0.12  # it flowed
    assert np.abs(ratios - 1.0).max() < 0.02


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="at 2 cm the layer the block spreads into is three spacings deep, where the "
                   "bulk Voronoi measure does not hold (a jittered 6-layer slab already reads 1 % low; here 0.885 at "
                   "0.35 s, sum V0 J within 5e-4): the 1 cm case below asserts the issue's 2 %")
def test_dam_break_keeps_volume_long(sim_factory):
    ratios, _ = dam_volumes(sim_factory, 0.4, 8)
    print(f"\nvolume / start: {np.round(ratios, 4).tolist()}")
    assert np.abs(ratios - 1.0).max() < 0.02


@pytest.mark.slow
def test_dam_break_keeps_volume_fine(sim_factory):
    """The dam break at 1 cm cells (4608 particles), where the layer it spreads into stays six spacings deep, deep
    enough for the bulk Voronoi measure: within 2 % at every sample through 0.4 s (docs/results.md, 'Liquids')."""
    ratios, _ = dam_volumes(sim_factory, 0.4, 8, dx=0.01)
    print(f"\nvolume / start: {np.round(ratios, 4).tolist()}")
    assert np.abs(ratios - 1.0).max() < 0.02


def couette_errors(sim_factory, duration, samples, **size):
    """Mid-layer velocity against the series (held node rows depth + dx apart), relative to the final value."""
    scene = F.couette(duration, **size)
    sim = sim_factory(base=scene)
    mat, dx, h = scene["bodies"][0]["material"], sim.model.dx, sim.model.bodies[0].spacing
    depth, length = size.get("depth", 0.1), size.get("length", 0.2)
    nu = mat["relaxing_fraction"] * mat["mu"] * mat["relaxation_time"] / mat["density"]
    rows = []
    for t in np.linspace(0, duration, samples + 1)[1:]:
        sim.advance(t)
        u = F.mid_layer_velocity(sim.state.particle_x, sim.state.particle_v, h, (0.1 + length / 2, 0.105 + depth / 2),
                                 depth)
        rows.append((t, u, F.couette_mid_velocity(t, depth + dx, nu, 0.1)))
    rows = np.array(rows)
    print("\n" + "; ".join(f"t {t:.3f} s: {u:.4f} m/s (series {a:.4f})" for t, u, a in rows))
    return rows


def test_startup_couette_follows_the_series(sim_factory):
    """Start-up Couette flow: the mid-layer velocity follows the analytic series with nu = l mu tau / rho within
    10 % after the first 5 % of the diffusion time (H + dx)^2 / nu (before, the Maxwell liquid's shear wave lags)."""
    rows = couette_errors(sim_factory, 0.12, 3, depth=0.06, length=0.12, width=0.02)
    np.testing.assert_allclose(rows[:, 1], rows[:, 2], rtol=0.1)


@pytest.mark.slow
def test_startup_couette_follows_the_series_long(sim_factory):
    rows = couette_errors(sim_factory, 0.3, 5)
    np.testing.assert_allclose(rows[:, 1], rows[:, 2], rtol=0.1)


def test_resume_carries_the_volume_ratio(sim_factory):
    """particle_J is a declared array, so a checkpoint carries it: a resumed dam break is bitwise the uninterrupted
    one, and the same resume with J reset to 1 is not (the declaration is what carries it)."""
    scene = F.dam_break(0.04)
    ref = sim_factory(base=scene)
    ref.advance(0.02)
    arrays, scalars = snapshot(ref.state)
    ref.advance(0.04)
    for lose_j, equal in ((False, True), (True, False)):
        saved = dict(arrays, particle_J=np.ones_like(arrays["particle_J"])) if lose_j else arrays
        sim = sim_factory(base=scene)
        restore(SimpleNamespace(arrays=saved, attrs=scalars, path="memory"), sim.state, sim.solver)
        sim.advance(0.04)
        assert np.array_equal(sim.state.particle_x, ref.state.particle_x) == equal
