"""`pdmpm stability`: the case list, the classification (it must catch a blow-up), the automatic step
on the quick set, the forced-step threshold against the predicted bound, and the command's exit codes."""

import csv

import pytest

from pdmpm_cli import stability as st
from tests.test_cli import pdmpm


def test_sweep_covers_every_category_with_40_cases():
    cases = st.cases()
    names = [c.name for c in cases]
    assert len(cases) >= 40 and len(set(names)) == len(names)
    assert {c.category for c in cases} >= {"stiffness", "cfl", "incompressible", "stretch", "compression", "impact",
                                           "plastic", "broken", "shell", "fluid"}
    stiff = [c for c in cases if c.category == "stiffness"]
    assert len(stiff) >= 7  # 6-8 decades at fixed geometry
    assert set(st.QUICK) <= set(names) and set(st.THRESHOLD_CASES) <= set(names)
    with pytest.raises(st.InputError, match="unknown stability case nope"):
        st.select(["nope"])


def test_forced_oversize_step_is_caught_and_flagged():
    """The classifier must see a blow-up: 16x the predicted limit (the grid's here, 1.5 dx / c) is unstable, 1/2 of
    it is not."""
    case = st.select(["stiff_1e6"])[0]
    ready = st.prepare_case(case)
    big = st.run_case(case, 16.0, ready)
    small = st.run_case(case, 0.5, ready)
    assert big["forced"] and small["forced"]
    assert big["class"] in ("energy", "nan", "outside"), big
    assert small["class"] == "stable" and small["energy_ratio"] <= 1.0 + 1e-9


def test_quick_set_is_stable_with_the_automatic_step():
    """About 12 cases, one or two per category, including the soft plastic block that used to blow up."""
    rows = {c.name: st.run_case(c) for c in st.select(quick=True)}
    assert rows["cfl_1.2"]["class"] == "refused"
    bad = {n: (r["class"], r.get("message")) for n, r in rows.items() if r["class"] not in ("stable", "refused")}
    assert not bad
    for name, r in rows.items():
        if r["class"] == "stable":  # dt_ratio: the largest step over dx / c, at most the case's CFL factor
            cfl = 1.0 if name.startswith("cfl_1") else 0.4
            assert r["energy_ratio"] <= st.GROWTH and r["dt_ratio"] <= cfl + 1e-9 and r["cells_per_step"] < 2.0, name
    assert rows["shatter_1e-4"]["isolated"] > 0  # the case did break every bond of some particles


def test_predicted_limits_order_and_the_automatic_step_below_them():
    """Jensen's inequality puts the grid limit above the crack particles', which the Silling & Askari bond bound
    (the automatic step's, 0.7 of it) bounds from below; a floor 0.4 m above the particles' lowest allowed
    position is 0.4 m deep."""
    ready = st.prepare_case(st.select(["crack_0.02"])[0])
    crit, plan = ready.critical, ready.prep.plan
    assert crit.grid > crit.particles > ready.dt_bond > plan.dt_max
    assert crit.tunnel_depth == pytest.approx(0.45 - 0.05)
    assert ready.bound == "grid" and ready.dt_pred == crit.grid
    assert crit.predicted(ready.v0, True) == crit.particles
    assert crit.predicted(1e6, False) == pytest.approx(0.4 / 1e6)


