"""Stability sweep: stiff, near-incompressible, stretched, compressed, impacting, shattering and cloth-like bodies
and liquids, each run with the automatic time step and classified.

Every case is a small scene dict (about 500 particles) built from `BASE`, plus what the scene language cannot say:
an initial homogeneous stretch of the particles about their centre (`prestretch`) and impact speeds given in units
of dx / dt, the grid cells per step of the at-rest time step (`impact`). A run is classified as

- `stable`,
- `nan`: a non-finite position, velocity or energy,
- `outside`: particles left the domain,
- `energy`: total energy (kinetic + strain + gravitational, measured from the domain floor) above
  `GROWTH` times its start at a frame, kinetic energy above that at any step, or the solver's runaway check,
- `refused`: the scene was rejected on input (a CFL factor above 1 is, by the schema),
- `error`: a kernel raised an arithmetic error (a crash; counted as unstable).

Forced steps: the Plan reduces any user dt to its bound, by design. To measure the real threshold,
`run_case(..., dt_factor=k)` replaces the Plan's step with k times the engine's predicted stability limit
(engine.spectrum: 2 / omega_max of the linearised grid operator; of the crack particles' own, off the grid, while
one holds a bond; and a collider's depth over the initial speed, which a particle must not cross in one step), on
a copy of the Plan never reachable from `pdmpm run`; every such row is marked `forced`. `threshold` bisects k
(geometrically, between 1/4 and 8) for the largest stable one. Measured (docs/results.md, 'Stability'): 0.70-1.49
for all 23 threshold cases, while the automatic step, min(cfl dx / (c + |v|), bond_safety dt_bond), stays 4.5-30x
below the limit (docs/method.md, 'Time step').
"""

import copy
import dataclasses
import functools
import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from pdmpm_cli.errors import InputError, SimulationError
from pdmpm_cli.scene.loader import merge

GROWTH = 10.0  # total energy above this multiple of its start is a blow-up
FRAMES = 10  # energy and runaway checks per run
FORCED_STEPS = 300  # a forced run takes at least this many steps, so a slowly growing mode shows
LO, HI = 0.25, 8.0  # bisection bracket of the forced step, in units of the predicted bound
BISECTIONS = 6  # halvings of log(HI / LO): the threshold to about 6 %

BASE = {
    "simulation": {"duration": 1.0, "fps": 1e-3},  # run_case sets duration and frames; 1000 s frames cap no step
    "grid": {"cell_size": 0.05, "domain": {"min": [0, 0, 0], "max": [1.2, 1.2, 1.2]}},
    "gravity": [0, 0, 0],
    "bodies": [{
        "name": "block",
        "geometry": {"mode": "cloud", "shape": {"type": "box", "center": [0.6, 0.6, 0.6], "size": [0.2, 0.2, 0.2]}},
        "material": {"model": "elastic", "density": 1000.0, "lam": 1e5, "mu": 1e5},
    }],
}
# 0.05 m (a cell) below the block; the projection, whose tunnelling bound the impact cases probe (a penalty
# floor bounces a block hitting it at several wave speeds back at that speed, into the domain's top wall)
FLOOR = {"type": "plane", "point": [0, 0.45, 0], "normal": [0, 1, 0], "response": "projection"}
BOUNCY = {**FLOOR, "response": "penalty"}


@dataclass(frozen=True)
class Case:
    """One sweep case: a scene (BASE merged with `changes`), what it probes, and how long it runs."""

    name: str
    category: str
    parameter: str  # the swept value, as printed
    probes: str
    changes: dict = field(default_factory=dict)
    prestretch: tuple[float, float, float] = (1.0, 1.0, 1.0)  # initial x_p = c + S (X_p - c), S = diag [-]
    impact: float = 0.0  # initial speed along -y (the first body; +y for a second) in dx / dt_auto [-]
    steps: int = 250  # nominal run length in at-rest automatic steps


def _material(**kw) -> dict:
    return {"bodies": [merge(BASE["bodies"][0], {"material": kw})]}


def _body(**kw) -> dict:
    return merge(BASE["bodies"][0], kw)


