"""The animation of the rendered frames: MP4 through imageio-ffmpeg, else an animated GIF."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np


def write_video(images: list[Path], folder: Path, fps: float) -> Path:
    """animation.mp4 when imageio and imageio-ffmpeg are installed, else animation.gif (pillow, which pyvista
    brings)."""
    if importlib.util.find_spec("imageio") is not None and importlib.util.find_spec("imageio_ffmpeg") is not None:
        import imageio.v2 as imageio

        path = folder / "animation.mp4"
        with imageio.get_writer(path, fps=fps, codec="libx264", quality=8) as writer:
            for image in images:
                writer.append_data(imageio.imread(image))
        return path
    from PIL import Image

    path = folder / "animation.gif"
    first, *rest = [Image.open(image).convert("RGB") for image in images]
    first.save(path, save_all=True, append_images=rest, duration=round(1000 / fps), loop=0)
    return path


def frame_rate(times: np.ndarray) -> float:
    return float(1 / np.median(np.diff(times))) if len(times) > 1 else 24.0
