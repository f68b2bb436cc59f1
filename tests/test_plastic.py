"""Plastic bonds (eqs. 8-11): return map, load / unload / reload, a dent that stays, and the elastic limit."""

import numpy as np

from pdmpm_cli.engine.parallel import particle_chunks
from pdmpm_cli.engine.materials.elastic import averaged_bond
from pdmpm_cli.engine.materials.plastic import fbar_dilatation, plastic_forces, reverse_slots

from tests.conftest import BASE, merge

NONE_U1 = np.zeros(0, np.uint8)


def block(sim_factory, material, size=0.5):
    body = merge(BASE["bodies"][0], {"material": material})
    body["geometry"]["shape"]["size"] = [size] * 3
    return sim_factory({"bodies": [body]})


def reverse_of(m):
    """bond_reverse of a Model's families (the plastic material's start hook)."""
    out = np.full(len(m.bond_nbr), -1, np.int64)
    reverse_slots(m.bond_start, m.bond_nbr, 0, m.n_particles, out)
    return out


def return_map(sim, x, fbar, theta, lam, mu, psi, rev, ep):
    """Fbar (eq. 4) and the dilatations, then the return map of every bond at positions x, e_p in place (the pass
    also gives the bond forces, not used here); returns the largest f / psi_p after the map."""
    m, n = sim.model, sim.model.n_particles
    fbar_dilatation(0, n, m.body_horizon[0], mu, x, m.rest_x, m.particle_volume, m.bond_start, m.bond_nbr,
                    sim.state.bond_wv, NONE_U1, m.particle_Kinv, fbar, theta, particle_chunks())
    return plastic_forces(0, n, lam, mu, psi, x, m.rest_x, m.particle_volume, m.bond_start, m.bond_nbr,
                          sim.state.bond_wv, sim.state.bond_inv_len, NONE_U1, ep, NONE_U1, m.particle_coef, fbar, theta,
                          rev, np.zeros((1, n, 3)))


def shear_stress(m, x, fbar, ep, p, lam, mu, delta):
    """sigma_xy of particle p: sum_q T<p,q> (x) xi V_q, which equals dW/d(eps) under homogeneous deformation."""
    sigma = np.zeros((3, 3))
    for b in range(m.bond_start[p], m.bond_start[p + 1]):
        q = m.bond_nbr[b]
        xi = m.rest_x[q] - m.rest_x[p]
        eta = x[q] - x[p]
        r, l = np.linalg.norm(xi), np.linalg.norm(eta)
        y0, y1, y2, ly = averaged_bond(fbar[p], *xi)
        t = m.particle_coef[p] * (1 - r / delta) / r * (2 * mu * (ly / r - 1 - ep[b]) * np.array([y0, y1, y2]) / ly
                                                         + lam * (l / r - 1 - ep[b]) * eta / l)
        sigma += np.outer(t, xi) * m.particle_volume[q]
    return sigma[0, 1]


def test_shear_load_unload_reload(sim_factory):
    """Simple shear x = X + gamma Y e_x on a lattice block: linear to yield, a plateau, elastic unloading slope,
    the same slope on reloading, and f <= 1e-9 psi_p after every return map."""
    lam, mu, sy = 1e5, 1e5, 2e2  # yield strains ~1e-3: geometric nonlinearity stays below 1e-3
    sim = block(sim_factory, {"model": "plastic", "density": 1000.0, "lam": lam, "mu": mu, "yield_stress": sy})
    m = sim.model
    n = m.n_particles
    delta = m.body_horizon[0]
    c = m.rest_x.mean(axis=0)
    p = int(np.argmin(np.linalg.norm(m.rest_x - c, axis=1)))
    ep = np.zeros(len(m.bond_nbr))
    rev = reverse_of(m)
    theta = np.zeros(n)
    fbar = np.zeros((n, 3, 3))
    gy = sy / (lam + 2 * mu)  # a bond strain of the order of first yield
    path = np.concatenate([np.linspace(0, 8 * gy, 81), np.linspace(8 * gy, 0, 81)[1:],
                           np.linspace(0, 8 * gy, 81)[1:]])
    stress, worst = [], -1.0
    for g in path:
        x = m.rest_x.copy()
        x[:, 0] += g * (m.rest_x[:, 1] - c[1])
        worst = max(worst, return_map(sim, x, fbar, theta, lam, mu, 0.5 * sy**2, rev, ep))
        stress.append(shear_stress(m, x, fbar, ep, p, lam, mu, delta))
    stress = np.array(stress)
    g0 = stress[1] / path[1]  # initial shear modulus of the lattice
    slope = np.diff(stress) / np.diff(path)
    load, unload, reload = slope[:80], slope[80:160], slope[160:]
    print(f"\nG0 = {g0:.4g} Pa (M/3 = {(lam + 2 * mu) / 3:.4g}); peak stress {stress[80]:.4g} Pa; "
          f"final load slope {load[-1] / g0:.3g} G0; unloading slope {unload[0] / g0:.4g} G0; "
          f"reload slope {reload[0] / g0:.4g} G0; max f/psi after a return map {worst:.2e}")
    assert worst <= 1e-9
    assert np.allclose(load[:2], g0, rtol=1e-3)  # linear before the first bond yields
    assert abs(load[-1]) < 0.02 * g0  # plateau: every bond on the yield surface
    assert np.allclose(unload[:10], g0, rtol=3e-3)  # unloading is elastic, with the initial slope
    assert np.allclose(reload[:10], g0, rtol=3e-3)
    assert abs(stress[-1] - stress[80]) < 0.02 * abs(stress[80])  # reloading returns to the same plateau
    assert stress[160] < 0  # unloaded to zero strain, the block keeps a reverse stress: plastic strain stayed