def _cloth(**kw) -> dict:
    """A 0.3 m single-layer sheet (rank-2 shape tensors), normal up, at the block's height."""
    body = {"name": "cloth", "geometry": {"mode": "shell", "layers": 1, "surface": {
        "type": "sheet", "center": [0.6, 0.6, 0.6], "size": [0.3, 0.3], "rotation": [-90, 0, 0]}},
        "material": {"model": "elastic", "density": 500.0, "lam": 1e6, "mu": 1e5}}
    return merge(body, kw)


def cases() -> list[Case]:
    """The full sweep: every category of the stability cases (stiffness over decades, incompressibility, large
    stretch and compression, fast impacts, broken bonds, rank-deficient shells)."""
    out = []
    vib = (1.05, 1.0, 1.0)  # 5 % uniaxial pre-strain released: a vibration of every mode of the block
    for e in range(3, 11):  # lam = mu = 1e3 .. 1e10 Pa at fixed geometry: dt must follow sqrt(rho / M)
        out.append(Case(f"stiff_1e{e}", "stiffness", f"lam=mu=1e{e} Pa", "stable dt scales as sqrt(rho/M)",
                        _material(lam=10.0**e, mu=10.0**e), vib))
    spin = {"bodies": [_body(angular_velocity=[0, 0, 20.0])]}
    for cfl in (0.1, 0.2, 0.4, 0.7, 1.0):
        out.append(Case(f"cfl_{cfl:g}", "cfl", f"cfl={cfl:g}", "automatic step at that CFL factor",
                        merge(spin, {"simulation": {"cfl": cfl}}), (1.1, 1.0, 1.0)))
    out.append(Case("cfl_1_bond_1", "cfl", "cfl=1, bond_safety=1", "both safety factors at their maximum",
                    merge(spin, {"simulation": {"cfl": 1.0, "bond_safety": 1.0}}), (1.1, 1.0, 1.0)))
    out.append(Case("cfl_1.2", "cfl", "cfl=1.2", "an oversize CFL factor is refused on input",
                    merge(spin, {"simulation": {"cfl": 1.2}}), (1.1, 1.0, 1.0)))
    for ratio in (1, 10, 100, 300, 1000):  # mu = 1e4 Pa, lam up to 1e7 Pa
        out.append(Case(f"lam_mu_{ratio}", "incompressible", f"lam/mu={ratio}", "near-incompressible bonds",
                        _material(lam=1e4 * ratio, mu=1e4), vib))
    out.append(Case("mu_0", "incompressible", "mu=0", "bond term only (no Fbar)", _material(lam=1e5, mu=0.0), vib))
    for ratio in (10, 100, 1000):  # viscoelastic: the LPS dilatation coupling is not in the bond bound
        visco = {"model": "viscoelastic", "density": 1000.0, "lam": 1e4 * ratio, "mu": 1e4, "relaxation_time": 0.01,
                 "relaxing_fraction": 0.5}
        out.append(Case(f"visco_lam_mu_{ratio}", "incompressible", f"viscoelastic lam/mu={ratio}",
                        "LPS dilatation term under a compressive impact",
                        {"bodies": [_body(material=visco)], "colliders": [FLOOR]}, impact=0.3))
    for s in (1.5, 2.0, 3.0):
        out.append(Case(f"stretch_{s:g}x", "stretch", f"uniaxial {s:g}x", "released from a large stretch",
                        prestretch=(s, 1.0, 1.0)))
    out.append(Case("stretch_1.5x_3d", "stretch", "triaxial 1.5x", "released from a large dilatation",
                    prestretch=(1.5, 1.5, 1.5)))
    for s in (0.7, 0.5, 0.3):
        out.append(Case(f"compress_{s:g}x", "compression", f"uniaxial {s:g}x", "released from a large compression",
                        prestretch=(s, 1.0, 1.0)))
    out.append(Case("compress_0.5x_3d", "compression", "triaxial 0.5x", "released from a volumetric compression",
                    prestretch=(0.5, 0.5, 0.5)))
    for k in (0.3, 1.0, 3.0, 10.0):
        out.append(Case(f"impact_floor_{k:g}", "impact", f"{k:g} dx/dt", "block hits the floor",
                        {"colliders": [FLOOR]}, impact=k))
    pair = {"bodies": [_body(name="a", geometry={"shape": {"center": [0.6, 0.75, 0.6]}}),
                       _body(name="b", geometry={"shape": {"center": [0.6, 0.45, 0.6]}})]}
    for k in (1.0, 3.0):
        out.append(Case(f"impact_pair_{k:g}", "impact", f"2 x {k:g} dx/dt", "two blocks collide head-on",
                        pair, impact=k))
    out.append(Case("impact_stiff_1", "impact", "1 dx/dt, lam=mu=1e9 Pa", "stiff block hits the floor",
                    {**_material(lam=1e9, mu=1e9), "colliders": [FLOOR]}, impact=1.0))
    plastic = {"model": "plastic", "density": 1000.0, "lam": 1e4, "mu": 1e4, "yield_stress": 300.0}
    out.append(Case("plastic_drop", "plastic", "lam=mu=1e4 Pa, yield 300 Pa", "soft plastic block dropped",
                    {"bodies": [_body(material=plastic)], "colliders": [FLOOR], "gravity": [0, -9.81, 0]},
                    steps=1500))
    out.append(Case("plastic_impact_1", "plastic", "1 dx/dt", "plastic block hits the floor",
                    {"bodies": [_body(material=plastic)], "colliders": [FLOOR]}, impact=1.0))
    out.append(Case("plastic_stretch_2x", "plastic", "uniaxial 2x", "plastic flow from a large stretch",
                    {"bodies": [_body(material=plastic)]}, (2.0, 1.0, 1.0)))
    for thr, label in ((1e-4, "1e-4"), (1e-2, "1e-2")):
        out.append(Case(f"shatter_{label}", "broken", f"threshold {label}", "impact breaks bonds to single particles",
                        {"bodies": [_body(fracture={"threshold": thr, "damage_resistance": 0.0})],
                         "colliders": [FLOOR]},
                        impact=0.3))
    out.append(Case("crack_0.02", "broken", "threshold 0.02", "crack particles keep some bonds off the grid",
                    {"bodies": [_body(fracture={"threshold": 0.02})], "colliders": [FLOOR]}, impact=0.2))
    out.append(Case("shatter_stretch", "broken", "threshold 1e-3, 1.5x", "every bond over threshold at the start",
                    {"bodies": [_body(fracture={"threshold": 1e-3, "damage_resistance": 0.0})]}, (1.5, 1.5, 1.5)))
    out.append(Case("shatter_plastic", "broken", "plastic, threshold 1e-3", "plastic flow and fracture together",
                    {"bodies": [_body(material=plastic, fracture={"threshold": 1e-3, "damage_resistance": 0.0})],
                     "colliders": [FLOOR]}, impact=0.3))
    ball = {"type": "sphere", "center": [0.6, 0.45, 0.6], "radius": 0.1}
    gravity = [0, -9.81, 0]
    out.append(Case("cloth_drape", "shell", "cloth on a ball", "rank-2 shape tensor, folding",
                    {"bodies": [_cloth()], "colliders": [ball], "gravity": gravity}, steps=1000))
    corner = {"type": "box", "center": [0.45, 0.6, 0.45], "size": [0.06, 0.06, 0.06]}
    out.append(Case("cloth_pinned", "shell", "pinned corner", "hanging cloth, pinned particles",
                    {"bodies": [_cloth(pins=[{"region": corner}])], "gravity": gravity}, steps=1000))
    out.append(Case("cloth_stretch_2x", "shell", "in-plane 2x", "cloth released from a large stretch",
                    {"bodies": [_cloth()]}, (2.0, 1.0, 2.0)))
    out.append(Case("cloth_stiff", "shell", "lam=mu=1e9 Pa", "stiff cloth hits the floor",
                    {"bodies": [_cloth(material={"lam": 1e9, "mu": 1e9})], "colliders": [FLOOR]}, impact=1.0))
    shell = {**_body(name="ball"), "geometry": {"mode": "shell", "layers": 1, "surface": {
        "type": "sphere", "center": [0.6, 0.6, 0.6], "radius": 0.12}}}
    out.append(Case("shell_ball", "shell", "hollow ball, 1 layer", "closed single-layer shell hits the floor",
                    {"bodies": [shell], "colliders": [{**FLOOR, "point": [0, 0.43, 0]}]}, impact=1.0))
    out += discretisation_cases(vib, gravity)
    out += fluid_cases(gravity)
    return out


