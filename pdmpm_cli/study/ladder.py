"""Space and time ladders: run a problem or a scene file at several resolutions, measure each run's error and cost,
fit the orders, and write the CSV and the log-log plot.

The space ladder scales the grid cell size dx by a constant ratio; particle spacing and horizon follow (the
spacing stays the same fraction of the cell, the horizon the same multiple of the spacing), and so does dt, since
it is set by the CFL and bond bounds, both proportional to dx. The time ladder reruns the finest grid with
simulation.dt forced to dt/2, dt/4, ..., where dt is that run's largest step; each of its errors is the difference
from the run at the next smaller dt, which leaves the space error out. Wall time counts the stepping only (after a
warm-up run loads the compiled kernels), not the discretisation.
"""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Callable
from dataclasses import astuple, dataclass, fields
from pathlib import Path

import numpy as np

from pdmpm_cli.engine.state import State
from pdmpm_cli.engine.solver import Solver
from pdmpm_cli.errors import InputError
from pdmpm_cli.io.atomic import atomic_write_text
from pdmpm_cli.runner import Prepared, prepare, start_in_memory
from pdmpm_cli.scene.loader import load_scene, merge, parse_overrides
from pdmpm_cli.scene.schema import Scene
from pdmpm_cli.study.problems import Problem
from pdmpm_cli.study.sim import Sim


@dataclass
class Run:
    """One run of a ladder: its resolution, its cost and its error (a CSV row)."""

    ladder: str  # "space" or "time"
    level: int  # 0 = coarsest (space) or largest dt (time)
    cell_size_m: float
    spacing_m: float  # particle spacing h of the first body
    particles: int
    bonds: int  # directed bonds (each pair twice, as stored)
    steps: int
    dt_s: float  # mean step: simulated time / steps
    wall_s: float
    value: float  # the problem's quantity, or a scene's RMS displacement at the end [m]
    error: float  # NaN for the run the others are compared with
    reference: str


@dataclass
class Study:
    """A finished study: its runs and the fitted slopes of log(error) against log(h), log(dt) and log(wall time)."""

    name: str
    quantity: str
    runs: list[Run]

    def measured(self, ladder: str) -> list[Run]:
        """The ladder's runs with a positive error (the ones a log-log fit and plot can use)."""
        return [r for r in self.runs if r.ladder == ladder and np.isfinite(r.error) and r.error > 0]

    def slope(self, ladder: str, x: str) -> tuple[float, int]:
        """Least-squares slope of log(error) against log(x) ('h', 'dt' or 'wall') over the ladder's runs with a
        positive error, and how many runs that is (NaN below 2)."""
        rows = self.measured(ladder)
        if len(rows) < 2:
            return float("nan"), len(rows)
        xs = [{"h": r.cell_size_m, "dt": r.dt_s, "wall": r.wall_s}[x] for r in rows]
        return float(np.polyfit(np.log(xs), np.log([r.error for r in rows]), 1)[0]), len(rows)

    def slopes(self) -> dict[str, tuple[float, int]]:
        out = {"space: error ~ h^p": self.slope("space", "h"), "space: error ~ wall^q": self.slope("space", "wall")}
        if any(r.ladder == "time" for r in self.runs):
            out |= {"time: error ~ dt^p": self.slope("time", "dt"), "time: error ~ wall^q": self.slope("time", "wall")}
        return out


def cell_ladder(finest: float, ratio: float, levels: int) -> list[float]:
    """Cell sizes from the coarsest to `finest`, each `ratio` times the next."""
    return [finest * ratio ** (levels - 1 - k) for k in range(levels)]


OnRun = Callable[[Run], None]
# One run of a study: (ladder, level, input) -> (its row without the error, what it measured, its largest dt).
Execute = Callable[[str, int, object], tuple[Run, object, float]]


def _ladders(name: str, quantity: str, space: list, timed: Callable[[float], object] | None, time_levels: int,
             execute: Execute, error: Callable[[object, object | None], float], analytic: bool,
             on_run: OnRun | None) -> Study:
    """Run the space ladder (`space`, coarse to fine), then the time ladder on the last of them, `timed(dt)` for
    dt / 2 ... dt / 2^(time_levels - 1). Space errors are against the analytic value if `analytic`, else
    against the finest run; time errors against the next smaller dt."""
    report = on_run or (lambda run: None)
    runs, measured = [], []
    for level, item in enumerate(space):
        run, m, dt0 = execute("space", level, item)
        if analytic:
            run.error = error(m, None)
        runs.append(run)
        measured.append(m)
        report(run)
    if not analytic:
        for run, m in zip(runs[:-1], measured[:-1]):
            run.error = error(m, measured[-1])
    if timed is not None and time_levels >= 2:
        first = Run(**{**runs[-1].__dict__, "ladder": "time", "level": 0, "error": float("nan")})
        ladder = [(first, measured[-1])]
        for k in range(1, time_levels):
            run, m, _ = execute("time", k, timed(dt0 / 2**k))
            report(run)
            ladder.append((run, m))
        # Each against the next smaller dt: for an error c dt^p that difference is c (1 - 2^-p) dt^p, so the fitted
        # slope is p; against the smallest dt it would be biased upwards (log2 3 = 1.58 for p = 1 on 3 levels).
        for (run, m), (_, m_next) in zip(ladder[:-1], ladder[1:]):
            run.error, run.reference = error(m, m_next), "next smaller dt"
        ladder[-1][0].reference = "smallest dt"
        runs += [run for run, _ in ladder]
    return Study(name, quantity, runs)


