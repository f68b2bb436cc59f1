"""Elastic bonds (eqs. 4-7): equilibrium, calibration and the effective constants of docs/method.md."""

import numpy as np
import pytest

from pdmpm_cli.engine.bonds import averaged_deformation
from pdmpm_cli.engine.parallel import particle_chunks
from pdmpm_cli.engine.materials.elastic import effective_constants, elastic_energy, elastic_forces, sum_forces

NONE_U1 = np.zeros(0, np.uint8)  # no fracture: every bond intact
NONE_F8 = np.zeros(0)  # no plasticity: e_p = 0


def interior(sim, margin):
    """Particles whose whole family lies inside the body (no surface effect)."""
    x = sim.model.rest_x
    lo, hi = x.min(axis=0) + margin, x.max(axis=0) - margin
    return np.flatnonzero(np.all((x > lo) & (x < hi), axis=1))


def deform(sim, F):
    """Apply the homogeneous deformation x = F X about the body centre; return (forces, per-particle W)."""
    m = sim.model
    c = m.rest_x.mean(axis=0)
    x = (m.rest_x - c) @ np.asarray(F).T + c
    fbar = np.zeros((len(x), 3, 3))
    averaged_deformation(0, len(x), x, m.rest_x, m.bond_start, m.bond_nbr, sim.state.bond_wv, m.particle_Kinv, fbar,
                         particle_chunks())
    mat = m.materials[0]
    delta = m.body_horizon[0]
    force, private = np.zeros_like(x), np.zeros((3,) + x.shape)  # three thread arrays, whatever the thread count
    elastic_forces(0, len(x), mat.lam, mat.mu, x, m.rest_x, m.particle_volume, m.bond_start, m.bond_nbr,
                   sim.state.bond_wv, sim.state.bond_inv_len, NONE_U1, NONE_F8, NONE_U1, m.particle_coef, fbar, private)
    sum_forces(0, len(x), private, force)
    w = np.array([elastic_energy(p, p + 1, mat.lam, mat.mu, delta, x, m.rest_x, m.particle_volume, m.bond_start,
                                 m.bond_nbr, NONE_U1, NONE_F8, NONE_U1, m.particle_coef, fbar) / m.particle_volume[p]
                  for p in range(len(x))])
    return force, w, fbar


@pytest.mark.parametrize("lam,mu", [(1e5, 1e5), (5e6, 1.5e5), (500.0, 0.0)])
def test_uniform_stretch_zero_force_and_calibrated_energy(sim_factory, lam, mu):
    """Interior lattice particles under x = (1 + s0) X: zero net force, W = (5/2) M s0^2 exactly."""
    body = sim_factory().scene.bodies[0].model_dump()
    body["geometry"]["shape"]["size"] = [0.5, 0.5, 0.5]
    body["material"] = {"model": "elastic", "density": 1000.0, "lam": lam, "mu": mu}
    sim = sim_factory({"bodies": [body]})
    s0 = 1e-3
    force, w, fbar = deform(sim, (1 + s0) * np.eye(3))
    inner = interior(sim, sim.model.body_horizon[0] * 2.01)
    assert len(inner) > 50
    m = lam + 2 * mu
    typical = m * s0 * sim.model.particle_volume[0] ** (2 / 3)  # stress x face area
    assert np.abs(force[inner]).max() < 1e-10 * typical
    np.testing.assert_allclose(fbar[inner], (1 + s0) * np.broadcast_to(np.eye(3), fbar[inner].shape), atol=1e-12)
    np.testing.assert_allclose(w[inner], 2.5 * m * s0**2, rtol=1e-9)


def test_surface_particles_have_calibrated_energy(sim_factory):
    """The per-particle normalisation (surface correction): surface particles store the same energy density."""
    sim = sim_factory()
    s0 = 1e-3
    _, w, _ = deform(sim, (1 + s0) * np.eye(3))
    m = 1e5 + 2e5
    corner_floor = sim.model.particle_omega < np.pi * sim.model.body_horizon[0] ** 3 / 24
    np.testing.assert_allclose(w[~corner_floor], 2.5 * m * s0**2, rtol=1e-9)


def test_free_body_at_rest_feels_no_force(sim_factory):
    sim = sim_factory({"bodies": [{**sim_factory().scene.bodies[0].model_dump(),
                                    "geometry": {"mode": "cloud", "sampling": "jittered",
                                                 "shape": {"type": "sphere", "center": [0.5, 0.5, 0.5], "radius": 0.15}}}]})
    force, w, _ = deform(sim, np.eye(3))
    typical = 3e5 * sim.model.particle_volume[0] ** (2 / 3)  # M x face area: the force of a unit strain
    assert np.abs(force).max() < 1e-12 * typical and np.abs(w).max() < 1e-25 * 3e5


