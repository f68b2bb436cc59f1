"""Checkpoints: the complete simulation state every `output.checkpoint_every` frames, so that
`pdmpm run --resume OUTDIR` continues a killed run and produces the frames an uninterrupted run would.

``OUTDIR/checkpoints/frame_NNNNN.h5`` (``format = "pdmpm-checkpoint"``, ``format_version = 4``)::

    /               attributes: format, format_version, frame, threads (Numba threads),
                      pdmpm_version, scene_path, overrides (JSON list of --set items), variant ("" for none),
                      scene_json (the validated scene less what a resume may change, see _binding),
                      model_sha256 (hash of the discretisation), precision (simulation.precision: the dtype
                      of the per-particle and per-bond float arrays),
                      state_<name> for each of the State's scalars (time, step, dt_prev, vmax, ...)
    /state/<name>   every allocated State array that is not transient (declared in engine.fields and by the
                    materials), including the CSR families, which viscoelastic bodies rebuild; an emitter's born
                    particles are in them (state_emitted layers: restore grows the Model and State to match)

The output thread writes a checkpoint after the frame it belongs to (so it never names a frame that is not on
disk), to a temporary file that is fsynced and renamed (io.atomic), and keeps the two newest: a kill while one is
written leaves the previous one. Stepping draws no random numbers (the seeded sampling RNG runs once, in
discretisation, and is checked through model_sha256), and everything that evolves lives in the State, so the State
is all a resumed run needs to continue bitwise identically with the same thread count. A finished run removes its
checkpoints.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numba
import numpy as np

from pdmpm_cli import __version__
from pdmpm_cli.engine.emitter import grow
from pdmpm_cli.engine.state import SCALARS, State
from pdmpm_cli.errors import InputError
from pdmpm_cli.io.atomic import atomic_path, fsync_file
from pdmpm_cli.io.hdf5 import reserved_file
from pdmpm_cli.io.vtk import frame_index

FORMAT = "pdmpm-checkpoint"
FORMAT_VERSION = 4  # 4: plastic bodies store bond_reverse (engine.materials.plastic)
FOLDER = "checkpoints"
KEEP = 2


@dataclass
class Checkpoint:
    """One checkpoint read back: its attributes and state arrays."""

    path: Path
    attrs: dict[str, Any]
    arrays: dict[str, np.ndarray]

    @property
    def frame(self) -> int:
        return self.attrs["frame"]

    @property
    def source(self) -> tuple[Path, list[str], str | None]:
        """The scene file, --set overrides and variant the run was started with."""
        return Path(self.attrs["scene_path"]), json.loads(self.attrs["overrides"]), self.attrs["variant"] or None


def header(prep) -> dict[str, Any]:
    """The attributes every checkpoint of a run shares: what a resumed run must match, and how it was started."""
    m = prep.model
    digest = hashlib.sha256()
    for array in (m.rest_x, m.particle_volume, m.particle_mass, m.particle_body, m.bond_start, m.bond_nbr):
        digest.update(np.ascontiguousarray(array).tobytes())
    return {
        "format": FORMAT, "format_version": FORMAT_VERSION, "pdmpm_version": __version__,
        "threads": numba.get_num_threads(),
        "scene_path": str(prep.path.resolve()), "overrides": json.dumps(list(prep.overrides)),
        "variant": prep.variant or "",
        "scene_json": json.dumps(_binding(prep.scene), sort_keys=True),
        "model_sha256": digest.hexdigest(), "precision": prep.scene.simulation.precision,
    }


def _binding(scene) -> dict:
    """The validated scene less what a resumed run may change: its description, render settings, variant
    definitions (the chosen one is applied in the values) and checkpoint interval."""
    data = scene.model_dump(mode="json", exclude={"description", "render", "variants"})
    del data["output"]["checkpoint_every"]
    return data


def snapshot(state: State) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Copies of the State's lasting arrays and its scalars, taken between frames while the solver goes on."""
    return ({name: array.copy() for name, array in state.lasting().items()},
            {f"state_{name}": value for name, value in state.scalars.items()})


def save(out: Path, frame: int, snap: tuple[dict, dict], head: dict[str, Any]) -> Path:
    """Write checkpoint `frame` atomically (after fsyncing run.h5, whose frames it relies on), then delete all
    but the KEEP newest."""
    if (out / "run.h5").is_file():
        fsync_file(out / "run.h5")
    folder = out / FOLDER
    folder.mkdir(exist_ok=True)
    path = folder / f"frame_{frame:05d}.h5"
    arrays, scalars = snap
    size = sum(a.nbytes for a in arrays.values()) + 2 * len(json.dumps(head | scalars, default=str))
    with atomic_path(path) as tmp:
        with reserved_file(tmp, size) as f:  # format 1.10, dense attributes: scene_json may exceed 64 KiB
            f.attrs.update(head | scalars | {"frame": frame})
            group = f.create_group("state")
            for name, array in arrays.items():
                group.create_dataset(name, data=array)
    for old in files(out)[:-KEEP]:
        old.unlink()
    return path


