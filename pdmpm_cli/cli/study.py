"""`pdmpm study`: error against run time over a ladder of resolutions, for a built-in problem or a scene file."""

import math
from pathlib import Path
from typing import Annotated

import typer
from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from pdmpm_cli.cli.options import SetOpt, VariantOpt

PROBLEM_NAMES = ("bar", "cantilever", "column", "free_fall")  # pdmpm_cli.study.problems.PROBLEMS (kept here: --help is instant)


def study(
    target: Annotated[str, typer.Argument(
        help=f"A built-in problem with an analytic answer ({', '.join(PROBLEM_NAMES)}) or a scene YAML file.",
        show_default=False)],
    levels: Annotated[int, typer.Option("--levels", "-n", min=2, help="Resolutions in the space ladder.")] = 4,
    ratio: Annotated[float | None, typer.Option(
        "--ratio", min=1.01, help="Ratio of successive cell sizes \\[-] (default: the problem's; sqrt(2) for a scene).",
        show_default=False)] = None,
    finest: Annotated[float | None, typer.Option(
        "--finest", min=0, help="Cell size of the finest level \\[m] (default: the problem's, or the scene's own).",
        show_default=False)] = None,
    time_levels: Annotated[int, typer.Option(
        "--time-levels", "-t", min=0, help="Runs in the time ladder on the finest grid, at dt, dt/2, dt/4, ... "
        "(dt: that grid's largest step \\[s]); 0 or 1 for none.")] = 3,
    set_: SetOpt = [],
    variant: VariantOpt = None,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Folder for study.csv and study.png (default outputs/study/<name>).",
        show_default=False)] = None,
):
    """Run TARGET over a ladder of cell sizes (particle spacing, horizon and dt follow) and over a ladder of time
    steps on the finest grid; print and write each run's error, wall time and particle, bond and step counts, and
    the fitted orders. Errors are against the analytic value (built-in problems, space ladder), the finest level
    (scene files: RMS displacement difference at the end) or the next smaller dt (time ladder)."""
    from pdmpm_cli.errors import InputError
    from pdmpm_cli.study.ladder import plot, problem_study, scene_study, write_csv
    from pdmpm_cli.study.problems import PROBLEMS

    console = Console(stderr=True, highlight=False, emoji=False, soft_wrap=True)

    def show(run):
        err = "pending" if math.isnan(run.error) else f"{run.error:.4g}"
        console.print(f"{run.ladder} {run.level}: dx {run.cell_size_m:.4g} m, {run.particles} particles, "
                      f"{run.steps} steps, {run.wall_s:.1f} s, error {err}")

    if target in PROBLEMS:
        if variant:
            raise InputError(f"--variant applies to scene files, not to the built-in problem {target!r}")
        problem = PROBLEMS[target]
        console.print(f"{target}: {problem.description}; reference {problem.reference_name}")
        result = problem_study(problem, levels, time_levels, finest, ratio, show, set_)
    else:
        path = Path(target)
        if path.suffix not in (".yaml", ".yml") and not path.is_file():
            raise InputError(f"{target!r} is neither a built-in problem ({', '.join(PROBLEMS)}) nor a scene file")
        result = scene_study(path, set_, variant, levels, time_levels, finest, ratio or 2**0.5, show)
    folder = out or Path("outputs/study") / result.name
    folder.mkdir(parents=True, exist_ok=True)
    csv_path, png_path = write_csv(folder / "study.csv", result), plot(folder / "study.png", result)

    table = Table(title=f"{escape(result.name)}: value = {escape(result.quantity)}", box=box.SIMPLE_HEAD)
    for column in ("ladder", "dx [m]", "particles", "steps", "dt [s]", "wall [s]", "value", "error"):
        table.add_column(escape(column), justify="left" if column == "ladder" else "right")
    for r in result.runs:
        table.add_row(f"{r.ladder} {r.level}", f"{r.cell_size_m:.4g}", str(r.particles), str(r.steps),
                      f"{r.dt_s:.3g}", f"{r.wall_s:.2f}", f"{r.value:.5g}",
                      "reference" if math.isnan(r.error) else f"{r.error:.3g}")
    Console(highlight=False, emoji=False).print(table)
    for name, (slope, n) in result.slopes().items():
        fit = f"{slope:.2f} (least squares over {n} runs)" if n >= 2 else f"needs 2 runs with an error, has {n}"
        Console(highlight=False, emoji=False).print(f"{name}: {fit}")
    console.print(f"wrote {csv_path}, {png_path}")
