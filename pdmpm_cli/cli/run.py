"""`pdmpm run`: simulate a scene and write HDF5 + VTK frames, with a progress bar."""

import time
from enum import Enum
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from pdmpm_cli.cli.options import SceneArg, SetOpt, VariantOpt


class Backend(str, Enum):
    cpu = "cpu"
    cuda = "cuda"


class RichReporter:
    """Progress bar: frames done, substeps, simulated time, ETA."""

    def __init__(self, console: Console):
        self.progress = Progress(
            TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
            TextColumn("{task.fields[info]}"), TimeElapsedColumn(), TimeRemainingColumn(),
            console=console, transient=False,
        )
        self.substeps = 0
        self.last = 0.0

    def start(self, plan):
        self.task = self.progress.add_task("frames", total=plan.frames, info="")
        self.progress.start()

    def substep(self, state, dt):
        self.substeps += 1
        now = time.monotonic()
        if now - self.last > 0.25:
            self.last = now
            self.progress.update(self.task, info=f"t={state.time:.4g}s steps={self.substeps} dt={dt:.2e}s")

    def frame(self, index, state):
        self.progress.update(self.task, completed=index,
                             info=f"t={state.time:.4g}s steps={self.substeps}")

    def stop(self):
        self.progress.stop()


def run(
    scene: SceneArg,
    set_: SetOpt = [],
    variant: VariantOpt = None,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Output folder (default outputs/<scene file stem>[-<variant>]).")] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace the outputs of an earlier run.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
    backend: Annotated[Backend | None, typer.Option(
        "--backend", help="Run the step on the cpu or on an NVIDIA GPU (cuda); overrides simulation.backend.",
        show_default=False)] = None,
):
    """Simulate SCENE and write run.h5 (all frames) and vtk/particles.pvd (ParaView) to the output folder."""
    from pdmpm_cli.runner import prepare, simulate

    console = Console(stderr=True, highlight=False, soft_wrap=True)
    overrides = [*set_, f"simulation.backend={backend.value}"] if backend else set_
    prep = prepare(scene, overrides, variant)
    for w in prep.plan.warnings():
        console.print(f"[yellow]warning:[/] {w}")
    out = out or Path("outputs") / (scene.stem if variant is None else f"{scene.stem}-{variant}")
    plan = prep.plan
    console.print(f"{prep.scene.name}: {plan.particles} particles, {plan.bonds} bonds, {plan.frames} frames, "
                  f"dt <= {plan.dt_max:.3g} s on {plan.backend} -> {out}")
    reporter = None if quiet else RichReporter(console)
    t0 = time.perf_counter()
    try:
        state = simulate(prep, out, reporter, overwrite=overwrite)
    finally:
        if reporter:
            reporter.stop()
    wall = time.perf_counter() - t0
    console.print(f"done: {state.step} steps in {wall:.1f} s "
                  f"({plan.particles * state.step / wall / 1e6:.2f} M particle-steps/s); outputs in {out}")
