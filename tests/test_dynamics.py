"""MPM dynamics with analytic answers: free fall, conservation, vibrating bar."""

import dataclasses

import numpy as np
import pytest

from pdmpm_cli.errors import SimulationError
from pdmpm_cli.scene.loader import merge
from pdmpm_cli.study.problems import BAR_LENGTH, BAR_V0, bar_scene, bar_start, period as bar_period


def test_free_fall_follows_g_t2_over_2(sim_factory):
    """The leapfrog (Solver.substep: the first kick half a step) drops a free body exactly g t^2 / 2, at any step
    sequence, and its velocity is the half step's, -g (t - dt / 2); symplectic Euler's kick of a whole step from the
    start ran g t dt / 2 ahead."""
    sim = sim_factory({"gravity": [0, -9.81, 0], "grid": {"domain": {"min": [0, -1, 0], "max": [1, 1, 1]}},
                       "bodies": [{**sim_factory().scene.bodies[0].model_dump(),
                                   "geometry": {"mode": "cloud", "sampling": "jittered",
                                                "shape": {"type": "sphere", "center": [0.5, 0.6, 0.5],
                                                          "radius": 0.1}}}]})
    y0 = sim.com()[1]
    dts = []
    sim.advance(0.3, lambda s, dt: dts.append(dt))
    exact = y0 - 0.5 * 9.81 * 0.3**2
    err = sim.com()[1] - exact
    print(f"\nfree fall: y_com - exact = {err:.3e} m after {len(dts)} steps (symplectic Euler's g t dt / 2: "
          f"{9.81 * 0.3 * max(dts) / 2:.3e})")
    assert len(set(dts)) > 1 and abs(err) < 1e-12
    np.testing.assert_allclose(sim.state.particle_v[:, 1], -9.81 * (0.3 - dts[-1] / 2), rtol=1e-9)


@pytest.mark.parametrize("flip", [0.0, 0.95])
def test_linear_momentum_conserved_to_round_off(sim_factory, flip):
    """Bond forces are pairwise and APIC transfers conserve momentum, with a FLIP share (and MUSL's remap) too: a
    free, internally vibrating body."""
    sim = sim_factory({"simulation": {"duration": 1.0, "fps": 10, "flip": flip},
                       "bodies": [{**sim_factory().scene.bodies[0].model_dump(), "velocity": [0.3, -0.2, 0.1],
                                   "geometry": {"mode": "cloud", "sampling": "jittered",
                                                "shape": {"type": "box", "center": [0.45, 0.5, 0.5],
                                                          "size": [0.25, 0.2, 0.2]}}}]})
    rng = np.random.default_rng(1)
    sim.state.particle_v += rng.normal(0, 0.05, sim.state.particle_v.shape)
    sim.solver.start(sim.state)
    p0 = sim.momentum()
    sim.advance(0.2)
    assert sim.state.step > 50
    scale = sim.model.particle_mass.sum() * 0.4
    drift = np.abs(sim.momentum() - p0).max()
    print(f"\nmomentum drift over {sim.state.step} steps: {drift / scale:.2e} (relative)")
    assert drift < 1e-12 * scale * np.sqrt(sim.state.step)


def test_spinning_body_keeps_angular_momentum(sim_factory):
    """APIC keeps angular momentum: within 1 % over one revolution of a free spinning block."""
    omega = 2 * np.pi / 0.5
    sim = sim_factory({"bodies": [{**sim_factory().scene.bodies[0].model_dump(), "angular_velocity": [0, 0, omega],
                                   "geometry": {"mode": "cloud", "sampling": "jittered",
                                                "shape": {"type": "box", "center": [0.5, 0.5, 0.5],
                                                          "size": [0.3, 0.12, 0.12]}}}]})
    about = sim.com()
    l0 = sim.angular_momentum(about)[2]
    sim.advance(0.5)
    l1 = sim.angular_momentum(sim.com())[2]
    print(f"\nspin: L_z changed by {100 * (l1 / l0 - 1):+.3f} % over one revolution ({sim.state.step} steps)")
    assert abs(l1 / l0 - 1) < 0.01


def vibrating_bar(sim_factory, cell=1.25, periods=2.0):
    """Sulsky's bar (pdmpm_cli.study.problems.bar_scene): times and centre-of-mass velocity at every step."""
    sim = sim_factory(bar_scene(cell, periods), base={})
    bar_start(sim)
    times, vcom = [0.0], [sim.momentum()[0] / sim.model.particle_mass.sum()]

    def record(state, dt):
        times.append(state.time)
        vcom.append(sim.momentum()[0] / sim.model.particle_mass.sum())

    sim.advance(10.0 * periods, record)
    return np.array(times), np.array(vcom)


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_vibrating_bar_period_and_damping(sim_factory, precision):
    """Sulsky's bar in both storage precisions (simulation.precision; float32 read the same to 6 digits)."""
    t, v = vibrating_bar(lambda scene, base: sim_factory(merge(scene, {"simulation": {"precision": precision}}),
                                                       base=base))
    period = bar_period(t, v)  # from the zero crossings of the centre-of-mass velocity, (2 v0 / pi) cos(omega t)
    amp = [np.abs(v[(t >= a) & (t < a + 10.0)]).max() for a in (0.0, 10.0)]
    decay = 1 - amp[1] / amp[0]
    print(f"\nvibrating bar ({precision}): period {period:.4f} (analytic 10.0, error {100 * (period / 10 - 1):+.2f} %),"
          f" v_com amplitude {amp[0]:.5f} (analytic {0.2 / np.pi:.5f}), decay per period {100 * decay:.2f} %")
    assert abs(period / 10.0 - 1) < 0.05
    assert abs(amp[0] / (0.2 / np.pi) - 1) < 0.05
    assert decay < 0.12  # measured 8.5 % (jittered, 8 particles per cell): APIC damping plus mode mixing