def test_return_map_bounded_under_sustained_flow(sim_factory):
    """Thousands of increments of plastic shear: e_p follows e_dev, f stays on the surface, nothing grows."""
    lam, mu, sy = 1e5, 5e4, 1e3
    sim = block(sim_factory, {"model": "plastic", "density": 1000.0, "lam": lam, "mu": mu, "yield_stress": sy},
                size=0.3)
    m = sim.model
    n = m.n_particles
    ep = np.zeros(len(m.bond_nbr))
    rev = reverse_of(m)
    theta = np.zeros(n)
    fbar = np.zeros((n, 3, 3))
    worst = -1.0
    for g in np.linspace(0, 0.5, 2001):  # 50 % shear strain, 250x the yield strain
        x = m.rest_x.copy()
        x[:, 0] += g * m.rest_x[:, 1]
        worst = max(worst, return_map(sim, x, fbar, theta, lam, mu, 0.5 * sy**2, rev, ep))
    assert worst <= 1e-9 and np.isfinite(ep).all()
    assert np.abs(ep).max() < 0.5  # bounded by the total bond strain


def test_return_map_is_symmetric_and_rotation_free(sim_factory):
    """e_p is identical on both directions of every bond, and a rigid rotation causes no plastic flow."""
    sim = block(sim_factory, {"model": "plastic", "density": 1000.0, "lam": 1e5, "mu": 1e5, "psi_p": 1.0},
                size=0.3)
    m = sim.model
    n = m.n_particles
    rng = np.random.default_rng(1)
    theta = np.zeros(n)
    fbar = np.zeros((n, 3, 3))
    ep = np.zeros(len(m.bond_nbr))
    rev = reverse_of(m)
    x = m.rest_x + 1e-3 * rng.standard_normal(m.rest_x.shape)
    return_map(sim, x, fbar, theta, 1e5, 1e5, 1.0, rev, ep)
    src = np.repeat(np.arange(n), np.diff(m.bond_start))
    key = src * n + m.bond_nbr
    rev = np.searchsorted(key, m.bond_nbr.astype(np.int64) * n + src)
    assert np.count_nonzero(ep) > 0 and np.array_equal(ep, ep[rev])
    a = np.radians(40.0)
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    ep[:] = 0.0
    x = m.rest_x @ rot.T
    return_map(sim, x, fbar, theta, 1e5, 1e5, 1.0, rev, ep)
    assert np.abs(ep).max() < 1e-12


def test_elastic_limit_leaves_out_plastic_pass(sim_factory):
    """psi_p = 1e25 (Table 1's "elastic") runs as an elastic body: no return map and no per-bond arrays."""
    plastic = block(sim_factory, {"model": "plastic", "density": 1000.0, "lam": 1e5, "mu": 1e5, "psi_p": 100.0},
                    size=0.3)
    assert {"dilatation:plastic", "bonds:plastic"} <= set(plastic.plan.phases) and "bond_ep" in plastic.plan.fields
    assert plastic.state.bond_ep.shape == (plastic.plan.bonds,)
    elastic = block(sim_factory, {"model": "plastic", "density": 1000.0, "lam": 1e5, "mu": 1e5, "psi_p": 1e25},
                    size=0.3)
    assert elastic.plan.bodies[0].model == "elastic"
    assert "bonds:elastic" in elastic.plan.phases and not any(p.endswith(":plastic") for p in elastic.plan.phases)
    assert not {"bond_ep", "particle_theta"} & set(elastic.plan.fields)
    assert elastic.state.bond_ep.shape == (0,) and elastic.state.particle_theta.shape == (0,)


def test_elastic_scene_allocates_no_inelastic_arrays(sim_factory):
    """An elastic-only scene has no plastic, viscoelastic or damage arrays, in the Plan or in the State."""
    sim = sim_factory()
    inelastic = {"bond_ep", "particle_theta", "bond_active", "particle_damage", "particle_crack", "particle_inactive",
                 "bond_len0", "bond_force_el", "bond_force_visc", "particle_m", "particle_x_prev"}
    assert not inelastic & set(sim.plan.fields)
    assert all(getattr(sim.state, name).shape[0] == 0 for name in inelastic)
    assert sim.plan.phases == ("fbar", "bonds:elastic", "p2g", "grid_update", "g2p")


