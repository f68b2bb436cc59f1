"""The colour field: which run field a --field reads, its values per frame and one range for all frames."""

from __future__ import annotations

import numpy as np

from pdmpm_cli.errors import InputError
from pdmpm_cli.render.source import Frame, RunSource

FIELDS = {
    "speed": ("particle_speed", "speed [m/s]"),
    "damage": ("particle_damage", "damage [-]"),
    "plastic": ("particle_plastic_strain", "plastic strain [-]"),
    "body": ("particle_body", "body"),
}



def check_field(source: RunSource, name: str) -> None:
    """InputError naming what is there and how to get the missing field."""
    available = [f for f, (run_name, _) in FIELDS.items() if f == "speed" or run_name in source.field_names]
    if name in available:
        return
    if name not in FIELDS:
        raise InputError(f"field {name!r}: unknown; choose one of {', '.join(FIELDS)}")
    run_name = FIELDS[name][0]
    note = {"damage": " (only bodies with `fracture` have damage)",
            "plastic": " (only `model: plastic` bodies have plastic strain)"}[name]
    raise InputError(f"field {name!r}: this run has no {run_name}{note}; available: {', '.join(available)}. "
                     f"Add {run_name} to output.fields in the scene and run it again")


def field_values(source: RunSource, name: str, frame: Frame) -> np.ndarray:
    """Per-particle values of --field `name`; speed falls back to |v|, then to the motion between frames."""
    if name == "body":
        return source.particle_body.astype(float)
    if name != "speed":
        return np.asarray(frame.fields[FIELDS[name][0]], dtype=float)
    if "particle_speed" in frame.fields:
        return np.asarray(frame.fields["particle_speed"], dtype=float)
    if "particle_v" in frame.fields:
        return np.linalg.norm(frame.fields["particle_v"], axis=1)
    if len(source) < 2:
        return np.zeros(len(frame.x))
    other = source.read(frame.index - 1 if frame.index > 0 else 1)
    return np.linalg.norm(frame.x - other.x, axis=1) / abs(frame.time - other.time)


def color_range(name: str, highs: list[float]) -> tuple[float, float]:
    """Fixed over all frames so the animation does not flicker; damage is 0..1 by definition."""
    if name == "damage":
        return 0.0, 1.0
    return 0.0, max(max(highs), 1e-9)


def survey(source: RunSource, indices: list[int], name: str) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Bounding box of the particles over the frames (for the camera) and each frame's colour maximum (the
    99.5th percentile: a few stray fast particles must not wash out the colours of the rest)."""
    lo, hi, highs = np.full(3, np.inf), np.full(3, -np.inf), []
    for i in indices:
        frame = source.read(i)
        lo, hi = np.minimum(lo, frame.x.min(axis=0)), np.maximum(hi, frame.x.max(axis=0))
        highs.append(float(np.percentile(field_values(source, name, frame), 99.5)))
    return lo, hi, highs