def discretisation_cases(vib, gravity) -> list[Case]:
    """Discretisations the grid-filtering argument depends on (particles per cell, horizon, cell shapes, layers)
    and boundary conditions that feed energy in (a moving pin) or hold a body (resting on a collider)."""
    cloud = {"mode": "cloud", "shape": {"type": "box", "center": [0.6, 0.6, 0.6], "size": [0.3, 0.3, 0.3]}}
    out = [
        Case("spacing_dx", "discretisation", "h = dx (1 particle per cell)", "coarsest particles: 1 per cell",
             {"bodies": [_body(geometry={**cloud, "spacing": 0.05})]}, vib),
        Case("spacing_dx_4", "discretisation", "h = dx/4 (64 per cell)", "fine particles: 64 per cell",
             {"bodies": [_body(geometry={"spacing": 0.0125})]}, vib),
        Case("horizon_3h", "discretisation", "horizon 3h", "wider horizon, 4x the bonds",
             {"bodies": [_body(geometry={"horizon": 3.0})]}, vib),
        Case("horizon_3h_dx", "discretisation", "h = dx, horizon 3h", "1 particle per cell and a wide horizon",
             {"bodies": [_body(geometry={**cloud, "spacing": 0.05, "horizon": 3.0})]}, vib),
        Case("voronoi", "discretisation", "Voronoi cells, h = dx/2", "face-sharing bonds of Voronoi cells",
             {"bodies": [_body(geometry={"mode": "voronoi", "shape": BASE["bodies"][0]["geometry"]["shape"]})]},
             vib),
        Case("shell_layers_3", "discretisation", "hollow ball, 3 layers", "multi-layer shell hits the floor",
             {"bodies": [{**_body(name="ball"), "geometry": {"mode": "shell", "layers": 3, "surface": {
                 "type": "sphere", "center": [0.6, 0.6, 0.6], "radius": 0.12}}}],
              "colliders": [{**FLOOR, "point": [0, 0.43, 0]}]}, impact=1.0),
        Case("crack_dx_4", "discretisation", "threshold 0.02, h = dx/4", "crack particles at 64 per cell",
             {"bodies": [_body(geometry={"spacing": 0.0125}, fracture={"threshold": 0.02})], "colliders": [FLOOR]},
             impact=0.2),
        Case("fracture_intact", "discretisation", "threshold 10, nothing breaks", "a fracture body with no crack",
             {"bodies": [_body(fracture={"threshold": 10.0})]}, vib),
    ]
    pull = {"region": {"type": "box", "center": [0.7, 0.6, 0.6], "size": [0.02, 0.2, 0.2]},
            "velocity": [0.1, 0.0, 0.0]}  # the +x face, pulled at 0.1 m/s (0.006 c), the rest dragged along
    out.append(Case("pin_pulled", "boundary", "face pinned at 0.1 m/s", "a moving pin drags the block",
                    {"bodies": [_body(pins=[pull])]}))
    out.append(Case("resting_floor", "boundary", "on the floor, gravity", "a body touching a collider from the start",
                    {"bodies": [_body()], "colliders": [{**FLOOR, "point": [0, 0.5, 0]}], "gravity": gravity},
                    steps=1000))
    out.append(Case("resting_penalty", "boundary", "on a penalty floor, gravity", "a body set down on the elastic "
                    "push of a penalty collider", {"bodies": [_body()], "colliders": [{**BOUNCY, "point": [0, 0.5, 0]}],
                                                   "gravity": gravity}, steps=1000))
    out.append(Case("bounce_penalty", "boundary", "penalty floor, 0.05 dx/dt", "a block bounces off a penalty floor",
                    {"colliders": [BOUNCY]}, impact=0.05))
    out.append(Case("bounce_penalty_stiff", "boundary", "penalty stiffness 4, 0.05 dx/dt", "the stiffest penalty "
                    "push", {"colliders": [{**BOUNCY, "stiffness": 4.0}]}, impact=0.05))
    liquid = {"model": "viscoelastic", "density": 1000.0, "lam": 5e3, "mu": 500.0, "relaxation_time": 0.05,
              "relaxing_fraction": 1.0, "break_stretch": 0.03}
    blob = {"mode": "cloud", "spacing": 0.0125, "shape": {"type": "sphere", "center": [0.6, 0.75, 0.6],
                                                          "radius": 0.06}}
    out.append(Case("mesh_bowl", "boundary", "liquid into a mesh bowl", "a closed mesh file (signed distance) holds "
                    "a liquid", {"bodies": [{**_body(material=liquid), "geometry": blob}], "gravity": gravity,
                                 "colliders": [{"type": "mesh", "path": MESH_FILES[0], "translate": [0.6, 0.6, 0.6],
                                                "boundary": "slip", "friction": 0.2}]}, steps=1000))
    out.append(Case("mesh_pusher", "boundary", "mesh box at 0.5 m/s", "a moving mesh collider meets a block "
                    "(1 m/s towards it) and throws it back", {"bodies": [_body(velocity=[-1.0, 0.0, 0.0])],
                    "colliders": [{"type": "mesh", "path": MESH_FILES[1], "translate": [0.35, 0.6, 0.6],
                                   "velocity": [0.5, 0.0, 0.0]}]}, steps=300))
    return out


