"""Fracture from a fracture energy G_c: the threshold it gives, and the energy a crack absorbs against G_c."""

import math

import numpy as np
import pytest

from pdmpm_cli.engine.fracture import critical_stretch
from pdmpm_cli.study.fracture import critical_bond_energy, crossing_energy, pull, slit_drag
from pdmpm_cli.study.sim import Sim
from tests.test_cli import SMALL, pdmpm

G_C = 2.0  # [J/m^2]
M = 3e5  # P-wave modulus lam + 2 mu of the blocks below [Pa]


def block(cell, horizon=2.0, size=0.32, sampling="relaxed"):
    pad = 4 * cell
    return {"simulation": {"duration": 0.01, "fps": 100},
            "grid": {"cell_size": cell, "domain": {"min": [0, 0, 0], "max": [size + 2 * pad] * 3}},
            "gravity": [0, 0, 0],
            "bodies": [{"name": "block",
                        "geometry": {"mode": "cloud", "sampling": sampling, "horizon": horizon,
                                     "shape": {"type": "box", "center": [size / 2 + pad] * 3, "size": [size] * 3}},
                        "material": {"model": "elastic", "density": 1000.0, "lam": 1e5, "mu": 1e5},
                        "fracture": {"energy": G_C}}]}


def test_critical_stretch_is_silling_askari_for_their_bonds():
    """The integral behind critical_stretch, done for the PMB micropotential (c s^2 xi / 2 with
    c = 18 K / (pi delta^4)) instead of ours, gives Silling & Askari's s0 = sqrt(5 G / (9 K delta)); for ours it gives
    G = 3/4 M delta s0^2."""
    delta, k, g = 0.02, 1e6, 3.0
    xi = np.linspace(0.0, delta, 20001)
    s0 = math.sqrt(5 * g / (9 * k * delta))
    pmb = np.trapezoid(math.pi * xi**3 * (18 * k / (math.pi * delta**4)) * s0**2 * xi / 2, xi)
    assert pmb == pytest.approx(g, rel=1e-6)
    s0 = critical_stretch(g, M, delta)
    ours = np.trapezoid(math.pi * xi**3 * 15 / (math.pi * delta**3) * M * (1 - xi / delta) * s0**2, xi)
    assert ours == pytest.approx(g, rel=1e-6)


@pytest.mark.parametrize("cell, horizon", [(0.04, 2.0), (0.02, 2.0), (0.04, 3.0)])
def test_bonds_crossing_a_plane_hold_g_c_at_the_threshold(cell, horizon):
    """On the discretisation itself (relaxed cloud, per-particle calibration), the bonds crossing a unit area of a
    plane through the block, each at the threshold derived from G_c, hold G_c: within 10 % at 2 and 3 spacings,
    both inside the block and over a whole cross-section (surface particles included)."""
    size = 0.32
    sim = Sim(block(cell, horizon, size))
    b = sim.model.bodies[0]
    assert b.fracture.threshold == pytest.approx(math.sqrt(4 * G_C / (3 * M * b.horizon)))
    mid = sim.model.rest_x.mean(axis=0)
    whole = crossing_energy(sim.model, 0, M, mid[0], mid[1:] - size / 2, mid[1:] + size / 2)
    inner = crossing_energy(sim.model, 0, M, mid[0], mid[1:] - size / 2 + b.horizon, mid[1:] + size / 2 - b.horizon)
    print(f"\ncell {cell}, horizon {b.horizon:.3f} m, threshold {b.fracture.threshold:.4g}: crossing energy / G_c "
          f"{whole / G_C:.3f} (whole section), {inner / G_C:.3f} (interior)")
    assert whole == pytest.approx(G_C, rel=0.10) and inner == pytest.approx(G_C, rel=0.10)


