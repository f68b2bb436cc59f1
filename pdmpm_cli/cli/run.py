"""`pdmpm run`: simulate a scene and write HDF5 + VTK frames, with a progress bar."""

import time
from enum import Enum
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from pdmpm_cli.cli import signals
from pdmpm_cli.cli.options import SetOpt, VariantOpt


class Backend(str, Enum):
    cpu = "cpu"
    cuda = "cuda"


class QuietReporter:
    """No output; a Ctrl-C or SIGTERM stops the run between two substeps (pdmpm_cli.cli.signals)."""

    def start(self, plan, frame):
        pass

    def substep(self, state, dt):
        signals.check()

    def frame(self, index, state):
        pass

    def stop(self):
        pass


class RichReporter(QuietReporter):
    """Progress bar: frames done, substeps, simulated time, ETA."""

    def __init__(self, console: Console):
        self.progress = Progress(
            TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
            TextColumn("{task.fields[info]}"), TimeElapsedColumn(), TimeRemainingColumn(),
            console=console, transient=False,
        )
        self.last = 0.0

    def start(self, plan, frame):
        self.task = self.progress.add_task("frames", total=plan.frames, completed=frame, info="")
        self.progress.start()

    def substep(self, state, dt):
        signals.check()
        now = time.monotonic()
        if now - self.last > 0.25:
            self.last = now
            self.progress.update(self.task, info=f"t={state.time:.4g}s steps={state.step} dt={dt:.2e}s")

    def frame(self, index, state):
        self.progress.update(self.task, completed=index, info=f"t={state.time:.4g}s steps={state.step}")

    def stop(self):
        self.progress.stop()


def run(
    scene: Annotated[Path | None, typer.Argument(
        help="Scene YAML file (with --resume: optional, the run's own by default).", show_default=False)] = None,
    set_: SetOpt = [],
    variant: VariantOpt = None,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Output folder (default outputs/<scene file stem>[-<variant>]).")] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace the outputs of an earlier run.")] = False,
    resume: Annotated[Path | None, typer.Option(
        "--resume", help="Continue the run in this output folder from its newest checkpoint. Without SCENE it uses "
        "the scene file, --set and --variant the run was started with; with them, they must give the same scene.",
        show_default=False)] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
    backend: Annotated[Backend | None, typer.Option(
        "--backend", help="Run the step on the cpu or on an NVIDIA GPU (cuda); overrides simulation.backend.",
        show_default=False)] = None,
):
    """Simulate SCENE and write run.h5 (all frames) and vtk/particles.pvd (ParaView) to the output folder;
    --resume OUTDIR continues a killed run from its newest checkpoint."""
    import numba

    from pdmpm_cli.errors import InputError, OutputError
    from pdmpm_cli.io.lock import check_folder, check_free
    from pdmpm_cli.scene.loader import load_scene
    from pdmpm_cli.scene.schema import Scene

    console = Console(stderr=True, highlight=False, emoji=False, soft_wrap=True)
    overrides = [*set_, f"simulation.backend={backend.value}"] if backend else set_
    if resume is not None:
        if overwrite or (out is not None and out.resolve() != resume.resolve()):
            raise InputError("--resume continues the run in its own folder: leave out --overwrite and --out")
        if scene is None and (overrides or variant):
            raise InputError("--set, --variant and --backend apply to a SCENE: with --resume give the scene file too, "
                             "or leave them out to use the run's own")
        out = resume
    elif scene is None:
        raise InputError("missing SCENE: give a scene file (pdmpm run scene.yaml), or --resume OUTDIR")
    else:
        out = out or Path("outputs") / (scene.stem if variant is None else f"{scene.stem}-{variant}")
    check_folder(out)
    if scene is not None:
        load_scene(scene, Scene, overrides, variant)  # bad input is refused before the engine loads

    from pdmpm_cli import budget
    from pdmpm_cli.runner import prepare, prepare_resume, simulate

    ckpt = None
    if resume is not None:
        check_free(out)  # a run writing there now is named before anything about resuming is said
        prep, ckpt = prepare_resume(resume, scene, overrides, variant)
    else:
        prep = prepare(scene, overrides, variant)
    plan = prep.plan
    for w in [*plan.warnings(), *budget.warnings(prep)]:
        console.print(f"[yellow]warning:[/] {escape(w)}")
    budget.check_output(prep, out, plan.frames - (ckpt.frame if ckpt else -1), reclaim=overwrite)
    born = f" + {plan.emitted} emitted" if plan.emitted else ""
    console.print(f"{escape(prep.scene.name)}: {plan.particles} particles{born}, {plan.bonds} bonds, {plan.frames} "
                  f"frames, dt <= {plan.dt_max:.3g} s on {plan.backend} -> {escape(str(out))}")
    if ckpt is not None:
        console.print(f"resuming from frame {ckpt.frame} (t = {ckpt.attrs['state_time']:.6g} s, "
                      f"step {ckpt.attrs['state_step']}); frames after it are written again")
        if ckpt.attrs["threads"] != numba.get_num_threads():
            console.print(f"[yellow]warning:[/] the run started with {ckpt.attrs['threads']} Numba threads, this one "
                          f"has {numba.get_num_threads()}: the frames will differ from an uninterrupted run in the "
                          f"last bits (set NUMBA_NUM_THREADS={ckpt.attrs['threads']} for identical ones)")
    reporter = QuietReporter() if quiet else RichReporter(console)
    first_step = ckpt.attrs["state_step"] if ckpt else 0
    t0 = time.perf_counter()
    try:
        with signals.polling():
            state = simulate(prep, out, reporter, overwrite=overwrite, resume=ckpt)
    except KeyboardInterrupt:
        if (out / "checkpoints").is_dir():
            console.print(f"continue it with: pdmpm run --resume {escape(str(out))}")
        raise
    except OutputError as error:
        from pdmpm_cli.io.hdf5 import abandoned

        kept = ("run.h5 is left as HDF5 had it and may not open" if abandoned() else
                "the frames written before are complete and readable")
        resumable = (out / "checkpoints").is_dir() and not abandoned()
        then = (f"once there is room, continue it with: pdmpm run --resume {out}" if resumable
                else "once there is room, start it again with --overwrite")
        raise OutputError(f"{error}; {kept}; {then}") from error
    finally:
        reporter.stop()
    wall = time.perf_counter() - t0
    steps = state.step - first_step
    console.print(f"done: {steps} steps in {wall:.1f} s "
                  f"({plan.particles * steps / wall / 1e6:.2f} M particle-steps/s); outputs in {escape(str(out))}")
