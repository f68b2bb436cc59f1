"""Scene file -> Plan -> Model/State -> frames on disk. The CLI's `run`, `validate` and `sweep` call this."""

import dataclasses
import functools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from pdmpm_cli import budget, checkpoint
from pdmpm_cli.assemble import build_model
from pdmpm_cli.discretize import Discretization, check_sizes, discretize, keyed
from pdmpm_cli.engine.embedding import mesh_positions
from pdmpm_cli.engine.materials import MATERIALS
from pdmpm_cli.engine.model import Model
from pdmpm_cli.engine.plan import Plan
from pdmpm_cli.engine.solver import Solver, initial_state
from pdmpm_cli.engine.state import State
from pdmpm_cli.engine.transfer import WALL
from pdmpm_cli.errors import InputError, SceneValueError
from pdmpm_cli.io.lock import LOCK_NAME, OutputLock
from pdmpm_cli.io.surface import FluidBody, FluidSurfaces, FluidSurfaceWriter
from pdmpm_cli.plan import make_plan
from pdmpm_cli.scene.loader import load_scene, locate
from pdmpm_cli.scene.schema import Scene


@dataclass
class Prepared:
    """Everything known before the first step."""

    path: Path
    scene: Scene
    text: str
    disc: Discretization
    model: Model
    plan: Plan
    overrides: tuple[str, ...] = ()  # the --set items and variant it was loaded with (checkpoints record them)
    variant: str | None = None


def prepare(path, overrides=(), variant: str | None = None) -> Prepared:
    """Load and validate the scene file (with one of its variants), discretise it, and make the Plan."""
    path = Path(path)
    scene, text = load_scene(path, Scene, list(overrides), variant)
    try:
        prep = prepare_scene(scene, path, text)
    except SceneValueError as e:  # a broken mesh file, a body larger than the domain: point at the scene's line
        raise locate(e, path, text, overrides, variant) from None
    return dataclasses.replace(prep, overrides=tuple(overrides), variant=variant)


def prepare_resume(out: Path, scene=None, overrides=(), variant: str | None = None
                   ) -> tuple[Prepared, checkpoint.Checkpoint]:
    """The run in `out` and its newest checkpoint. Without `scene`, the scene file, overrides and variant the run
    was started with; with one, those given. Either way the scene must still be the one the run started with."""
    if not checkpoint.files(out) and run_complete(out):
        raise InputError(f"{out}: the run is complete (its checkpoints are removed at the end); nothing to resume")
    ckpt = checkpoint.latest(out)
    if scene is None:
        scene, overrides, variant = ckpt.source
        if not scene.is_file():
            raise InputError(f"{out}: the run's scene file {scene} is gone; give it: pdmpm run SCENE --resume {out}")
    prep = prepare(scene, overrides, variant)
    checkpoint.check(ckpt, prep)
    return prep, ckpt


def prepare_scene(scene: Scene, path: Path, text: str = "") -> Prepared:
    """Discretise a validated scene (relative mesh paths resolve beside `path`) and make the Plan; a scene whose
    estimated memory exceeds what the machine has free is refused before sampling."""
    base = Path(path).parent
    try:  # sizes first: a body too large for the domain is named as such, not as a memory estimate
        check_sizes(scene, base)
        budget.check_memory(scene, base, str(path))
    except SceneValueError as e:
        raise keyed(e, scene) from None
    disc = discretize(scene, base)
    model = build_model(scene, disc)
    return Prepared(Path(path), scene, text, disc, model, make_plan(scene, disc, model))


def run_complete(out: Path) -> bool:
    """Whether `out` holds a run.h5 with every frame of its plan."""
    from pdmpm_cli.io.hdf5 import read_run

    try:
        run = read_run(out / "run.h5")
    except InputError:
        return False
    return len(run) == run.plan["frames"] + 1


class Reporter(Protocol):
    """Receives progress; the CLI implements it with rich. Library code prints nothing."""

    def start(self, plan: Plan, frame: int) -> None: ...  # frame: where the run starts (a checkpoint's on resume)
    def substep(self, state: State, dt: float) -> None: ...
    def frame(self, index: int, state: State) -> None: ...


def start_in_memory(prep: Prepared) -> tuple[State, Solver]:
    """A fresh State and a started Solver on the Plan's backend, for a prepared scene stepped from code (studies,
    the stability sweep, `validate --limits`) rather than by `simulate`."""
    state = initial_state(prep.model, prep.plan, prep.disc.velocity, prep.disc.velocity_gradient)
    solver = Solver(prep.model, prep.plan)
    solver.start(state)
    return state, solver


