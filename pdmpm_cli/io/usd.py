"""Animation for studio tools (Houdini, Blender, Omniverse): one USD file per run, ``OUTDIR/run.usd``.

The stage is in metres (``metersPerUnit`` 1) with +y up, ``timeCodesPerSecond`` = ``framesPerSecond`` = the scene's
fps, and one time sample per frame at time code = frame time x fps (frame N at N). Under the default prim
``/pdmpm`` each body is an Xform ``/pdmpm/<body>`` holding

* ``particles``: a ``UsdGeomPoints`` with the particle positions, ``velocities`` (when ``particle_v`` is written),
  a constant width of the body's particle spacing, and every other per-frame field of ``output.fields`` as a
  primvar of the same name (``primvars:particle_speed``; 3-vectors as float3, 3x3 tensors as 9 floats per point);
* ``surface`` (shell bodies) or ``cells`` (Voronoi bodies): a ``UsdGeomMesh`` of the triangles the PLY files hold,
  with animated points;
* ``fluid_surface`` (viscoelastic bodies): the surface reconstructed from the particles each frame
  (``io.surface``), a ``UsdGeomMesh`` whose points and faces are both time-sampled (its topology changes).

The file is written in USD's binary (crate) format and saved after every frame (an incremental save costs about a
millisecond), so a killed run leaves every frame written so far; ``reopen`` (``pdmpm run --resume``) drops the time
samples after the checkpoint. It needs Pixar's ``usd-core`` package (module ``pxr``), an optional dependency:
``pip install usd-core``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pdmpm_cli.errors import InputError
from pdmpm_cli.io.sink import check_order

FILE_NAME = "run.usd"
ROOT = "/pdmpm"
POSITION_FIELD = "particle_x"
VELOCITY_FIELD = "particle_v"
VERTEX_FIELD = "vertex_x"
_MISSING = ("output.usd: true needs Pixar's USD library, which is not installed. Fix: pip install usd-core (or "
            "pip install 'pdmpm[usd]'), or set output.usd: false")


def require() -> None:
    """InputError (exit code 2) if usd-core is missing: checked before a run starts, not at its first frame."""
    try:
        import pxr.Usd  # noqa: F401
    except ImportError:
        raise InputError(_MISSING) from None


@dataclass(frozen=True)
class UsdBody:
    """One body's particles in the frame arrays (start..end), its name and its particles' width (spacing) [m]."""

    name: str
    start: int
    end: int
    width: float


def prim_names(names) -> list[str]:
    """Valid, unique USD prim names for the body names (other characters become '_')."""
    out: list[str] = []
    for name in names:
        base = re.sub(r"[^A-Za-z0-9_]", "_", name) or "body"
        base = base if not base[0].isdigit() else "_" + base
        unique, k = base, 1
        while unique in out:
            k += 1
            unique = f"{base}_{k}"
        out.append(unique)
    return out


class UsdWriter:
    """Writes every frame as time samples of one USD stage (see the module doc)."""

    def __init__(self, path: str | os.PathLike[str], *, fps: float, bodies: list[UsdBody], meshes,
                 surfaces=None) -> None:
        require()
        from pxr import Usd, UsdGeom

        self.path = Path(path)
        self._fps = float(fps)
        self._stage = Usd.Stage.CreateNew(str(self.path))
        UsdGeom.SetStageMetersPerUnit(self._stage, 1.0)
        UsdGeom.SetStageUpAxis(self._stage, UsdGeom.Tokens.y)
        self._stage.SetTimeCodesPerSecond(self._fps)
        self._stage.SetFramesPerSecond(self._fps)
        self._stage.SetStartTimeCode(0.0)
        self._stage.SetEndTimeCode(0.0)
        root = UsdGeom.Xform.Define(self._stage, ROOT)
        self._stage.SetDefaultPrim(root.GetPrim())
        names = prim_names([b.name for b in bodies])
        for body, name in zip(bodies, names):
            UsdGeom.Xform.Define(self._stage, f"{ROOT}/{name}")
            points = UsdGeom.Points.Define(self._stage, f"{ROOT}/{name}/particles")
            points.CreateWidthsAttr([float(body.width)])
            points.SetWidthsInterpolation(UsdGeom.Tokens.constant)
        for mesh in meshes:
            prim = UsdGeom.Mesh.Define(self._stage, self._mesh_path(names[mesh.body], mesh))
            prim.CreateFaceVertexCountsAttr(np.full(len(mesh.triangles), 3, dtype=np.int32).tolist())
            prim.CreateFaceVertexIndicesAttr(np.asarray(mesh.triangles, dtype=np.int32).ravel().tolist())
            prim.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        prims = dict(zip((b.name for b in bodies), names))
        for fluid in surfaces.bodies if surfaces else ():
            UsdGeom.Mesh.Define(self._stage, _surface_path(prims[fluid.name])).CreateSubdivisionSchemeAttr(
                UsdGeom.Tokens.none)
        self._layout(bodies, names, meshes, surfaces)
        self._stage.Save()

    @staticmethod
    def _mesh_path(body_prim: str, mesh) -> str:
        return f"{ROOT}/{body_prim}/{'cells' if mesh.kind == 'cells' else 'surface'}"

    def _layout(self, bodies, names, meshes, surfaces=None) -> None:
        from pxr import UsdGeom

        prims = dict(zip((b.name for b in bodies), names))
        self._surfaces = surfaces if surfaces and surfaces.bodies else None
        self._surface_prims = [UsdGeom.Mesh.Get(self._stage, _surface_path(prims[f.name]))
                               for f in (surfaces.bodies if self._surfaces else ())]

        self._bodies = [(UsdGeom.Points.Get(self._stage, f"{ROOT}/{n}/particles"), b) for b, n in zip(bodies, names)]
        starts = np.cumsum([0] + [len(m.vertices) for m in meshes])
        self._meshes = [(UsdGeom.Mesh.Get(self._stage, self._mesh_path(names[m.body], m)), a, b)
                        for m, a, b in zip(meshes, starts[:-1], starts[1:])]
        self._last_index = -1
        self._closed = False

    @classmethod
    def reopen(cls, path: str | os.PathLike[str], *, fps: float, bodies: list[UsdBody], meshes, frames: int,
               surfaces=None) -> UsdWriter:
        """Continue the stage at ``path`` after its first ``frames`` frames: later time samples are removed."""
        require()
        from pxr import Usd

        writer = cls.__new__(cls)
        writer.path = Path(path)
        writer._fps = float(fps)
        if not writer.path.is_file():
            raise InputError(f"{writer.path}: missing, so the run cannot continue it; start the run again with "
                             f"--overwrite")
        try:
            writer._stage = Usd.Stage.Open(str(writer.path))
        except Exception as error:  # pxr raises Tf.ErrorException for a missing or damaged file
            raise InputError(f"{writer.path}: cannot be reopened to continue the run ({str(error).strip()[:200]}); "
                             f"start the run again with --overwrite") from None
        names = prim_names([b.name for b in bodies])
        writer._layout(bodies, names, meshes, surfaces)
        held = 0
        for prim in writer._stage.Traverse():
            for attr in prim.GetAttributes():
                times = attr.GetTimeSamples()
                held = max(held, sum(1 for t in times if t < frames - 0.5))
                for t in times:
                    if t > frames - 0.5:
                        attr.ClearAtTime(t)
        if held < frames:
            raise InputError(f"{writer.path}: holds {held} of the {frames} frames the checkpoint needs; start the "
                             f"run again with --overwrite")
        writer._stage.SetEndTimeCode(frames - 1)
        writer._last_index = frames - 1
        writer._stage.Save()
        return writer

    def write_frame(self, index: int, time: float, fields: dict[str, np.ndarray]) -> None:
        """Add frame ``index`` as time samples at time code ``time * fps`` and save the stage."""
        from pxr import Vt

        check_order(self.path, self._closed, self._last_index, index)
        code = float(time) * self._fps
        x = np.asarray(fields[POSITION_FIELD])
        extras = {name: np.asarray(value) for name, value in fields.items()
                  if name.startswith("particle_") and name not in (POSITION_FIELD, VELOCITY_FIELD)
                  and np.ndim(value) >= 1 and len(value) == len(x)}
        for points, body in self._bodies:
            sl = slice(body.start, body.end)
            points.GetPointsAttr().Set(_vec3f(x[sl]), code)
            points.GetExtentAttr().Set(_extent(x[sl], 0.5 * body.width), code)
            if VELOCITY_FIELD in fields:
                points.GetVelocitiesAttr().Set(_vec3f(np.asarray(fields[VELOCITY_FIELD])[sl]), code)
            for name, value in extras.items():
                _primvar(points, name, value[sl]).Set(_array(value[sl]), code)
        if self._meshes:
            vx = np.asarray(fields[VERTEX_FIELD])
            for mesh, a, b in self._meshes:
                mesh.GetPointsAttr().Set(_vec3f(vx[a:b]), code)
                mesh.GetExtentAttr().Set(_extent(vx[a:b], 0.0), code)
        if self._surfaces:
            for prim, (V, T) in zip(self._surface_prims, self._surfaces.at(index, x)):
                prim.GetPointsAttr().Set(_vec3f(V), code)
                prim.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(len(T), 3, dtype=np.int32)), code)
                prim.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(T.astype(np.int32).ravel()), code)
                prim.GetExtentAttr().Set(_extent(V, 0.0), code)
        self._stage.SetEndTimeCode(max(code, self._stage.GetEndTimeCode()))
        self._last_index = index
        self._stage.Save()

    def close(self) -> None:
        """Every frame is saved as it is written; marks the writer closed."""
        self._closed = True


def _surface_path(body_prim: str) -> str:
    """A fluid body's reconstructed surface; its topology changes every frame (time-sampled faces)."""
    return f"{ROOT}/{body_prim}/fluid_surface"