def fluid_cases(gravity) -> list[Case]:
    """Liquids (the viscoelastic model with its whole shear relaxing and the volume-ratio pressure p = K (1 - J)):
    water's real bulk modulus, a paste a million times more viscous than water, a fast splash and a pour onto a
    plate that slides away underneath; and two streams from an emitter, a fast pour and a pour onto a sliding plate
    (the energy check counts what the born particles bring)."""
    def liquid(**kw) -> dict:
        material = {"model": "viscoelastic", "density": 1000.0, "lam": 5e3, "mu": 500.0, "relaxation_time": 0.05,
                    "relaxing_fraction": 1.0} | kw
        return _body(material=material)

    floor = {**FLOOR, "boundary": "sticky"}
    return [
        Case("fluid_water_bulk", "fluid", "K = 2.2 GPa (water)", "the pressure's sound speed (1480 m/s) sets the "
             "step", {"bodies": [liquid(bulk_modulus=2.2e9)], "colliders": [floor], "gravity": gravity},
             steps=1000),
        Case("fluid_viscous", "fluid", "viscosity 1e5 Pa s", "a paste: mu = 1e5 Pa relaxing over 1 s",
             {"bodies": [liquid(mu=1e5, lam=1e5, relaxation_time=1.0)], "colliders": [floor], "gravity": gravity},
             impact=1.0),
        Case("fluid_splash", "fluid", "3 dx/dt", "a liquid block hits the floor fast",
             {"bodies": [liquid()], "colliders": [floor]}, impact=3.0),
        Case("fluid_moving_plate", "fluid", "plate at 1 m/s", "a liquid falls on a sticky plate sliding away",
             {"bodies": [liquid()], "gravity": gravity,
              "colliders": [{**floor, "velocity": [1.0, 0.0, 0.0]}]}, steps=1000),
        Case("fluid_pour_fast", "fluid", "poured at 5 m/s", "an emitter pours a liquid at 5 m/s onto the floor "
             "(0.0375 m^3/s from a 12-point nozzle 0.2 m above it)",
             {"bodies": [poured(liquid(), 5.0, 0.6)], "colliders": [floor], "gravity": gravity}, steps=1500),
        Case("fluid_pour_plate", "fluid", "poured onto a plate at 0.5 m/s", "an emitter pours a liquid at 1 m/s "
             "onto a sticky plate sliding away", {"bodies": [poured(liquid(), 1.0, 0.4)], "gravity": gravity,
                                                  "colliders": [{**floor, "velocity": [0.5, 0.0, 0.0]}]},
             steps=2000),
    ]


