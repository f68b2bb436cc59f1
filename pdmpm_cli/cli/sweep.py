"""`pdmpm sweep`: run a grid of scene variants on Dask distributed, with progress and a summary table."""

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from pdmpm_cli.cli.options import SceneArg, SetOpt

HIDDEN = ("folder", "particles", "frames", "message")  # in the summary files; messages are printed as they come


def sweep(
    scene: SceneArg,
    param: Annotated[list[str], typer.Option(
        "--param", "-p", help="KEY=V1,V2,...: values of one scene key, written as for --set (commas inside [] stay "
        "in a value); repeat for a grid of every combination.")] = [],
    variant: Annotated[list[str], typer.Option(
        "--variant", "-V", help="One of the scene's named variants; repeat for several (each combined with every "
        "--param combination).")] = [],
    set_: SetOpt = [],
    out: Annotated[Path, typer.Option(
        "--out", "-o", help="Parent folder: each variant runs in OUT/<scene stem>/<key=value,...>.")] = Path(
        "outputs/sweeps"),
    workers: Annotated[int | None, typer.Option(
        "--workers", "-w", min=1, help="Worker processes of the local cluster (default: one per core).",
        show_default=False)] = None,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", help="Address of a running Dask scheduler, e.g. tcp://host:8786, instead of a local cluster; "
        "its workers need pdmpm and the scene and output paths.", show_default=False)] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace the outputs of earlier runs.")] = False,
):
    """Run every combination of --param values (and --variant names) of SCENE on a Dask cluster, and write
    summary.csv and summary.md. Exit code 1 if any variant failed."""
    from pdmpm_cli.errors import InputError
    from pdmpm_cli.sweep import connect, expand, run_sweep, summary_rows, write_summary

    console = Console(stderr=True, highlight=False, emoji=False, soft_wrap=True)
    variants = expand(scene, param, variant, set_)
    base = out / scene.stem
    used = [v.name for v in variants if (base / v.name).is_dir() and any((base / v.name).iterdir())]
    if used and not overwrite:
        raise InputError(f"{base}: {len(used)} variant folders already hold outputs ({', '.join(used[:3])}"
                         f"{', ...' if len(used) > 3 else ''}); pass --overwrite to replace them, or choose --out")
    with connect(scheduler, workers) as client:
        n = len(client.scheduler_info()["workers"])
        console.print(f"{scene}: {len(variants)} variants on {n} workers "
                      f"({scheduler or 'local cluster'}) -> {base}")
        progress = Progress(TextColumn("[bold]variants"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                            console=console)
        task = progress.add_task("variants", total=len(variants))

        def done(v, row):
            mark = "[green]ok[/]" if row["status"] == "ok" else f"[red]{row['status']}[/]"
            detail = f": {escape(row['message'])}" if row["message"] else ""
            progress.console.print(f"{mark} {escape(v.name)} ({row['wall_s']:.1f} s){detail}")
            progress.advance(task)

        with progress:
            rows = run_sweep(client, scene, base, variants, overwrite, done)
    csv_path, md_path = write_summary(base, variants, rows)
    header, cells = summary_rows(variants, rows, digits=4)
    shown = [i for i, column in enumerate(header) if column not in HIDDEN]
    table = Table(title=f"{scene.stem}: {len(variants)} variants")
    for i in shown:
        table.add_column(escape(header[i]), overflow="fold")
    for row in cells:
        table.add_row(*(escape(row[i]) for i in shown))
    Console(highlight=False, emoji=False).print(table)
    failed = sum(row["status"] != "ok" for row in rows.values())
    console.print(f"summary: {csv_path}, {md_path}" + (f"; [red]{failed} failed[/]" if failed else ""))
    if failed:
        raise typer.Exit(1)
