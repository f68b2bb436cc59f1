"""`pdmpm study`: convergence orders on the verification problems, scene-file ladders, outputs."""

import csv
import math

import numpy as np
import pytest

from pdmpm_cli.scene.schema import Scene
from pdmpm_cli.study.ladder import Field, cell_ladder, field_error, level_overrides, plot, problem_study, write_csv
from pdmpm_cli.study.problems import BAR, CANTILEVER, COLUMN, FREE_FALL
from tests.test_cli import SMALL, pdmpm


def show(study):
    for r in study.runs:
        print(f"{r.ladder} {r.level}: dx {r.cell_size_m:.4g}, {r.particles} particles, {r.steps} steps, "
              f"{r.wall_s:.2f} s, value {r.value:.5g}, error {r.error:.4g}")
    for name, (slope, n) in study.slopes().items():
        print(f"{name}: {slope:.2f} ({n} runs)")


def test_bar_space_order_reduced(tmp_path):
    """Vibrating bar, dx = 2.5, 1.77, 1.25: the RMS error of v_com(t) over 1.5 periods falls about first order
    (measured 1.31; the full study, docs/results.md, measures the same). Band 0.8-2.0."""
    study = problem_study(BAR, levels=3, time_levels=0, finest=1.25, ratio=np.sqrt(2))
    show(study)
    errors = [r.error for r in study.runs]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] == pytest.approx(0.052, abs=0.01)  # 0.0522 measured at dx = 1.25
    p, n = study.slope("space", "h")
    assert n == 3 and 0.8 < p < 2.0
    q, n_wall = study.slope("space", "wall")  # error against run time: fitted, its value is the machine's timing
    assert n_wall == 3 and np.isfinite(q)
    csv_path, png_path = write_csv(tmp_path / "study.csv", study), plot(tmp_path / "study.png", study)
    rows = list(csv.DictReader(csv_path.open()))
    assert [r["ladder"] for r in rows] == ["space"] * 3
    assert int(rows[2]["particles"]) > int(rows[0]["particles"]) and int(rows[2]["bonds"]) > 0
    assert float(rows[2]["error"]) == pytest.approx(errors[2], rel=1e-5)
    assert png_path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png_path.stat().st_size < 200_000


def test_cantilever_space_order_reduced():
    """Cloud cantilever L/H = 5, 4, 5 and 6 particles through the thickness, explicit run after 1.5 periods: the tip
    deflection's error against Timoshenko is 0.098, 0.111, 0.092 (measured). With the jittered cloud it fell 0.24,
    0.117, 0.078 (order 2.8), but that was the jittered cloud's softness shrinking with h; with the relaxed
    sampling the error left is the explicit run's creep towards rest (the rest state sags 1.012 of
    Euler-Bernoulli, 0.973 of Timoshenko, at 6 particles), about the same at every level: no order to fit."""
    study = problem_study(CANTILEVER, levels=3, time_levels=0, finest=0.1 / 3, ratio=1.25)
    show(study)
    errors = [r.error for r in study.runs]
    assert [round(0.2 / r.cell_size_m) for r in study.runs] == [4, 5, 6]
    assert max(errors) < 0.13
    assert errors[2] == pytest.approx(0.092, abs=0.02)


def test_column_space_order_reduced():
    """Self-weight column, dx = H0 / 5.7, H0 / 8, H0 / 11.3: the top settles 14 %, 10 %, 5.5 % further than
    rho g H0^2 / (2 M) (measured), about first order (1.4; published MPM: first order, boundary dominated)."""
    study = problem_study(COLUMN, levels=3, time_levels=0, finest=0.125 / np.sqrt(2), ratio=np.sqrt(2))
    show(study)
    errors = [r.error for r in study.runs]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] == pytest.approx(0.055, abs=0.015)
    assert 0.8 < study.slope("space", "h")[0] < 2.5