def test_stiff_scene_with_oversize_dt_is_reduced_and_stable(sim_factory):
    """lam = 5e6 (the plastic board): a user dt 10x above the bound is reduced, says so, and runs stably."""
    probe = sim_factory({"bodies": [{**sim_factory().scene.bodies[0].model_dump(),
                                     "material": {"model": "elastic", "density": 1000.0, "lam": 5e6, "mu": 1.5e5}}]})
    bound = min(probe.plan.dt_cfl, probe.plan.dt_bond)
    sim = sim_factory({"simulation": {"duration": 0.1, "fps": 10, "dt": 10 * bound},
                       "gravity": [0, -9.81, 0],
                       "colliders": [{"type": "plane", "point": [0, 0.3, 0], "normal": [0, 1, 0]}],
                       "bodies": [{**probe.scene.bodies[0].model_dump(), "velocity": [0, -2.0, 0]}]})
    assert sim.plan.dt_reduced and sim.plan.dt_max <= bound
    assert "above the stability bound" in sim.plan.warnings()[0]
    sim.advance(0.1)
    assert np.isfinite(sim.state.particle_x).all()
    assert sim.solver.kinetic_energy(sim.state) < 0.5 * sim.model.particle_mass.sum() * 2.0**2 * 1.01 + 1.0


def test_forced_oversize_step_is_caught(sim_factory):
    """Forcing dt far above the bound blows up; the solver stops with the step, particles and the knob."""
    sim = sim_factory({"bodies": [{**sim_factory().scene.bodies[0].model_dump(), "velocity": [0, -1.0, 0]}]})
    sim.solver.plan = dataclasses.replace(sim.plan, dt_max=30 * sim.plan.dt_max, dt_cfl=30 * sim.plan.dt_cfl)
    with pytest.raises(SimulationError, match=r"at step \d+ .*lower simulation.cfl or simulation.bond_safety"):
        sim.advance(1.0)


def test_flip_keeps_the_energy_of_a_free_vibration(sim_factory):
    """A free elastic body keeps its energy. Sulsky's bar without walls, free at both ends, in its first mode
    v = v0 cos(pi x / L) (period 2 L / c = 5 s), the conservative bond term alone (mu = 0), simulation.flip = 1:
    kinetic (with APIC's affine part, 1/2 m D C:C, D = dx^2 / 3) plus strain energy within 1 % over two periods."""
    d = bar_scene(1.25, 2.0)
    d["simulation"] = {**d["simulation"], "flip": 1.0}
    d["colliders"] = []
    d["bodies"][0]["material"] = {**d["bodies"][0]["material"], "lam": 2 * d["bodies"][0]["material"]["mu"],
                                  "mu": 0.0}
    sim = sim_factory(d, base={})
    assert sim.plan.phases[-2:] == ("g2p", "remap")
    s, m, dx = sim.state, sim.model.particle_mass, sim.model.dx
    x0 = s.particle_x[:, 0].min()
    s.particle_v[:, 0] = BAR_V0 * np.cos(np.pi * (s.particle_x[:, 0] - x0) / BAR_LENGTH)
    sim.solver.start(s)

    def energy():
        affine = 0.5 * m @ np.einsum("ijk,ijk->i", s.particle_C, s.particle_C) * dx * dx / 3
        return sim.solver.kinetic_energy(s) + sim.solver.strain_energy(s) + affine

    e0 = energy()
    ratios = []
    for t in (2.5, 5.0, 7.5, 10.0):
        sim.advance(t)
        ratios.append(energy() / e0)
    print(f"\nfree bar, flip = 1: energy / initial every quarter of its 10 s {np.round(ratios, 4).tolist()}")
    assert min(ratios) > 0.99 and max(ratios) < 1.01


def test_auto_step_drops_the_bond_bound_of_grid_bodies_only(sim_factory):
    """simulation.step auto: an elastic body takes the CFL step (0.25 dx / c at rest), no bond bound, and an
    instability names only the CFL knob; a fracture body keeps its bond bound (crack particles integrate bonds
    off the grid). The conservative default keeps the bond bound for every body."""
    conservative = sim_factory()
    assert conservative.plan.binding == "bonds" and conservative.plan.step == "conservative"
    auto = sim_factory({"simulation": {"step": "auto"}})
    plan = auto.plan
    assert plan.binding == "cfl" and plan.dt_bond == np.inf
    assert plan.dt_max == pytest.approx(0.25 * plan.cell_size / plan.wave_speed)
    assert plan.dt_max > 1.3 * conservative.plan.dt_max  # the bond bound is 0.18 dx / c here
    assert auto.solver.knobs() == "simulation.cfl"
    body = {**sim_factory().scene.bodies[0].model_dump(), "fracture": {"threshold": 0.02}}
    cracking = sim_factory({"simulation": {"step": "auto"}, "bodies": [body]})
    assert cracking.plan.binding == "bonds" and cracking.plan.dt_bond < np.inf