def poured(body: dict, speed: float, x: float) -> dict:
    """The liquid `body` as a stream poured down at `speed` [m/s] from a nozzle at (x, 0.7, 0.6) [m]: a disc of
    radius 2 h (12 lattice points) one spacing thick, at the rate a continuous stream has (12 h^2 speed), with a head
    of two layers below it."""
    h = BASE["grid"]["cell_size"] / 2
    disc = {"type": "cylinder", "radius": 2 * h, "rotation": [90, 0, 0]}
    return body | {
        "geometry": {"mode": "cloud", "sampling": "lattice",
                     "shape": disc | {"center": [x, 0.7 - 2 * h, 0.6], "height": 2 * h}},
        "velocity": [0.0, -speed, 0.0],
        "emitter": {"shape": disc | {"center": [x, 0.7, 0.6], "height": h}, "velocity": [0.0, -speed, 0.0],
                    "rate": 12 * h * h * speed}}


MESH_FILES = ("bowl.ply", "pusher.ply")  # written by mesh_folder: a bowl (r 0.2 m, wall 4 cm), a 0.2 m box


@functools.cache
def mesh_folder() -> Path:
    """A scratch folder with the sweep's mesh files, beside which the cases' scenes are prepared."""
    from pdmpm_cli.geometry.primitive_surfaces import bowl_surface, primitive_surface
    from pdmpm_cli.io.ply import write_ply

    folder = Path(tempfile.mkdtemp(prefix="pdmpm-stability-"))
    for name, mesh in zip(MESH_FILES, (bowl_surface(0.2, 0.16, 0.015),
                                       primitive_surface("box", center=(0, 0, 0), R=None, edge=0.05,
                                                         size=(0.2, 0.2, 0.2)))):
        write_ply(folder / name, mesh.vertices, mesh.triangles)
    return folder