def simulation_changes(overrides) -> dict:
    """`simulation.key=value` overrides as a scene dict (a built-in problem takes no other: its geometry is what
    its analytic value describes)."""
    changes = {}
    for keys, value in parse_overrides(list(overrides)):
        if len(keys) != 2 or keys[0] != "simulation" or keys[1] in ("duration", "fps", "dt"):
            raise InputError(f"a built-in problem takes --set simulation.<key>=value only (not duration, fps or "
                             f"dt, which the problem and its time ladder set); got {'.'.join(map(str, keys))}")
        changes[keys[1]] = value
    return {"simulation": changes} if changes else {}


def problem_study(problem: Problem, levels: int, time_levels: int, finest: float | None = None,
                  ratio: float | None = None, on_run: OnRun | None = None, overrides=()) -> Study:
    """A built-in problem: space ladder against its analytic value, time ladder on its finest grid; `overrides`
    (`simulation.key=value`, as --set) change every run's simulation section (the step rule, say)."""
    cells = cell_ladder(finest or problem.finest, ratio or problem.ratio, levels)
    changes = simulation_changes(overrides)

    def scene_of(cell: float) -> dict:
        return merge(problem.scene(cell), changes)

    warm = Sim(scene_of(cells[0]))
    _warm_up(warm.solver, warm.state)

    def execute(ladder, level, scene):
        sim = Sim(scene)
        t0 = time.perf_counter()
        m = problem.measure(sim)
        wall = time.perf_counter() - t0
        return _row(ladder, level, sim.prep, sim.state, wall, problem.summary(m),
                    "analytic: " + problem.reference_name), m, sim.plan.dt_max

    def timed(dt):
        scene = scene_of(cells[-1])
        return {**scene, "simulation": {**scene["simulation"], "dt": dt}}

    return _ladders(problem.name, problem.quantity, [scene_of(c) for c in cells], timed, time_levels, execute,
                    problem.error, True, on_run)


@dataclass
class Field:
    """The end of a scene run, for comparing runs at different resolutions: rest positions and displacements."""

    rest_x: np.ndarray
    u: np.ndarray
    body_ranges: list


def field_error(coarse: Field, fine: Field | None) -> float:
    """RMS over the coarse run's particles of |u_coarse - u_fine| at the fine particle with the nearest rest
    position in the same body, over the fine run's RMS displacement [-]."""
    from scipy.spatial import cKDTree

    diff = []
    for (cs, ce), (fs, fe) in zip(coarse.body_ranges, fine.body_ranges):
        _, j = cKDTree(fine.rest_x[fs:fe]).query(coarse.rest_x[cs:ce])
        diff.append(coarse.u[cs:ce] - fine.u[fs:fe][j])
    d = np.concatenate(diff)
    return float(np.sqrt((d**2).sum(axis=1).mean() / (fine.u**2).sum(axis=1).mean()))


def level_overrides(scene: Scene, factor: float) -> list[str]:
    """--set items that scale a scene's resolution by `factor` (cell size, explicit spacings, shell edges, a
    user dt); shell layers and Voronoi seed counts change so that the layered thickness and the seed density
    stay as they were."""
    out = [f"grid.cell_size={scene.grid.cell_size * factor!r}"]
    if scene.simulation.dt is not None:
        out.append(f"simulation.dt={scene.simulation.dt * factor!r}")
    for i, body in enumerate(scene.bodies):
        geo, key = body.geometry, f"bodies.{i}.geometry"
        if getattr(geo, "spacing", None) is not None:
            out.append(f"{key}.spacing={geo.spacing * factor!r}")
        if getattr(geo, "edge", None) is not None:
            out.append(f"{key}.edge={geo.edge * factor!r}")
        if geo.mode == "shell" and geo.layers > 1:
            out.append(f"{key}.layers={max(1, round(geo.layers / factor))}")
        if getattr(geo, "count", None) is not None:
            out.append(f"{key}.count={max(2, round(geo.count / factor**3))}")
    return out


