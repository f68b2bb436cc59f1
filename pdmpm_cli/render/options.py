"""The options of `pdmpm render` (frames, resolution, camera) and the scene's `render` section."""

from __future__ import annotations

import re

from pydantic import ValidationError

from pdmpm_cli.errors import InputError
from pdmpm_cli.render.source import RunSource
from pdmpm_cli.scene.schema import Camera, RenderSettings


def parse_frames(text: str | None, n: int) -> list[int]:
    """Frame indices from a python-style slice 'START:STOP[:STEP]' (or one index); None: all frames."""
    if text is None:
        return list(range(n))
    try:
        parts = [int(p) if p.strip() else None for p in text.split(":")]
        if len(parts) > 3:
            raise ValueError
        chosen = slice(*parts) if len(parts) > 1 else slice(parts[0], parts[0] + 1 or None)
        indices = list(range(n))[chosen]
    except (ValueError, TypeError):
        raise InputError(f"--frames {text!r}: expected START:STOP[:STEP] like python slicing, e.g. 0:100:2 or -1")
    if not indices:
        raise InputError(f"--frames {text!r} selects no frame: the run has {n} frames (0 to {n - 1})")
    return indices


def parse_resolution(text: str) -> tuple[int, int]:
    """'1280x720' -> (1280, 720)."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    try:
        return RenderSettings(resolution=(int(match[1]), int(match[2]))).resolution  # the schema's size check
    except (TypeError, ValidationError):  # no match, or too small
        raise InputError(f"--resolution {text!r}: expected WIDTHxHEIGHT in pixels, each >= 16, e.g. 1280x720") from None


def parse_camera(text: str) -> Camera:
    """'px,py,pz;fx,fy,fz[;ux,uy,uz]' (position; focus; up) in metres -> Camera."""
    try:
        vectors = [tuple(float(c) for c in part.split(",")) for part in text.split(";")]
        if len(vectors) not in (2, 3) or any(len(v) != 3 for v in vectors):
            raise ValueError
    except ValueError:
        raise InputError(f"--camera {text!r}: expected 'px,py,pz;fx,fy,fz[;ux,uy,uz]' (position; focus; up) in m, "
                         f"e.g. '1.5,1.2,2.5;0.5,0.4,0.5'") from None
    try:
        return Camera(**dict(zip(("position", "focus", "up"), vectors)))
    except ValidationError as error:  # not finite, or no direction to look in (the schema's checks)
        reason = "; ".join(e["msg"].removeprefix("Value error, ") for e in error.errors(include_url=False))
        raise InputError(f"--camera {text!r}: {reason}") from None


def scene_settings(source: RunSource) -> RenderSettings:
    """The scene's `render` section (defaults when absent or when only the VTK series is there)."""
    try:
        return RenderSettings.model_validate(source.scene.get("render") or {})
    except ValidationError as error:
        reason = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg'].removeprefix('Value error, ')}"
                           for e in error.errors(include_url=False))
        raise InputError(f"{source.folder}: the scene's render section is invalid ({reason}); give --camera, "
                         f"--field or --resolution instead") from None