def test_column_on_a_lattice_stays_where_it_settled():
    """An elastic column under its own weight, its motion damped out, is in static equilibrium: it must stay put.
    On a lattice (every family symmetric: no particle-scale force under a smooth strain) the top moves by less
    than 5e-4 of its settlement from 3 to 9 periods (measured: 1e-4). Irregular clouds creep instead
    (bench/column_creep.py, dx = H0 / 11.3: the jittered column's top settles 7.4 % -> 9.3 % past the exact value
    over the same periods, relaxed 1.6 % -> 1.9 %; docs/results.md, 'Self-weight column')."""
    from pdmpm_cli.study.problems import COLUMN_H, COLUMN_M, COLUMN_SETTLE, RHO, column_scene
    from pdmpm_cli.study.sim import Sim

    d = column_scene(0.125, 9.0)
    d["bodies"][0]["geometry"]["sampling"] = "lattice"
    sim = Sim(d)
    period = 4 * COLUMN_H / np.sqrt(COLUMN_M / RHO)
    top = sim.model.rest_x[:, 1] > sim.model.rest_x[:, 1].max() - 0.6 * 0.125
    settled = []
    for periods in (3.0, 9.0):
        sim.advance(periods * period)
        settled.append(float(sim.model.rest_x[top, 1].mean() - sim.state.particle_x[top, 1].mean()))
    print(f"top settlement at 3 and 9 periods: {settled[0]:.6e}, {settled[1]:.6e} m (exact {COLUMN_SETTLE:.6e})")
    assert settled[0] == pytest.approx(COLUMN_SETTLE, rel=0.15)
    assert abs(settled[1] - settled[0]) < 5e-4 * settled[0]


def test_free_fall_is_exact_at_every_step_and_resolution():
    """A falling ball has no space error, and the leapfrog's drop has no time error (Solver.substep: symplectic
    Euler's first whole kick dropped it g t dt / 2 too far, a first-order time ladder): every run of both ladders
    falls g t^2 / 2 to round-off, whatever its cell and step."""
    study = problem_study(FREE_FALL, levels=2, time_levels=3, finest=0.05, ratio=2.0)
    show(study)
    time_rows = [r for r in study.runs if r.ladder == "time"]
    assert time_rows[1].steps > 1.9 * time_rows[0].steps
    assert math.isnan(time_rows[-1].error)
    assert max(r.error for r in study.runs if not math.isnan(r.error)) < 1e-10


def test_problem_study_takes_simulation_overrides():
    """--set simulation.step=auto on a built-in problem: the CFL step (0.25 dx / c) replaces the bond bound at every
    level, so the free fall takes fewer steps (and, its drop being exact at any step, falls as far)."""
    kw = dict(levels=2, time_levels=0, finest=0.05, ratio=2.0)
    conservative = problem_study(FREE_FALL, **kw)
    auto = problem_study(FREE_FALL, **kw, overrides=["simulation.step=auto"])
    for c, a in zip(conservative.runs, auto.runs):
        assert a.steps < 0.8 * c.steps and a.error < 1e-10


def test_field_error_matches_particles_by_rest_position():
    rng = np.random.default_rng(0)
    fine_x = rng.uniform(0, 1, (2000, 3))
    fine = Field(fine_x, np.tile([0.0, -0.1, 0.0], (2000, 1)), [(0, 2000)])
    coarse_x = fine_x[::7] + 1e-4
    same = Field(coarse_x, np.tile([0.0, -0.1, 0.0], (len(coarse_x), 1)), [(0, len(coarse_x))])
    assert field_error(same, fine) == pytest.approx(0.0, abs=1e-12)
    off = Field(coarse_x, np.tile([0.0, -0.11, 0.0], (len(coarse_x), 1)), [(0, len(coarse_x))])
    assert field_error(off, fine) == pytest.approx(0.1, rel=1e-9)


def test_level_overrides_scale_every_length_of_the_resolution():
    scene = Scene.model_validate({
        "simulation": {"duration": 0.1, "dt": 1e-4},
        "grid": {"cell_size": 0.02, "domain": {"min": [0, 0, 0], "max": [1, 1, 1]}},
        "bodies": [
            {"name": "board", "geometry": {"mode": "shell", "spacing": 0.01, "layers": 4, "edge": 0.02,
                                           "surface": {"type": "box", "center": [0.5, 0.5, 0.5],
                                                       "size": [0.3, 0.3, 0.1]}},
             "material": {"model": "elastic", "density": 1000, "lam": 1e5, "mu": 1e5}},
            {"name": "wall", "geometry": {"mode": "voronoi", "count": 800,
                                          "shape": {"type": "box", "center": [0.5, 0.2, 0.5], "size": [0.2] * 3}},
             "material": {"model": "elastic", "density": 1000, "lam": 1e5, "mu": 1e5}},
            {"name": "cube", "geometry": {"mode": "cloud",
                                          "shape": {"type": "box", "center": [0.5, 0.8, 0.5], "size": [0.2] * 3}},
             "material": {"model": "elastic", "density": 1000, "lam": 1e5, "mu": 1e5}}]})
    assert level_overrides(scene, 2.0) == [
        "grid.cell_size=0.04", "simulation.dt=0.0002", "bodies.0.geometry.spacing=0.02",
        "bodies.0.geometry.edge=0.04", "bodies.0.geometry.layers=2", "bodies.1.geometry.count=100"]
    assert cell_ladder(0.01, 2.0, 3) == [0.04, 0.02, 0.01]