def scene_study(path: Path, overrides=(), variant: str | None = None, levels: int = 4, time_levels: int = 0,
                finest: float | None = None, ratio: float = 2 ** 0.5, on_run: OnRun | None = None) -> Study:
    """A scene file: its own resolution (or `finest` cell size) is the finest level, coarser levels scale it by
    `ratio`; every error is the displacement field's against the finest run (space) or next smaller dt (time)."""
    scene, _ = load_scene(path, Scene, list(overrides), variant)
    base = scene.grid.cell_size
    cells = cell_ladder(finest or base, ratio, levels)
    preps = {c: prepare(path, [*overrides, *level_overrides(scene, c / base)], variant) for c in cells}
    state, solver = start_in_memory(preps[cells[0]])
    _warm_up(solver, state)

    def execute(ladder, level, prep: Prepared):
        state, wall = _run_scene(prep)
        m = Field(prep.model.rest_x, state.particle_x - prep.model.rest_x, prep.model.body_ranges)
        value = float(np.sqrt((m.u**2).sum(axis=1).mean()))
        return _row(ladder, level, prep, state, wall, value, "finest level"), m, prep.plan.dt_max

    def timed(dt):
        return prepare(path, [*overrides, *level_overrides(scene, cells[-1] / base), f"simulation.dt={dt!r}"],
                       variant)

    return _ladders(Path(path).stem, "RMS displacement [m]", [preps[c] for c in cells], timed, time_levels,
                    execute, field_error, False, on_run)


def _warm_up(solver: Solver, state: State):
    """A few steps, so that loading the compiled kernels is not timed with the first level."""
    solver.advance(state, state.time + 3 * solver.plan.dt_max)


def _run_scene(prep: Prepared) -> tuple[State, float]:
    """Step a prepared scene to its end in memory, frame by frame as the runner does; the stepping's wall time."""
    state, solver = start_in_memory(prep)
    t0 = time.perf_counter()
    for f in range(1, prep.plan.frames + 1):
        solver.advance(state, f * prep.plan.frame_dt)
    return state, time.perf_counter() - t0


def _row(ladder: str, level: int, prep: Prepared, state: State, wall: float, value: float, reference: str) -> Run:
    return Run(ladder, level, prep.scene.grid.cell_size, float(prep.disc.body_spacing[0]), prep.model.n_particles,
               len(prep.model.bond_nbr), state.step, state.time / max(state.step, 1), wall, value, float("nan"),
               reference)


# ---------------------------------------------------------------- outputs


def write_csv(path: Path, study: Study) -> Path:
    """One row per run, the columns of `Run`."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow([f.name for f in fields(Run)])
    for run in study.runs:
        writer.writerow([f"{v:.6g}" if isinstance(v, float) else v for v in astuple(run)])
    atomic_write_text(path, buf.getvalue())
    return path


def plot(path: Path, study: Study) -> Path:
    """Log-log error against wall time (both ladders), and against h (space) and dt (time), with the fitted
    slopes in the legends."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ladders = [lad for lad in ("space", "time") if any(r.ladder == lad and np.isfinite(r.error) for r in study.runs)]
    fig, axes = plt.subplots(1, 1 + len(ladders), figsize=(4.2 * (1 + len(ladders)), 3.4), dpi=80)
    for ladder, style in zip(ladders, ("o-", "s--")):
        rows = study.measured(ladder)
        q, _ = study.slope(ladder, "wall")
        against = {"space": "analytic" if rows[0].reference.startswith("analytic") else "finest", "time": "next dt"}
        axes[0].loglog([r.wall_s for r in rows], [r.error for r in rows], style,
                       label=f"{ladder} (vs {against[ladder]}): slope {q:.2f}")
    axes[0].set(xlabel="wall time [s]", ylabel="error [-]", title=f"{study.name}: error against run time")
    for ax, ladder in zip(axes[1:], ladders):
        x = "h" if ladder == "space" else "dt"
        rows = study.measured(ladder)
        xs, ys = [r.cell_size_m if x == "h" else r.dt_s for r in rows], [r.error for r in rows]
        p, _ = study.slope(ladder, x)
        ax.loglog(xs, ys, "o-" if x == "h" else "s--", label=f"slope {p:.2f}")
        ax.set(xlabel="cell size dx [m]" if x == "h" else "mean dt [s]", ylabel="error [-]", title=f"{ladder} ladder")
        ax.minorticks_off()  # ticks at the runs: a ladder often spans less than a decade
        ax.set_xticks(xs, [f"{v:.3g}" for v in xs])
        ax.set_yticks(ys, [f"{v:.3g}" for v in ys])
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