def _vec3f(a: np.ndarray):
    from pxr import Vt

    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32))


def _extent(x: np.ndarray, pad: float):
    """The bounding box [lo, hi] of the points, grown by `pad` (a point's radius), as USD's extent."""
    if len(x) == 0:
        return _vec3f(np.zeros((2, 3)))
    return _vec3f(np.stack([x.min(axis=0) - pad, x.max(axis=0) + pad]))


def _array(a: np.ndarray):
    from pxr import Vt

    if a.ndim == 2 and a.shape[1] == 3:
        return _vec3f(a)
    return Vt.FloatArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32).reshape(-1))


def _primvar(points, name: str, value: np.ndarray):
    """The per-point primvar for a field, created on first use (float, float3, or elementSize floats)."""
    from pxr import Sdf, UsdGeom

    api = UsdGeom.PrimvarsAPI(points.GetPrim())
    if api.HasPrimvar(name):
        return api.GetPrimvar(name)
    kind = Sdf.ValueTypeNames.Float3Array if value.ndim == 2 and value.shape[1] == 3 else Sdf.ValueTypeNames.FloatArray
    primvar = api.CreatePrimvar(name, kind, UsdGeom.Tokens.vertex)
    size = int(np.prod(value.shape[1:])) if value.ndim > 1 and kind == Sdf.ValueTypeNames.FloatArray else 1
    if size > 1:
        primvar.SetElementSize(size)
    return primvar