def test_arnoldi_matches_a_dense_eigensolve():
    """The matrix-free largest eigenvalues equal those of the assembled operators (not symmetric: the Fbar force
    is not an energy gradient), K probed column by column
    (study.problems.bond_stiffness) and N from the engine's weights: M_I^-1 N K N^T on the grid, M_p^-1 K off it."""
    import numpy as np
    from scipy.linalg import eigvals

    from pdmpm_cli.engine.spectrum import grid_omega2, particle_omega2
    from pdmpm_cli.study.problems import bond_stiffness, grid_weights
    from pdmpm_cli.study.sim import Sim

    scene = st.merge(st.BASE, {"bodies": [st._body(geometry={"shape": {"size": [0.1, 0.1, 0.15]}})]})
    sim = Sim(scene)
    m = sim.model
    K = bond_stiffness(sim).toarray()
    mp = np.repeat(m.particle_mass, 3)
    particles = np.abs(eigvals(K / mp[:, None])).max()
    N = grid_weights(sim)
    N = N[np.flatnonzero(np.asarray(N.sum(axis=1)).ravel() > 0)]
    N3 = np.kron(N.toarray(), np.eye(3))
    grid = np.abs(eigvals(N3 @ K @ N3.T / (N3 @ mp)[:, None])).max()
    print(f"\n{m.n_particles} particles: grid omega^2 {grid:.6g}, particles {particles:.6g} 1/s^2")
    assert grid_omega2(sim.solver, sim.state) == pytest.approx(grid, rel=1e-3)
    assert particle_omega2(sim.solver, sim.state, [0]) == pytest.approx(particles, rel=1e-3)


def test_threshold_is_within_2x_of_the_predicted_limit():
    result = st.threshold(st.select(["stiff_1e6"])[0], bisections=3)
    print(f"\nstiff_1e6: stable up to {result['measured']:.3g} dt_pred, unstable at {result['unstable']:.3g}")
    assert result["bracketed"] and result["within_2x"]
    assert result["bond_units"] > 2  # the bond bound the step uses is conservative for a body on the grid


def test_command_writes_tables_and_exit_codes(tmp_path, monkeypatch):
    out = tmp_path / "stab"
    r = pdmpm("stability", "-c", "stiff_1e3", "-c", "cfl_1.2", "--no-thresholds", "--out", out)
    assert r.returncode == 0, r.stderr
    rows = list(csv.DictReader(open(out / "stability.csv")))
    assert [row["class"] for row in rows] == ["stable", "refused"]
    assert "classes: refused 1, stable 1" in r.stderr
    r = pdmpm("stability", "-c", "stiff_1e6", "--out", out)  # one threshold: every forced run is flagged
    assert r.returncode == 0, r.stderr
    forced = list(csv.DictReader(open(out / "forced.csv")))
    assert len(forced) >= 3 and all(row["forced"] == "True" for row in forced)
    assert any(row["class"] != "stable" for row in forced)
    r = pdmpm("stability", "--list")
    assert r.returncode == 0 and "impact_floor_10" in r.stdout


def test_help_imports_no_engine():
    """`pdmpm stability --help` stays instant: the command module imports neither numba nor numpy."""
    import subprocess
    import sys

    code = "import sys, pdmpm_cli.cli.app; print(sorted({'numba', 'numpy'} & set(sys.modules)))"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.strip() == "[]"
    r = pdmpm("stability", "--help")
    assert r.returncode == 0 and "--quick" in r.stdout


def test_command_exits_1_on_an_unstable_case(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from pdmpm_cli.cli.app import app

    monkeypatch.setattr(st, "run_case", lambda case: {"case": case.name, "class": "nan", "wall_s": 0.0,
                                                      "message": "NaN at step 3"})
    result = CliRunner().invoke(app, ["stability", "-c", "stiff_1e3", "--no-thresholds", "--out", str(tmp_path)])
    assert result.exit_code == 1


@pytest.mark.slow
def test_full_sweep():
    """The whole sweep (about 90 s on one core) and every threshold case: none unstable with the automatic
    step, every measured threshold within 2x of the predicted limit, and the automatic step at least 3x below
    it (docs/results.md, 'Stability')."""
    rows = [st.run_case(c) for c in st.cases()]
    assert len(rows) >= 60
    assert all(r["class"] in ("stable", "refused") for r in rows), [r["case"] for r in rows if r["class"] != "stable"]
    results = {n: st.threshold(c) for n, c in zip(st.THRESHOLD_CASES, st.select(st.THRESHOLD_CASES))}
    assert all(r["bracketed"] and r["within_2x"] for r in results.values()), results
    assert all(r["margin"] > 3 for r in results.values()), results  # the automatic step is safe
    assert results["impact_floor_10"]["bound"] == "tunnel" and results["impact_floor_10"]["failure"] == "outside"
