"""`pdmpm` command line: one module per command, heavy imports inside the commands so --help is instant."""

import sys

import typer
from rich.console import Console

from pdmpm_cli.cli import render, run, scenes, schema, stability, study, sweep, validate
from pdmpm_cli.errors import PdmpmError

app = typer.Typer(
    name="pdmpm",
    help="Material Point Method with peridynamic bonds: scene YAML in, animation (HDF5, VTK) out.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.command("run")(run.run)
app.command("validate")(validate.validate)
app.command("schema")(schema.schema)
app.command("scenes")(scenes.scenes)
app.command("render")(render.render)
app.command("sweep")(sweep.sweep)
app.command("stability")(stability.stability)
app.command("study")(study.study)

err_console = Console(stderr=True, highlight=False)


def main():
    """Entry point: user-facing errors print one clear message and exit 2 (bad input) or 1 (failed run)."""
    try:
        app()
    except PdmpmError as e:
        err_console.print(f"[bold red]error:[/] {e}", soft_wrap=True)
        sys.exit(e.exit_code)
    except KeyboardInterrupt:
        err_console.print("[yellow]interrupted[/]: frames written so far are complete and readable")
        sys.exit(130)