def static_fields(model: Model, meshes=()) -> dict[str, np.ndarray]:
    from pdmpm_cli.io.ply import mesh_static_fields

    fields = {
        "particle_X": model.rest_x,
        "particle_volume": model.particle_volume,
        "particle_mass": model.particle_mass,
        "particle_body": model.particle_body,
        "particle_bonds": np.diff(model.bond_start).astype(np.int32),
    }
    if len(model.pin_mask):
        fields["particle_pinned"] = model.pin_mask.astype(np.uint8)
    return fields | mesh_static_fields(meshes)


def frame_fields(state: State, names, model: Model | None = None, meshes=()) -> dict[str, np.ndarray]:
    """The per-frame fields the scene selected, by name (particle_x always; vertex_x when meshes ride along). A
    material's output field is computed by that material; fields a scene does not have (Fbar, damage, plastic
    strain of an elastic scene) are left out."""
    out = {"particle_x": state.particle_x}
    if meshes:
        out["vertex_x"] = np.concatenate(mesh_positions(model, state, meshes))
    computed = {name: fn for b in (model.bodies if model is not None else ())
                for name, fn in MATERIALS[b.kind].outputs.items()}
    for name in names:
        if name == "particle_speed":
            out[name] = np.linalg.norm(state.particle_v, axis=1)
        elif name in computed:
            out[name] = computed[name](model, state)
        elif state.has(name):
            out[name] = getattr(state, name)
    return out


def prepare_output_dir(out: Path, overwrite: bool):
    """Refuse to overwrite an earlier run unless asked: nothing already written is lost silently."""
    if any(p.name != LOCK_NAME for p in out.iterdir()):
        if not overwrite:
            resumable = " (or --resume it from its checkpoint)" if (out / checkpoint.FOLDER).is_dir() else ""
            raise InputError(f"{out}: output folder is not empty; pass --overwrite to replace it{resumable}, or "
                             f"choose another folder with --out")
        for name in ("run.h5", "run.usd"):
            (out / name).unlink(missing_ok=True)
        for sub in ("vtk", "meshes", "colliders", checkpoint.FOLDER):
            if (out / sub).is_dir():
                for f in (out / sub).iterdir():
                    f.unlink()


def write_collider_meshes(prep: Prepared, out: Path) -> None:
    """Each mesh collider's surface as placed at time 0, colliders/collider_<index>.ply (it then moves with its
    velocity): for `pdmpm render` and for compositing in other tools."""
    from pdmpm_cli.io.ply import write_ply

    if prep.disc.collider_meshes:
        (out / "colliders").mkdir(exist_ok=True)
    for i, mesh in prep.disc.collider_meshes.items():
        write_ply(out / "colliders" / f"collider_{i}.ply", mesh.vertices, mesh.triangles)


def _writers(prep: Prepared, out: Path, static: dict, keep: int) -> list:
    """The scene's exporters; with `keep` > 0 they continue the outputs in `out` after its first `keep` frames."""
    from pdmpm_cli.io.hdf5 import Hdf5RunWriter
    from pdmpm_cli.io.ply import MeshSeriesWriter
    from pdmpm_cli.io.vtk import VtkSeriesWriter

    scene, meshes = prep.scene, prep.disc.meshes
    writers = []
    if scene.output.hdf5 and keep:
        writers.append(Hdf5RunWriter.reopen(out / "run.h5", keep))
    elif scene.output.hdf5:
        # The plan carries the scene as validated (with --set and --variant applied) and the grid's wall layer for
        # readers such as render.
        record = {**prep.plan.to_dict(), "scene": scene.model_dump(mode="json"), "wall_cells": WALL}
        writers.append(Hdf5RunWriter(out / "run.h5", scene_text=prep.text, plan=json.loads(json.dumps(
            record, default=_jsonable)), static=static, compression=scene.output.compression,
            capacity=prep.plan.capacity if prep.plan.emitted else None))
    if scene.output.vtk:
        writers.append(VtkSeriesWriter.reopen(out / "vtk", static=static, frames=keep) if keep else
                       VtkSeriesWriter(out / "vtk", static=static))
    if meshes and scene.output.meshes:
        writers.append(MeshSeriesWriter.reopen(out / "meshes", meshes, keep) if keep else
                       MeshSeriesWriter(out / "meshes", meshes))
    surfaces = fluid_surfaces(prep)
    if surfaces.bodies and scene.output.meshes:
        writers.append(FluidSurfaceWriter.reopen(out / "meshes", surfaces, keep) if keep else
                       FluidSurfaceWriter(out / "meshes", surfaces))
    if scene.output.usd:
        writers.append(_usd_writer(prep, out, keep, surfaces))
    return writers