IMPACT = {
    "simulation": {"duration": 0.2, "fps": 20},
    "grid": {"cell_size": 0.025, "domain": {"min": [0, 0, 0], "max": [0.6, 0.45, 0.6]},
             "boundary": "sticky"},
    "gravity": [0, -9.81, 0],
    "bodies": [
        {"name": "slab", "geometry": {"mode": "cloud", "shape": {"type": "box", "center": [0.3, 0.14, 0.3],
                                                                  "size": [0.24, 0.1, 0.24]}},
         "material": {"model": "plastic", "density": 1000.0, "lam": 2e5, "mu": 2e5, "yield_stress": 2e3}},
        {"name": "ball", "geometry": {"mode": "cloud", "shape": {"type": "sphere", "center": [0.3, 0.29, 0.3],
                                                                  "radius": 0.05}},
         "material": {"model": "elastic", "density": 1000.0, "lam": 2e6, "mu": 2e6}, "velocity": [0, -3.0, 0]},
    ],
}


def dent_history(sim_factory, psi_p):
    """Depth of the slab's top surface under the impact point over time [m] (positive: pushed in)."""
    scene = merge(IMPACT, {})
    scene["bodies"][0]["material"] = {"model": "plastic", "density": 1000.0, "lam": 2e5, "mu": 2e5, "psi_p": psi_p}
    sim = sim_factory(base=scene)
    s, e = sim.model.body_ranges[0]
    x0 = sim.model.rest_x[s:e]
    top = np.flatnonzero((x0[:, 1] > x0[:, 1].max() - 0.015)
                         & (np.hypot(x0[:, 0] - 0.3, x0[:, 2] - 0.3) < 0.03)) + s
    rim = np.flatnonzero((x0[:, 1] > x0[:, 1].max() - 0.015)
                         & (np.hypot(x0[:, 0] - 0.3, x0[:, 2] - 0.3) > 0.09)) + s
    depth = []
    for t in np.arange(0.01, 0.2001, 0.01):
        sim.advance(t)
        x = sim.state.particle_x
        depth.append(x[rim, 1].mean() - x[top, 1].mean())  # relative to the rim: settling cancels out
    return np.array(depth), sim


def test_ball_leaves_a_dent_only_in_plastic_slab(sim_factory):
    """A ball hits a slab: the plastic slab (yield stress 2 kPa) keeps a dent, the same slab with psi_p = 1e25
    springs back (the ball and the slab have a grid field each and come apart after the impact)."""
    plastic, sim_p = dent_history(sim_factory, 0.5 * 2e3**2)
    elastic, sim_e = dent_history(sim_factory, 1e25)
    ratio_p = plastic[-5:].mean() / plastic.max()
    ratio_e = elastic[-5:].mean() / elastic.max()
    print(f"\nmax dent: plastic {plastic.max() * 1e3:.2f} mm, elastic {elastic.max() * 1e3:.2f} mm; residual / max: "
          f"plastic {ratio_p:.2f}, elastic {ratio_e:.2f}; bonds yielded "
          f"{np.count_nonzero(sim_p.state.bond_ep)} of {len(sim_p.state.bond_ep)}")
    assert plastic.max() > 2e-3 and elastic.max() > 2e-3  # both were hit hard enough to deform
    assert ratio_p > 0.5
    assert abs(ratio_e) < 0.3
    assert plastic[-5:].mean() > 3 * abs(elastic[-5:].mean())
    assert sim_p.state.yield_residual <= 1e-9


def test_soft_plastic_block_settles_without_gaining_energy(sim_factory):
    """A soft plastic block (yield at 1 % of M) dropped on the floor flattens and settles; its strain energy
    must then stay put. With the return map measuring the bond stretch alone while the forces act on
    (lam s + mu (sbar_p + sbar_q)) / M, it grew from 1.2 J to 60 J between 0.3 s and 1.1 s and blew up."""
    scene = merge(BASE, {
        "grid": {"domain": {"min": [0, 0, 0], "max": [1.2, 1.2, 1.2]}}, "gravity": [0, -9.81, 0],
        "colliders": [{"type": "plane", "point": [0, 0.45, 0], "normal": [0, 1, 0]}]})
    scene["bodies"][0]["geometry"] = {"mode": "cloud", "shape": {"type": "box", "center": [0.6, 0.6, 0.6],
                                                                  "size": [0.2, 0.2, 0.2]}}
    scene["bodies"][0]["material"] = {"model": "plastic", "density": 1000.0, "lam": 1e4, "mu": 1e4,
                                      "yield_stress": 300.0}
    sim = sim_factory(base=scene)
    sim.advance(0.4)
    settled = sim.solver.strain_energy(sim.state)
    sim.advance(0.8)
    later = sim.solver.strain_energy(sim.state)
    print(f"\nstrain energy {settled:.4g} J at 0.4 s, {later:.4g} J at 0.8 s")
    assert later <= 1.01 * settled
    assert sim.state.yield_residual <= 1e-9
