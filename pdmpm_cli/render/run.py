"""`render_run`: the frames of a run to PNGs and a video, with the scene's render settings as defaults."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pdmpm_cli.io.lock import check_folder
from pdmpm_cli.render.fields import check_field, color_range, field_values, survey
from pdmpm_cli.render.options import parse_frames, scene_settings
from pdmpm_cli.render.scene import RenderScene, auto_camera, color_style, font_size, up_direction
from pdmpm_cli.render.source import open_run
from pdmpm_cli.render.video import frame_rate, write_video
from pdmpm_cli.scene.schema import Camera


@dataclass
class RenderResult:
    images: list[Path]
    video: Path | None
    seconds_per_frame: float


def render_run(folder: Path, *, field: str | None = None, frames: str | None = None,
               resolution: tuple[int, int] | None = None, camera: Camera | None = None, out: Path | None = None,
               fps: float | None = None, video: bool = True,
               progress: Callable[[int, int], None] | None = None) -> RenderResult:
    """Render frames of the run in `folder` to PNGs in `out` (default `folder`/frames) and a video (in `out` when
    given, else in `folder`); arguments left None come from the scene's `render` section, then from the defaults.
    `progress(done, total)` is called before the first frame and after each one."""
    source = open_run(folder)
    settings = scene_settings(source)
    field = field or settings.field
    check_field(source, field)
    indices = parse_frames(frames, len(source))
    resolution = resolution or settings.resolution
    lo, hi, highs = survey(source, indices, field)
    camera = camera or settings.camera or auto_camera(lo, hi, up_direction(source.scene), resolution[0] / resolution[1])
    movies = Path(out) if out else Path(folder)
    out = Path(out) if out else Path(folder) / "frames"
    check_folder(out)
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.glob("frame_*.png"):  # a new render replaces the frames of an earlier one
        stale.unlink()
    color = color_style(source, field, color_range(field, highs), font_size(resolution))
    scene = RenderScene(source, resolution, camera, color, lo, hi)
    images, start = [], time.perf_counter()
    progress = progress or (lambda done, total: None)
    try:
        progress(0, len(indices))
        for done, i in enumerate(indices, 1):
            frame = source.read(i)
            images.append(out / f"frame_{i:05d}.png")
            scene.draw(frame, field_values(source, field, frame), images[-1])
            progress(done, len(indices))
    finally:
        scene.close()
    per_frame = (time.perf_counter() - start) / len(indices)
    movie = write_video(images, movies, fps or frame_rate(source.times)) if video else None
    return RenderResult(images, movie, per_frame)
