"""`pdmpm` command line: one module per command, heavy imports inside the commands so --help is instant."""

import functools
import os
import signal
import sys

import typer
from rich.console import Console
from rich.markup import escape

from pdmpm_cli.cli import render, run, scenes, schema, signals, stability, study, sweep, validate
from pdmpm_cli.cli.signals import Terminated
from pdmpm_cli.errors import PdmpmError


class Stopped(Exception):
    """A command stopped by Ctrl-C or SIGTERM; typer would turn the KeyboardInterrupt into a silent exit 130."""

    def __init__(self, signum: int):
        self.signum = signum


def _stoppable(command):
    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except KeyboardInterrupt as stop:
            raise Stopped(signal.SIGTERM if isinstance(stop, Terminated) else signal.SIGINT) from None

    return wrapper


app = typer.Typer(
    name="pdmpm",
    help="Material Point Method with peridynamic bonds: scene YAML in, animation (HDF5, VTK) out.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.command("run")(_stoppable(run.run))
app.command("validate")(_stoppable(validate.validate))
app.command("schema")(_stoppable(schema.schema))
app.command("scenes")(_stoppable(scenes.scenes))
app.command("render")(_stoppable(render.render))
app.command("sweep")(_stoppable(sweep.sweep))
app.command("stability")(_stoppable(stability.stability))
app.command("study")(_stoppable(study.study))

err_console = Console(stderr=True, highlight=False, emoji=False)


def _exit(code: int):
    """Exit; without Python's and HDF5's clean-up when an HDF5 file was abandoned after an error inside the
    library (closing it would crash the process, see pdmpm_cli.io.hdf5)."""
    hdf5 = sys.modules.get("pdmpm_cli.io.hdf5")
    if hdf5 is not None and hdf5.abandoned():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


def main():
    """Entry point: user-facing errors print one clear message and exit 2 (bad input) or 1 (failed run);
    Ctrl-C and SIGTERM stop a run with its frames and checkpoints kept (exit 130 and 143)."""
    signals.install()  # (SIGXFSZ, sent past `ulimit -f`, is ignored by Python: such a write fails with EFBIG)
    try:
        app()
    except PdmpmError as e:
        err_console.print(f"[bold red]error:[/] {escape(str(e))}", soft_wrap=True)
        _exit(e.exit_code)
    except Stopped as e:
        what = "terminated (SIGTERM)" if e.signum == signal.SIGTERM else "interrupted"
        err_console.print(f"[yellow]{what}[/]: frames written so far are complete and readable")
        _exit(128 + e.signum)
