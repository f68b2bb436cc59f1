"""`pdmpm stability` (issue 6): the case list, the classification (it must catch a blow-up), the automatic step
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
                                           "plastic", "broken", "shell"}
    stiff = [c for c in cases if c.category == "stiffness"]
    assert len(stiff) >= 7  # 6-8 decades at fixed geometry
    assert set(st.QUICK) <= set(names) and set(st.THRESHOLD_CASES) <= set(names)
    with pytest.raises(st.InputError, match="unknown stability case nope"):
        st.select(["nope"])


def test_forced_oversize_step_is_caught_and_flagged():
    """The classifier must see a blow-up: 16x the predicted bound (dt_bond here; 2.9 dx / c) is unstable, 1/2 of
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


def test_predicted_bound_is_the_one_the_step_uses():
    """dt_pred is the engine's own bound at safety factors 1, and the Plan names it: the bond bound binds on the
    block at rest (0.7 dt_bond = 0.127 dx / c < 0.4 dx / c) and on a cracking block at h = dx / 4."""
    for name in ("stiff_1e6", "crack_dx_4"):
        ready = st.prepare_case(st.select([name])[0])
        plan = ready.prep.plan
        assert plan.binding == "bonds" and ready.bound == "bonds", name
        assert plan.dt_max == pytest.approx(ready.prep.scene.simulation.bond_safety * ready.dt_pred), name


def test_threshold_is_within_2x_of_the_wave_bound():
    result = st.threshold(st.select(["stiff_1e6"])[0], bisections=3)
    print(f"\nstiff_1e6: stable up to {result['measured']:.3g} dt_pred, unstable at {result['unstable']:.3g}")
    assert result["bracketed"] and 0.5 <= result["wave_units"] <= 2.0  # within 2x of dx / c
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
    step. Against dx / c, bodies on the grid at rest fail within 2x (one, h = dx with horizon 3 h, at 2.08), and
    so do moving ones but the 10 dx/dt impact, which fails by distance; against dt_bond, the bound the step uses,
    3-16x; crack particles at 2.6 dt_bond whatever h / dx (docs/results.md, 'Stability')."""
    rows = [st.run_case(c) for c in st.cases()]
    assert len(rows) >= 60
    assert all(r["class"] in ("stable", "refused") for r in rows), [r["case"] for r in rows if r["class"] != "stable"]
    results = {n: st.threshold(c) for n, c in zip(st.THRESHOLD_CASES, st.select(st.THRESHOLD_CASES))}
    assert all(r["bracketed"] and r["margin"] > 3 for r in results.values()), results  # the automatic step is safe
    grid = {n: r for n, r in results.items() if not n.startswith("crack")}
    at_rest = [r for r in grid.values() if r["v0_cells"] < 0.1]
    assert len(at_rest) >= 13 and all(0.5 <= r["wave_units"] <= 2.1 and r["bond_units"] > 3 for r in at_rest), at_rest
    moving = [r for n, r in grid.items() if r["v0_cells"] >= 0.1 and n != "impact_floor_10"]
    assert all(0.5 <= r["wave_units"] <= 2.0 for r in moving), moving
    assert all(2.0 <= r["bond_units"] <= 3.0 for n, r in results.items() if n.startswith("crack")), results
    assert results["impact_floor_10"]["v0_cells"] > 10
    assert results["impact_floor_10"]["failure"] == "outside"