def fit_moduli(sim, s=1e-4):
    """Fit C11, C12 from the mean interior energy of uniaxial and biaxial strain along x, y and z."""
    inner = interior(sim, sim.model.body_horizon[0] * 1.01)
    c11, c11_12 = [], []
    for a in range(3):
        e = np.zeros((3, 3))
        e[a, a] = s
        c11.append(2 * deform(sim, np.eye(3) + e)[1][inner].mean() / s**2)
        b = (a + 1) % 3
        e[b, b] = s
        c11_12.append(deform(sim, np.eye(3) + e)[1][inner].mean() / s**2)
    c11 = np.mean(c11)
    c12 = np.mean(c11_12) - c11
    return c11, c12


@pytest.mark.parametrize("sampling", ["relaxed", "jittered"])
def test_uniaxial_stretch_measures_documented_youngs_modulus(sim_factory, sampling):
    """Relaxed (default) and jittered sampling: E from the fitted stiffness within 5 % of E_eff = 5 M / 6, nu near
    1/4 (the Lloyd steps do not bring back the lattice's anisotropy)."""
    body = sim_factory().scene.bodies[0].model_dump()
    body["geometry"] = {"mode": "cloud", "sampling": sampling,
                        "shape": {"type": "box", "center": [0.5, 0.5, 0.5], "size": [0.5, 0.5, 0.5]}}
    sim = sim_factory({"grid": {"cell_size": 0.04}, "bodies": [body]})
    c11, c12 = fit_moduli(sim)
    e_meas = (c11 - c12) * (c11 + 2 * c12) / (c11 + c12)
    nu_meas = c12 / (c11 + c12)
    eff = effective_constants(1e5, 1e5, 1000.0)
    print(f"\nuniaxial, {sampling}: E_meas = {e_meas:.5g} Pa, E_eff = {eff['youngs_modulus']:.5g} Pa "
          f"({100 * (e_meas / eff['youngs_modulus'] - 1):+.2f} %), nu_meas = {nu_meas:.4f}")
    assert abs(e_meas / eff["youngs_modulus"] - 1) < 0.05
    assert abs(nu_meas - 0.25) < 0.02


def test_lattice_sampling_is_anisotropic(sim_factory):
    """Why jittered is the default: on a cubic lattice (delta = 2h) E along an axis is ~20 % above E_eff."""
    sim = sim_factory({"bodies": [{**sim_factory().scene.bodies[0].model_dump(),
                                    "geometry": {"mode": "cloud", "sampling": "lattice",
                                                 "shape": {"type": "box", "center": [0.5, 0.5, 0.5],
                                                           "size": [0.4, 0.4, 0.4]}}}]})
    c11, c12 = fit_moduli(sim)
    e100 = (c11 - c12) * (c11 + 2 * c12) / (c11 + c12)
    assert e100 / (5 * 3e5 / 6) > 1.15


def pair_forces(sim, x, fbar, private, active, crack, ep):
    m, mat = sim.model, sim.model.materials[0]
    force = np.zeros_like(x)
    elastic_forces(0, len(x), mat.lam, mat.mu, x, m.rest_x, m.particle_volume, m.bond_start, m.bond_nbr,
                   sim.state.bond_wv, sim.state.bond_inv_len, active, ep, crack, m.particle_coef, fbar, private)
    sum_forces(0, len(x), private, force)
    return force


def test_pair_forces_conserve_momentum_for_any_thread_count(sim_factory):
    """Each bond pair is evaluated once and its forces are equal and opposite (eq. 7): with random motion, broken
    bonds (both directions), crack-surface particles and plastic strain, the forces sum to zero, and one, two or
    seven per-thread force arrays give the same forces to round-off."""
    from pdmpm_cli.engine.fracture import cut_pair

    sim = sim_factory()
    m = sim.model
    rng = np.random.default_rng(7)
    x = m.rest_x + 0.05 * m.body_spacing[0] * rng.standard_normal(m.rest_x.shape)
    fbar = np.zeros((len(x), 3, 3))
    averaged_deformation(0, len(x), x, m.rest_x, m.bond_start, m.bond_nbr, sim.state.bond_wv, m.particle_Kinv, fbar,
                         particle_chunks())
    active = np.ones(len(m.bond_nbr), np.uint8)
    for b in rng.choice(len(m.bond_nbr), len(m.bond_nbr) // 10, replace=False):
        p = np.searchsorted(m.bond_start, b, side="right") - 1
        cut_pair(b, p, m.bond_start, m.bond_nbr, active)
    crack = (rng.random(len(x)) < 0.1).astype(np.uint8)
    src = np.repeat(np.arange(len(x)), np.diff(m.bond_start))
    ep = 1e-3 * np.sin(src + m.bond_nbr)  # symmetric in p, q like the return map's e_p
    typical = 3e5 * 0.05 * m.particle_volume[0] ** (2 / 3)
    forces = [pair_forces(sim, x, fbar, np.zeros((nt,) + x.shape), active, crack, ep) for nt in (1, 2, 7)]
    assert np.abs(forces[0]).max() > 1e-3 * typical
    for f in forces:
        assert np.abs(f.sum(axis=0)).max() < 1e-12 * typical * np.sqrt(len(x))
        np.testing.assert_allclose(f, forces[0], rtol=0, atol=1e-12 * np.abs(forces[0]).max())