def test_study_command_on_a_scene_file(tmp_path):
    """A scene-file study through the CLI: two levels of a small drop, the table, the slope, the CSV and PNG."""
    out, scene = tmp_path / "study", tmp_path / "drop.yaml"
    scene.write_text(SMALL.replace("min: [0, 0, 0], max: [0.8, 0.8, 0.8]", "min: [-0.2, 0, -0.2], max: [1.0, 1.0, 1.0]")
                     .replace("center: [0.4, 0.45, 0.4]", "center: [0.4, 0.5, 0.4]"))
    r = pdmpm("study", scene, "--levels", "2", "--ratio", "1.5", "--time-levels", "2", "--set",
              "grid.cell_size=0.05", "--set", "simulation.duration=0.15", "--out", out)
    print(r.stdout, r.stderr)
    assert r.returncode == 0, r.stderr
    assert "space: error ~ h^p" in r.stdout and "time: error ~ dt^p" in r.stdout
    rows = list(csv.DictReader((out / "study.csv").open()))
    assert [(r["ladder"], r["level"]) for r in rows] == [("space", "0"), ("space", "1"), ("time", "0"), ("time", "1")]
    assert float(rows[0]["cell_size_m"]) == pytest.approx(0.075) and float(rows[1]["cell_size_m"]) == 0.05
    assert 0 < float(rows[0]["error"]) < 1 and rows[1]["error"] == "nan"
    assert int(rows[3]["steps"]) > 1.9 * int(rows[2]["steps"])  # dt/2 (the CFL bound moves with the speed)
    assert (out / "study.png").stat().st_size > 1000


def test_study_command_exit_codes(tmp_path):
    """2 for bad input (unknown problem, invalid scene, --set on a built-in problem), 1 for a failed run."""
    r = pdmpm("study", "vibrating_string")
    assert r.returncode == 2
    assert "'vibrating_string' is neither a built-in problem (bar, cantilever, column, free_fall) nor a scene file" in r.stderr
    bad = tmp_path / "bad.yaml"
    bad.write_text("simulation: {duration: -1}\n")
    r = pdmpm("study", bad, "--levels", "2")
    assert r.returncode == 2 and "simulation.duration" in r.stderr
    r = pdmpm("study", "bar", "--set", "grid.cell_size=1")
    assert r.returncode == 2 and "built-in problem takes --set simulation.<key>=value only" in r.stderr
    thrown = tmp_path / "thrown.yaml"
    thrown.write_text(SMALL.replace("material: {model: elastic", "velocity: [0, 40, 0]\n    material: {model: elastic"))
    r = pdmpm("study", thrown, "--levels", "2", "--ratio", "1.1", "--time-levels", "0", "--out", tmp_path / "out")
    assert r.returncode == 1 and "left the simulation domain" in r.stderr


@pytest.mark.slow
@pytest.mark.parametrize("name", ["bar", "cantilever"])
def test_full_study(name, tmp_path):
    """The studies in docs/results.md (bar: 4 levels, 4 time levels, 108 s; cantilever: 4 levels, 3 time
    levels, about 10 min). Space orders measured 1.17 (bar) and 2.14 (cantilever). Neither converges in dt at
    fixed dx (measured orders 0.02 and -0.01: each halving of dt changes the result by the same amount,
    docs/results.md); the last assertion guards that present state, and should fail once the per-step effect is
    fixed."""
    problem = {"bar": BAR, "cantilever": CANTILEVER}[name]
    study = problem_study(problem, levels=4, time_levels=4 if name == "bar" else 3)
    show(study)
    p, n = study.slope("space", "h")
    assert n == 4 and (0.8 < p < 2.0 if name == "bar" else 1.5 < p < 3.0)
    assert abs(study.slope("time", "dt")[0]) < 0.3
    write_csv(tmp_path / "study.csv", study)
    assert plot(tmp_path / "study.png", study).stat().st_size > 1000
