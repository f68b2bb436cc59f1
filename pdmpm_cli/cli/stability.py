"""`pdmpm stability`: the stability sweep, its classification table and the measured time-step
thresholds against the engine's predicted bound."""

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

COLUMNS = ("case", "category", "parameter", "class", "energy_ratio", "energy_end", "max_speed", "cells_per_step",
           "steps", "dt_ratio", "dt_pred", "dt_bond", "particles", "isolated", "forced", "dt_factor", "wall_s",
           "message")
THRESHOLD_COLUMNS = ("case", "category", "parameter", "bound", "dt_pred", "dt_grid", "dt_particles", "dt_tunnel",
                     "dt_bond", "dt_auto", "measured",
                     "unstable", "wave_units", "bond_units", "margin", "v0_cells", "failure", "within_2x", "runs")
COLOUR = {"stable": "green", "refused": "cyan"}


def fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.3g}"
    return "" if value is None else str(value)


def write_tables(path: Path, columns, rows):
    """path.csv and path.md (a Markdown table, for docs/results.md) with the given columns."""
    import csv

    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows({k: fmt(v) for k, v in row.items()} for row in rows)
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(row.get(k)).replace("|", "/") for k in columns) + " |" for row in rows]
    path.with_suffix(".md").write_text("\n".join(lines) + "\n")


def stability(
    case: Annotated[list[str], typer.Option(
        "--case", "-c", help="Run only this case (repeat for several); default all, or the --quick set.")] = [],
    quick: Annotated[bool, typer.Option(
        "--quick", help="A reduced set (12 cases, one threshold): seconds on one core once the kernels are compiled.")
    ] = False,
    thresholds: Annotated[bool, typer.Option(
        "--thresholds/--no-thresholds", help="Also bisect a forced dt for the largest stable step on the "
        "representative cases, against the predicted limit.")] = True,
    out: Annotated[Path, typer.Option(
        "--out", "-o", help="Folder for stability, thresholds and forced (every forced run) .csv / .md.")] = Path("outputs/stability"),
    list_: Annotated[bool, typer.Option("--list", help="List the cases and what each probes, and exit.")] = False,
):
    """Run the stability sweep with the automatic time step and classify each case (stable, nan, outside,
    energy, refused, error); then bisect forced oversize steps (flagged 'forced', never reachable from
    `pdmpm run`) for the measured threshold against the engine's predicted limit: 2 / omega_max of the grid
    operator, of the crack particles' while one holds a bond, and a collider's depth over the initial speed.
    Exit code 1 if any automatic-step case is unstable."""
    from pdmpm_cli import stability as st

    console = Console(stderr=True, highlight=False, emoji=False, soft_wrap=True)
    chosen = st.select(case, quick)
    if list_:
        table = Table(title=f"{len(chosen)} stability cases")
        for column in ("case", "category", "parameter", "probes"):
            table.add_column(column)
        for c in chosen:
            table.add_row(escape(c.name), c.category, escape(c.parameter), escape(c.probes))
        Console(highlight=False, emoji=False).print(table)
        return
    rows = []
    for c in chosen:
        row = st.run_case(c)
        rows.append(row)
        colour = COLOUR.get(row["class"], "red")
        console.print(f"[{colour}]{row['class']:>8}[/] {escape(c.name)} ({row['wall_s']:.1f} s)"
                      + (f": {escape(row['message'])}" if row.get("message") else ""))
    table = Table(title=f"stability sweep: {len(rows)} cases, automatic time step")
    shown = ("case", "category", "parameter", "class", "energy_ratio", "energy_end", "max_speed", "cells_per_step",
             "steps", "dt_ratio")
    for column in shown:
        table.add_column(column, overflow="fold")
    for row in rows:
        colour = COLOUR.get(row["class"], "red")
        table.add_row(*(f"[{colour}]{fmt(row.get(k))}[/]" if k == "class" else escape(fmt(row.get(k))) for k in shown))
    Console(highlight=False, emoji=False).print(table)
    write_tables(out / "stability", COLUMNS, rows)
    counts = {}
    for row in rows:
        counts[row["class"]] = counts.get(row["class"], 0) + 1
    console.print("classes: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
                  + f" -> {out / 'stability.csv'}")

    if thresholds:
        names = [n for n in (st.QUICK_THRESHOLD if quick and not case else st.THRESHOLD_CASES)
                 if not case or n in case]
        results, forced = [], []

        def on_run(row):
            forced.append(row)
            console.print(f"  forced {row['dt_factor']:.3g} x dt_pred: {row['class']}")

        for c in st.select(names):
            console.print(f"[bold]threshold[/] {escape(c.name)}: forced dt in [{st.LO:g}, {st.HI:g}] x dt_pred "
                          f"[yellow](oversize steps, on purpose)[/]")
            results.append(st.threshold(c, on_run=on_run))
        if results:
            write_tables(out / "forced", COLUMNS, forced)  # every forced run, flagged forced = True
            table = Table(title="time-step threshold: largest stable forced dt / predicted limit")
            for column in THRESHOLD_COLUMNS:
                table.add_column(column, overflow="fold")
            for r in results:
                table.add_row(*(escape(fmt(r[k])) for k in THRESHOLD_COLUMNS))
            Console(highlight=False, emoji=False).print(table)
            write_tables(out / "thresholds", THRESHOLD_COLUMNS, results)
            off = [r["case"] for r in results if not r["within_2x"]]
            console.print(f"thresholds -> {out / 'thresholds.csv'}"
                          + (f"; [yellow]not within 2x of the bound: {', '.join(off)}[/]" if off else
                             "; all within 2x of the predicted bound"))
    unstable = [r["case"] for r in rows if r["class"] not in ("stable", "refused")]
    if unstable:
        console.print(f"[red]{len(unstable)} automatic-step cases unstable[/]: {', '.join(unstable)}")
        raise typer.Exit(1)