QUICK = ("stiff_1e3", "stiff_1e9", "cfl_1_bond_1", "cfl_1.2", "lam_mu_1000", "visco_lam_mu_1000", "stretch_3x",
         "compress_0.3x", "impact_floor_10", "plastic_drop", "shatter_1e-4", "cloth_drape")
THRESHOLD_CASES = ("stiff_1e3", "stiff_1e6", "stiff_1e9", "lam_mu_1000", "mu_0", "visco_lam_mu_100",
                   "cloth_stretch_2x", "cloth_stiff", "impact_floor_1", "impact_floor_10", "plastic_impact_1",
                   "crack_0.02", "shatter_plastic", "spacing_dx", "spacing_dx_4", "horizon_3h", "horizon_3h_dx",
                   "voronoi", "shell_layers_3", "crack_dx_4", "fracture_intact", "pin_pulled", "resting_floor")
QUICK_THRESHOLD = ("stiff_1e6",)


def select(names=None, quick: bool = False) -> list[Case]:
    """The cases named (all, or the quick set), in sweep order; an unknown name is an InputError."""
    every = cases()
    wanted = names or (QUICK if quick else None)
    if not wanted:
        return every
    known = {c.name: c for c in every}
    if unknown := [n for n in wanted if n not in known]:
        raise InputError(f"unknown stability case {', '.join(unknown)}; known: {', '.join(known)}")
    return [known[n] for n in wanted]


# ---------------------------------------------------------------- running one case


class Growth(Exception):
    """Kinetic energy above GROWTH times the starting total within a frame."""


@dataclass
class Prepared:
    prep: object  # runner.Prepared
    state: object  # the starting State (prestretch applied), copied by every run
    v0: float  # largest initial speed [m/s]
    critical: object  # engine.spectrum.CriticalSteps of the starting state
    dt_pred: float  # predicted limit at the start: critical.predicted(v0, no crack particles) [s]
    dt_bond: float  # bond bound before bond_safety [s]
    dt_wave: float  # dx / c [s]
    bound: str  # which limit dt_pred is: grid or tunnel


def prepare_case(case: Case, path: Path | None = None) -> Prepared:
    """Validate and discretise the case's scene (impact speeds are set from the at-rest automatic step), apply
    the prestretch and predict its stability limits (engine.spectrum)."""
    from pdmpm_cli.engine.spectrum import critical_steps
    from pdmpm_cli.runner import prepare_scene, start_in_memory
    from pdmpm_cli.scene.schema import Scene

    scene_dict = merge(BASE, case.changes)
    path = path or mesh_folder() / "stability.yaml"  # mesh colliders' files resolve beside it
    prep = prepare_scene(Scene.model_validate(scene_dict), path)
    if case.impact:
        speed = case.impact * prep.plan.cell_size / prep.plan.dt_max
        for i, body in enumerate(scene_dict["bodies"]):
            body["velocity"] = [0.0, -speed if i == 0 else speed, 0.0]
        prep = prepare_scene(Scene.model_validate(scene_dict), path)
    v0 = float(np.linalg.norm(prep.disc.velocity, axis=1).max()) if prep.disc.n_particles else 0.0
    plan = prep.plan
    state, solver = start_in_memory(prep)  # the materials' initial state depends on the rest positions only
    stretch = np.asarray(case.prestretch)
    for s, e in prep.model.body_ranges:
        centre = state.particle_x[s:e].mean(axis=0)
        state.particle_x[s:e] = centre + (state.particle_x[s:e] - centre) * stretch
    critical = critical_steps(solver, state)
    dt_pred = critical.predicted(v0, False)
    return Prepared(prep, state, v0, critical, dt_pred, min(b.dt_bond for b in plan.bodies),
                    plan.cell_size / plan.wave_speed, "grid" if dt_pred == critical.grid else "tunnel")