def files(out: Path) -> list[Path]:
    """The checkpoints in `out`, oldest first."""
    return sorted((out / FOLDER).glob("frame_*.h5"), key=lambda p: frame_index(p.name))


def remove(out: Path) -> None:
    """Delete the checkpoints of a finished run."""
    shutil.rmtree(out / FOLDER, ignore_errors=True)


def latest(out: Path) -> Checkpoint:
    """The newest checkpoint in `out`; InputError naming the file (and the older one to fall back on) if it is
    missing, truncated or corrupt."""
    if not out.is_dir():
        raise InputError(f"{out}: no such folder; give the output folder of an earlier `pdmpm run`")
    found = files(out)
    if not found:
        raise InputError(f"{out}: no checkpoint in {out / FOLDER}: the run stopped before its first one "
                         f"(output.checkpoint_every frames), or was not started with this pdmpm; start it again "
                         f"with --overwrite")
    path = found[-1]
    fallback = (f"delete it to resume from {found[-2].name}" if len(found) > 1 else
                "start the run again with --overwrite")
    try:
        with h5py.File(path, "r") as f:
            attrs = {k: v.item() if isinstance(v, np.generic) else v for k, v in f.attrs.items()}
            if attrs.get("format") != FORMAT or attrs.get("format_version") != FORMAT_VERSION:
                raise InputError(f"{path}: not a pdmpm checkpoint of format version {FORMAT_VERSION}; {fallback}")
            arrays = {name: dataset[()] for name, dataset in f["state"].items()}
            missing = [k for k in ("frame", "scene_json", *(f"state_{name}" for name in SCALARS)) if k not in attrs]
    except (OSError, KeyError, ValueError) as error:
        raise InputError(f"{path}: cannot read the checkpoint ({error}); it is truncated or corrupt: "
                         f"{fallback}") from error
    if missing:
        raise InputError(f"{path}: the checkpoint lacks {', '.join(missing)}; {fallback}")
    return Checkpoint(path, attrs, arrays)


def check(ckpt: Checkpoint, prep) -> None:
    """InputError unless `prep` is the scene (and discretisation) the checkpoint was written for."""
    mine = header(prep)
    theirs = ckpt.attrs.get("precision", "float64")
    if mine["precision"] != theirs:  # refused, not converted: the resumed frames would not be the run's
        raise InputError(f"{prep.path}: the run in {ckpt.path.parents[1]} was started with simulation.precision = "
                         f"{theirs} and its checkpoint holds {theirs} arrays; this scene asks for {mine['precision']}. "
                         f"Resume with --set simulation.precision={theirs}, or start a new run with --overwrite")
    if mine["scene_json"] != ckpt.attrs["scene_json"]:
        changes = _differences(json.loads(ckpt.attrs["scene_json"]), json.loads(mine["scene_json"]))
        raise InputError(f"{prep.path}: the scene differs from the one the run in {ckpt.path.parents[1]} was started "
                         f"with ({'; '.join(changes[:4])}); restore it to resume, or start a new run with --overwrite")
    if mine["model_sha256"] != ckpt.attrs["model_sha256"]:
        raise InputError(f"{prep.path}: the scene gives other particles or bonds than when the run in "
                         f"{ckpt.path.parents[1]} was started (a mesh file changed, or pdmpm samples differently since "
                         f"{ckpt.attrs['pdmpm_version']}); start a new run with --overwrite")


def _differences(old: Any, new: Any, key: str = "") -> list[str]:
    """'dotted.key: old -> new' for every leaf that differs."""
    if isinstance(old, dict) and isinstance(new, dict):
        return [d for k in sorted(old.keys() | new.keys(), key=str)
                for d in _differences(old.get(k), new.get(k), f"{key}.{k}" if key else str(k))]
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        return [d for i, (a, b) in enumerate(zip(old, new)) for d in _differences(a, b, f"{key}.{i}")]
    return [] if old == new else [f"{key}: {json.dumps(old)} -> {json.dumps(new)}"]


def restore(ckpt: Checkpoint, state: State, solver) -> None:
    """Overwrite a freshly started State with the checkpoint's, and bind the solver to it again (after growing the
    Model and State by the layers an emitter had born, so the shapes match)."""
    layers = int(ckpt.attrs.get("state_emitted", 0)) - state.emitted
    if layers > 0 and solver.model.emitter is not None:
        grow(solver, state, layers)
    expected = state.lasting()
    wrong = sorted(name for name in expected.keys() | ckpt.arrays.keys()
                   if name not in expected or name not in ckpt.arrays
                   or ckpt.arrays[name].dtype != expected[name].dtype
                   or (ckpt.arrays[name].shape != expected[name].shape and not name.startswith("bond_")))
    if wrong:
        raise InputError(f"{ckpt.path}: its state arrays {', '.join(wrong)} do not fit this scene (written by pdmpm "
                         f"{ckpt.attrs['pdmpm_version']}); start a new run with --overwrite")
    for name, array in ckpt.arrays.items():
        setattr(state, name, array)
    state.fit_transient_bonds()
    for name, default in SCALARS.items():
        setattr(state, name, type(default)(ckpt.attrs[f"state_{name}"]))
    solver.bind(state)