def test_energy_or_threshold_exactly_one(tmp_path):
    """fracture takes exactly one of threshold and energy; neither or both is bad input (exit 2, the key and the
    fix); with energy, validate --explain prints the threshold it gives."""
    path = tmp_path / "frac.yaml"
    material = "material: {model: elastic, density: 1000, lam: 1e4, mu: 1e4}\n"
    path.write_text(SMALL.replace(material, material + "    fracture: {energy: 2.0}\n"))
    r = pdmpm("validate", path, "--explain")
    assert r.returncode == 0, r.stderr
    row = next(line for line in r.stdout.splitlines() if "fracture threshold" in line)
    # lam = mu = 1e4: M = 3e4 Pa; h = 0.025 m, delta = 0.05 m
    assert float(row.split("│")[-2]) == pytest.approx(math.sqrt(4 * 2.0 / (3 * 3e4 * 0.05)), rel=1e-3)
    assert "fracture energy G_c [J/m^2]" in r.stdout
    for extra in ("--set", "bodies.0.fracture.threshold=0.1"), ("--set", "bodies.0.fracture.energy=null"):
        r = pdmpm("validate", path, *extra)
        assert r.returncode == 2 and "Traceback" not in r.stderr
        assert "bodies.0.fracture: give exactly one of threshold" in r.stderr and "J/m^2" in r.stderr


def test_pulled_bar_breaks_at_its_notch_and_absorbs_at_least_g_c_a():
    """A notched bar pulled apart slowly at 4 cm cells (pdmpm_cli/study/fracture.py): the energy balance closes to
    10 % of the grips' work while nothing breaks (energy conservation), the bar comes apart in two, and it absorbs at
    least G_c over the ligament, with broken bonds worth at least the ligament's area (Griffith: a crack across the
    ligament costs G_c A). How far above it lies is the measured shortfall of the plane cuts (results.md)."""
    r = pull(0.04, G_C, after=0.05)
    print(f"\nD / G_c A {r.dissipated / r.expected:.2f} (cut bonds held {r.cut_energy / r.expected:.2f}), broken area / A "
          f"{r.bond_area / r.area:.2f}, balance before breaking {r.before / r.work_before:.3f} of W, separation "
          f"{r.separation:.3f} s, {r.large} large pieces, {r.seconds:.0f} s")
    assert abs(r.before) < 0.10 * r.work_before
    assert r.large == 2 and r.separation < 0.3
    assert r.dissipated > 0.85 * r.expected and r.bond_area > 0.85 * r.area


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="the grid bridges the notch, so the bar stores more than G_c A before it "
                   "breaks and the transfers damp what the snap releases; the plane cuts break several times the "
                   "ligament's bonds: D is 3-4 G_c A "
                   "(docs/results.md, 'Fracture energy')")
@pytest.mark.parametrize("cell", [0.04, 0.03, 0.02])
def test_pulled_bar_absorbs_g_c_a_at_three_resolutions(cell):
    """The issue's target: the bar absorbs G_c A within 15 % at every resolution (energy balance)."""
    r = pull(cell, G_C)
    print(f"\ncell {cell}: D / G_c A {r.dissipated / r.expected:.2f}, broken area / A {r.bond_area / r.area:.2f}")
    assert r.large == 2
    assert r.dissipated == pytest.approx(r.expected, rel=0.15)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="the grid bridges a slit narrower than its B-splines' reach: the free half "
                   "follows the pulled one (docs/method.md, 'Fracture energy')")
def test_the_grid_does_not_pull_across_a_slit():
    """Newton: no force crosses a gap, so the free half of a slit bar stays where it is while the other half is
    pulled away (its mean displacement under 10 % of the pulled end's)."""
    moved = slit_drag()
    print(f"\nthe free half moved {moved:.2f} of the pulled end")
    assert abs(moved) < 0.1


def test_bond_energy_behind_the_threshold_is_the_engines():
    """The per-bond energy the threshold is derived from, c_p w V_p V_q M s^2 / 2 per direction, is the engine's own
    strain energy: under an isotropic stretch s (every bond at s, Fbar = (1 + s) I) the bonds' sum, the solver's
    strain energy and the continuum's (M / 6)(tr(eps)^2 + 2 eps:eps) V = 5/2 M s^2 V agree."""
    sim = Sim(block(0.04, size=0.24))
    m, st = sim.model, sim.state
    s = sim.model.bodies[0].fracture.threshold
    centre = m.rest_x.mean(axis=0)
    st.particle_x[:] = centre + (1.0 + s) * (m.rest_x - centre)
    engine = sim.solver.strain_energy(st)
    bonds = float(critical_bond_energy(m, 0, M, s).sum())
    continuum = 2.5 * M * s**2 * float(m.particle_volume.sum())
    print(f"\nisotropic stretch {s:.4g}: bonds {bonds:.6g} J, engine {engine:.6g} J, continuum {continuum:.6g} J")
    assert bonds == pytest.approx(engine, rel=1e-9) and engine == pytest.approx(continuum, rel=1e-9)