def cracked(state) -> bool:
    """Whether a crack particle still holds a bond: then the crack particles' own limit applies."""
    return bool(len(state.particle_crack)) and bool(np.any((state.particle_crack == 1) & (state.particle_damage < 1)))


def total_energy(solver, state, floor: float) -> float:
    """Kinetic + strain + gravitational energy (height measured along -g from the domain's lowest corner) [J]."""
    m = solver.model
    g = np.asarray(m.gravity, dtype=float)
    potential = -float(m.particle_mass @ (state.particle_x @ g)) - floor * float(m.particle_mass.sum())
    return solver.kinetic_energy(state) + solver.strain_energy(state) + potential


def run_case(case: Case, dt_factor: float | None = None, ready: Prepared | None = None) -> dict:
    """Run one case with the automatic step, or (dt_factor) a forced step of dt_factor times the predicted limit
    of the starting state (the crack particles' own limit included while one holds a bond), and classify it.
    Returns one row of the sweep table."""
    from pdmpm_cli.engine.solver import Solver, pin_speed

    row = {"case": case.name, "category": case.category, "parameter": case.parameter,
           "forced": dt_factor is not None, "dt_factor": dt_factor}
    t0 = time.perf_counter()
    try:
        ready = ready or prepare_case(case)
    except (InputError, ValidationError) as e:
        message = " ".join(str(e).split())[:160]
        return row | {"class": "refused", "message": message, "wall_s": time.perf_counter() - t0}
    prep, plan = ready.prep, ready.prep.plan
    duration = case.steps * plan.dt_max
    state = copy.deepcopy(ready.state)
    if dt_factor is not None:
        # The one place a step above the bound is taken: a copy of the Plan, flagged in every row.
        plan = dataclasses.replace(plan, dt_max=math.inf, dt_cfl=math.inf, frame_dt=math.inf)
        duration = max(duration, FORCED_STEPS * dt_factor * ready.dt_pred)
    solver = Solver(prep.model, plan)
    solver.start(state)
    if dt_factor is not None:
        solver.step_size = lambda: dt_factor * ready.critical.predicted(ready.v0, cracked(state))
    g = np.asarray(prep.model.gravity, dtype=float)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
    lo, hi = np.asarray(prep.scene.grid.domain.min), np.asarray(prep.scene.grid.domain.max)
    floor = float(np.min(-(lo + corners * (hi - lo)) @ g))
    e0 = total_energy(solver, state, floor)
    mass = float(prep.model.particle_mass.sum())
    em = prep.model.emitter
    if em is not None:  # born particles bring their kinetic energy and their height above the floor
        e0 += em.particles * em.mass * (0.5 * float(em.velocity @ em.velocity) - float(em.layer.mean(axis=0) @ g)
                                        - floor)
    ref = max(e0, 0.5 * mass * pin_speed(prep.model) ** 2, 1e-12 * mass)  # a moving pin drags the body along
    ratio, last, vmax, cells, steps, dt_top, message, cls = 1.0, 1.0, ready.v0, 0.0, 0, 0.0, "", "stable"

    def substep(st, dt):
        nonlocal vmax, cells, steps, dt_top
        steps += 1
        dt_top = max(dt_top, dt)
        vmax = max(vmax, state.vmax)
        cells = max(cells, state.vmax * dt / plan.cell_size)
        if solver.kinetic_energy(st) > GROWTH * ref:  # cheap, every step: a transient between frames counts too
            raise Growth(f"kinetic energy {solver.kinetic_energy(st) / ref:.3g}x the starting total at step {st.step}")

    try:
        for k in range(1, FRAMES + 1):
            solver.advance(state, duration * k / FRAMES, substep)
            e = total_energy(solver, state, floor)
            last = e / ref if math.isfinite(e) else math.inf
            ratio = max(ratio, last)
            if not math.isfinite(e):
                cls = "nan"
                break
            if ratio > GROWTH:
                cls, message = "energy", f"total energy {ratio:.3g}x its start at t = {state.time:.4g} s"
                break
    except Growth as e:
        cls, message, ratio = "energy", str(e), math.inf
    except ArithmeticError as e:  # a kernel divided by zero: a crash, reported as the case's class
        cls, message = "error", f"{type(e).__name__}: {e}"
    except SimulationError as e:
        message = str(e).split(";")[0]
        finite = np.isfinite(state.particle_x).all() and np.isfinite(state.particle_v).all()
        cls = "nan" if not finite else "outside" if "left the simulation domain" in message else "energy"
    isolated = 0  # particles with no intact bond left
    if len(state.bond_active):
        owner = np.repeat(np.arange(prep.disc.n_particles), np.diff(state.bond_start))
        isolated = int((np.bincount(owner, weights=state.bond_active, minlength=prep.disc.n_particles) == 0).sum())
    return row | {
        "class": cls, "energy_ratio": ratio, "energy_end": last, "max_speed": vmax, "cells_per_step": cells,
        "steps": steps, "dt_max": dt_top, "dt_pred": ready.dt_pred, "dt_ratio": dt_top / ready.dt_wave,
        "dt_bond": ready.dt_bond,
        "particles": solver.model.n_particles, "isolated": isolated, "time": state.time, "message": message,
        "wall_s": time.perf_counter() - t0,
    }