def fluid_surfaces(prep: Prepared) -> FluidSurfaces:
    """The fluid (viscoelastic) bodies whose reconstructed surfaces the exporters write each frame."""
    m = prep.model
    m = m.final  # an emitting body's range at its final count: a frame holds a prefix of it
    return FluidSurfaces([FluidBody(b.name, b.start, b.end, b.spacing, m.particle_volume[b.start:b.end])
                          for b in m.bodies if b.kind == "viscoelastic"])


def _usd_writer(prep: Prepared, out: Path, keep: int, surfaces: FluidSurfaces):
    """The run's USD stage (io.usd): each body's particle range, width (its spacing), embedded meshes and fluid
    surfaces."""
    from pdmpm_cli.io import usd

    bodies = [usd.UsdBody(b.name, s, e, float(h)) for b, (s, e), h in
              zip(prep.scene.bodies, prep.disc.body_ranges, prep.disc.body_spacing)]
    layout = {"fps": 1.0 / prep.plan.frame_dt, "bodies": bodies, "meshes": prep.disc.meshes, "surfaces": surfaces}
    path = out / usd.FILE_NAME
    return usd.UsdWriter.reopen(path, frames=keep, **layout) if keep else usd.UsdWriter(path, **layout)


def simulate(prep: Prepared, out: Path, reporter: Reporter | None = None, overwrite: bool = False,
             resume: checkpoint.Checkpoint | None = None) -> State:
    """Run the whole scene, writing frame 0 (the initial state) and every frame after it, with a checkpoint
    every `output.checkpoint_every` frames. With `resume` (from `prepare_resume`), continue from that checkpoint:
    the frames after it are dropped from the outputs and computed again. One run at a time per folder."""
    from pdmpm_cli.io.atomic import remove_temporaries
    from pdmpm_cli.io.sink import FrameSink

    scene, plan, model = prep.scene, prep.plan, prep.model
    solver = Solver(model, plan)  # before touching the output folder: a missing GPU loses no earlier run
    if scene.output.usd:  # likewise a missing usd-core
        from pdmpm_cli.io.usd import require

        require()
    with OutputLock(out):
        if resume is None:
            prepare_output_dir(out, overwrite)
            write_collider_meshes(prep, out)
        for folder in (out, out / "vtk", out / "meshes", out / checkpoint.FOLDER):
            remove_temporaries(folder)
        state = initial_state(model, plan, prep.disc.velocity, prep.disc.velocity_gradient)
        solver.start(state)
        first = 0
        if resume is not None:
            checkpoint.restore(resume, state, solver)
            first = resume.frame
        meshes = prep.disc.meshes
        # An emitter's particles are all in the static fields (Model.final); a frame holds the first of them.
        writers = _writers(prep, out, static_fields(model.final, meshes), first + 1 if resume else 0)
        every, head = scene.output.checkpoint_every, checkpoint.header(prep)
        if resume is not None:  # the thread count the run started with, which identical frames need
            head["threads"] = resume.attrs["threads"]
        if reporter:
            reporter.start(plan, first)
        on_substep = reporter.substep if reporter else None
        with FrameSink(writers) as sink:
            if resume is None:
                sink.submit(0, 0.0, frame_fields(state, scene.output.fields, model, meshes))
            for f in range(first + 1, plan.frames + 1):
                solver.advance(state, f * plan.frame_dt, on_substep)  # ends with the host State current
                sink.submit(f, state.time, frame_fields(state, scene.output.fields, solver.model, meshes))
                if every and f % every == 0 and f < plan.frames:
                    sink.call(f"checkpoint at frame {f}",
                              functools.partial(checkpoint.save, out, f, checkpoint.snapshot(state), head))
                if reporter:
                    reporter.frame(f, state)
        checkpoint.remove(out)
    return state


def _jsonable(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, float) and math.isinf(o):
        return "inf"
    raise TypeError(type(o))
