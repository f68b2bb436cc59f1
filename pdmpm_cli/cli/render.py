"""`pdmpm render`: PNG frames and a video of a finished run, offscreen, with a progress bar."""

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn


class RichBar:
    """Progress bar over the rendered frames; it appears once rendering starts, so errors print alone."""

    def __init__(self, console: Console):
        self.progress = Progress(TextColumn("[bold]render"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                                 TimeRemainingColumn(), console=console)
        self.task = None

    def __call__(self, done: int, total: int):
        if self.task is None:
            self.task = self.progress.add_task("frames", total=total)
            self.progress.start()
        self.progress.update(self.task, completed=done)

    def stop(self):
        if self.task is not None:
            self.progress.stop()


def render(
    outdir: Annotated[Path, typer.Argument(help="Output folder of `pdmpm run` (run.h5, or vtk/ and meshes/).",
                                           show_default=False)],
    field: Annotated[str | None, typer.Option(
        "--field", help="Colour by speed, damage, plastic or body (default: the scene's render.field, else speed).",
        show_default=False)] = None,
    frames: Annotated[str | None, typer.Option(
        "--frames", help="Frames to render as a python slice START:STOP[:STEP], e.g. 0:48:2 or -1 (default all).",
        show_default=False)] = None,
    resolution: Annotated[str | None, typer.Option(
        "--resolution", help="Image size WIDTHxHEIGHT in px (default: the scene's render.resolution, 1280x720).",
        show_default=False)] = None,
    camera: Annotated[str | None, typer.Option(
        "--camera", help="'px,py,pz;fx,fy,fz[;ux,uy,uz]': position; focus; up, in m (default: the scene's "
        "render.camera, else a 3/4 view of the particles).", show_default=False)] = None,
    fps: Annotated[float | None, typer.Option(
        "--fps", min=0.1, help="Frames per second of the video (default: the run's frame rate).",
        show_default=False)] = None,
    out: Annotated[Path | None, typer.Option(
        "--out", "-o", help="Folder for the PNG frames and the video (default: frames in OUTDIR/frames, the video in "
        "OUTDIR).", show_default=False)] = None,
    no_video: Annotated[bool, typer.Option("--no-video", help="Write only the PNG frames.")] = False,
):
    """Render OUTDIR's frames to OUTDIR/frames/frame_NNNNN.png and OUTDIR/animation.mp4 (or .gif without ffmpeg)."""
    from pdmpm_cli.render.options import parse_camera, parse_resolution
    from pdmpm_cli.render.run import render_run

    console = Console(stderr=True, highlight=False, emoji=False, soft_wrap=True)
    size = parse_resolution(resolution) if resolution else None
    view = parse_camera(camera) if camera else None
    bar = RichBar(console)
    try:
        result = render_run(outdir, field=field, frames=frames, resolution=size, camera=view, out=out, fps=fps,
                            video=not no_video, progress=bar)
    finally:
        bar.stop()
    console.print(f"done: {len(result.images)} frames in {result.images[0].parent} "
                  f"({result.seconds_per_frame:.2f} s per frame)" + (f"; video {result.video}" if result.video else ""))