def threshold(case: Case, lo: float = LO, hi: float = HI, bisections: int = BISECTIONS, on_run=None) -> dict:
    """Largest stable constant step in units of the predicted bound, by geometric bisection in [lo, hi].

    A bracket end on the wrong side moves out by factors of 2 (at most 4 times) before the bisection. `measured` is
    the largest stable factor found (0 if none was) and `unstable` the smallest unstable one (inf if none);
    `on_run(row)` sees every forced run."""
    ready = prepare_case(case)
    plan = ready.prep.plan
    runs = []

    def stable(k):
        row = run_case(case, k, ready)
        runs.append(row)
        if on_run:
            on_run(row)
        return row["class"] == "stable"

    low_ok = stable(lo)
    moved = False
    for _ in range(4):
        if low_ok:
            break
        hi, lo, moved = lo, lo / 2, True
        low_ok = stable(lo)
    high_ok = low_ok and not moved and stable(hi)
    for _ in range(4):
        if not high_ok:
            break
        lo, hi = hi, hi * 2
        high_ok = stable(hi)
    bracketed = low_ok and not high_ok
    if bracketed:
        for _ in range(bisections):
            mid = math.sqrt(lo * hi)
            lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    measured = lo if low_ok else 0.0
    crit = ready.critical
    return {"case": case.name, "category": case.category, "parameter": case.parameter, "dt_pred": ready.dt_pred,
            "dt_grid": crit.grid, "dt_particles": crit.particles,
            "dt_tunnel": crit.tunnel_depth / ready.v0 if ready.v0 > 0 else math.inf, "dt_bond": ready.dt_bond,
            "dt_auto": plan.dt_max, "bound": ready.bound,
            "measured": measured, "unstable": hi if bracketed else math.inf if low_ok else lo, "bracketed": bracketed,
            "within_2x": bracketed and 0.5 <= measured <= 2.0, "runs": len(runs),
            "bond_units": measured * ready.dt_pred / ready.dt_bond,
            "wave_units": measured * ready.dt_pred / ready.dt_wave,
            "margin": measured * ready.dt_pred / min(plan.dt_max, plan.dt_cfl * plan.wave_speed
                                                     / (plan.wave_speed + ready.v0)),
            "v0_cells": ready.v0 * measured * ready.dt_pred / plan.cell_size,
            "failure": next((r["class"] for r in runs if r["class"] != "stable"), "")}
