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
    """The classifier must see a blow-up: 4x the predicted bound is unstable, 1/2 of it is not."""
    case = st.select(["stiff_1e6"])[0]
    ready = st.prepare_case(case)
    big = st.run_case(case, 4.0, ready)
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


def test_bond_bound_limits_only_fracture_bodies():
    """Grid-integrated bodies take the CFL step (their measured threshold is 3-8x dt_bond); a fracture body keeps
    bond_safety dt_bond, since its crack particles integrate bonds off the grid (crack_dx_4 fails at 0.22 dx / c,
    below the CFL step)."""
    grid, crack = st.prepare_case(st.select(["stiff_1e6"])[0]), st.prepare_case(st.select(["crack_dx_4"])[0])
    assert grid.prep.plan.binding == "cfl" and grid.prep.plan.dt_bond == float("inf") and grid.bound == "cfl"
    plan = crack.prep.plan
    assert plan.binding == "bonds" and crack.bound == "bonds"
    assert plan.dt_max == pytest.approx(crack.prep.scene.simulation.bond_safety * crack.dt_pred)
    assert plan.dt_max < 0.25 * plan.cell_size / plan.wave_speed


def test_threshold_is_within_2x_of_the_predicted_bound():
    result = st.threshold(st.select(["stiff_1e6"])[0], bisections=3)
    print(f"\nstiff_1e6: stable up to {result['measured']:.3g} dt_pred, unstable at {result['unstable']:.3g}")
    assert result["bracketed"] and result["within_2x"]
    assert result["bond_units"] > 2  # the bond bound alone is conservative for a body on the grid


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
    step. Bodies on the grid at rest fail within 2x of dx / c (one, h = dx with horizon 3 h, at 2.07); moving
    ones within 2x of dx / c too, so 4-17x above dx / (c + v); crack particles at 2.6 dt_bond whatever h / dx
    (docs/results.md, 'Stability')."""
    rows = [st.run_case(c) for c in st.cases()]
    assert len(rows) >= 60
    assert all(r["class"] in ("stable", "refused") for r in rows), [r["case"] for r in rows if r["class"] != "stable"]
    results = {n: st.threshold(c) for n, c in zip(st.THRESHOLD_CASES, st.select(st.THRESHOLD_CASES))}
    assert all(r["bracketed"] and r["margin"] > 1.5 for r in results.values()), results  # the automatic step is safe
    at_rest = [r for r in results.values() if r["bound"] == "cfl" and r["v0_cells"] < 0.1]
    assert len(at_rest) >= 13 and all(0.5 <= r["wave_units"] <= 2.1 for r in at_rest), at_rest
    moving = [r for r in results.values() if r["bound"] == "cfl" and r["v0_cells"] >= 0.1]
    assert all(0.5 <= r["wave_units"] <= 2.0 and r["measured"] >= 1.0 for r in moving), moving
    assert all(2.0 <= r["bond_units"] <= 3.0 for n, r in results.items() if n.startswith("crack")), results
    assert results["impact_floor_10"]["failure"] == "outside"
