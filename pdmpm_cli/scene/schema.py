"""Scene schema: what a scene YAML file may say, with SI units on every field.

The models are frozen and forbid unknown keys, so a misspelt key is an error (reported with its file
position by `pdmpm_cli.scene.loader`). Field descriptions feed `pdmpm schema`. Geometry shapes, body
geometry modes, materials and colliders are discriminated unions keyed by `type`, `mode` and `model`.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal, Union

from pydantic import Field, ValidationError, ValidationInfo, field_validator, model_validator
from pydantic_core import InitErrorDetails, PydanticCustomError

from pdmpm_cli.engine.materials import MATERIALS
from pdmpm_cli.spec import Strict, Vec3

MAX_FRAMES = 100_000  # duration x fps; an hour at 30 fps is 108,000 frames of output per particle
CFL = {"conservative": 0.4, "auto": 0.25}  # default CFL factor of each step rule (docs/method.md, 'Time step')


# ---------------------------------------------------------------- shapes


class Placed(Strict):
    center: Vec3 = Field(description="Centre of the shape in world coordinates [m].")
    rotation: Vec3 = Field(
        (0.0, 0.0, 0.0),
        description="Rotation about the x, y then z axes through the centre [degrees].",
    )


class BoxShape(Placed):
    type: Literal["box"]
    size: Vec3 = Field(description="Full edge lengths along the local x, y, z axes [m].")

    @model_validator(mode="after")
    def _positive(self):
        if min(self.size) <= 0:
            raise ValueError(f"size must be positive in every axis (got {list(self.size)})")
        return self


class SphereShape(Strict):
    type: Literal["sphere"]
    center: Vec3 = Field(description="Centre [m].")
    radius: float = Field(gt=0, description="Radius [m].")


class CylinderShape(Placed):
    type: Literal["cylinder"]
    radius: float = Field(gt=0, description="Radius [m].")
    height: float = Field(gt=0, description="Full length along the local z axis [m].")


class CapsuleShape(Placed):
    type: Literal["capsule"]
    radius: float = Field(gt=0, description="Radius of the cylinder and the end caps [m].")
    length: float = Field(ge=0, description="Distance between the two cap centres, along local z [m].")


class MeshFit(Strict):
    """Place a mesh by size, as the built-in bunny's height and center: the mesh (after units, scale and rotation)
    is scaled uniformly so that its bounding box has this size, and moved so that the box's centre is `center`."""

    size: float = Field(gt=0, description="Length of the bounding box along `axis` after fitting [m].")
    axis: Literal["x", "y", "z", "longest"] = Field(
        "longest", description="Which edge of the bounding box `size` sets: x, y, z or the longest one [-].")
    center: Vec3 = Field(description="Centre of the fitted bounding box in world coordinates [m].")


class MeshShape(Strict):
    """A closed surface mesh file. Its coordinates become metres as x = R (units * scale * x_file) + translate
    (R the rotation about the file's origin), or, with `fit`, scaled and moved to a given size and centre."""

    type: Literal["mesh"]
    path: str = Field(description="Mesh file relative to the scene file: OBJ (with texture and normal indices, "
                                  "groups, materials, polygons), STL (ascii or binary), PLY, OFF, glTF/GLB, "
                                  "VTK/VTU.")
    units: Literal["m", "cm", "mm"] = Field(
        "m", description="Length unit of the file's coordinates (CAD files are often in mm); converted to metres "
                         "before scale [-].")
    scale: float | Vec3 = Field(
        1.0, description="Scale factor applied to the file's coordinates after units: one number, or one per axis "
                         "[x, y, z] [-].")
    translate: Vec3 = Field((0.0, 0.0, 0.0), description="Translation applied after scale and rotation [m].")
    rotation: Vec3 = Field((0.0, 0.0, 0.0), description="Rotation about x, y then z through the origin [degrees].")
    fit: MeshFit | None = Field(
        None, description="Fit the mesh to a size and centre instead of translating it (see MeshFit); absent: the "
                          "file's coordinates as they are (after units, scale, rotation and translate).")

    @model_validator(mode="after")
    def _placement(self):
        factors = (self.scale,) if isinstance(self.scale, (int, float)) else self.scale
        if min(factors) <= 0:
            raise ValueError(f"scale must be positive (got {self.scale})")
        if self.fit is not None and any(self.translate):
            raise ValueError("give translate or fit (whose center places the mesh), not both")
        return self


class BunnyShape(Placed):
    """The procedural bunny shipped with pdmpm (pdmpm_cli.geometry.bunny): sits upright (+y), faces +x."""

    type: Literal["bunny"]
    height: float = Field(gt=0, description="Total height of the bunny, feet to ear tips [m].")


class SheetShape(Placed):
    """An open flat rectangle (a cloth), only for `mode: shell`; its normal is the local +z axis."""

    type: Literal["sheet"]
    size: tuple[float, float] = Field(description="Full edge lengths along the local x and y axes [m].")

    @model_validator(mode="after")
    def _positive(self):
        if min(self.size) <= 0:
            raise ValueError(f"size must be positive in both axes (got {list(self.size)})")
        return self


Shape = Annotated[
    Union[BoxShape, SphereShape, CylinderShape, CapsuleShape, MeshShape, BunnyShape], Field(discriminator="type")
]
Surface = Annotated[
    Union[SheetShape, BoxShape, SphereShape, CylinderShape, CapsuleShape, MeshShape, BunnyShape],
    Field(discriminator="type"),
]


# ---------------------------------------------------------------- geometry modes


class CloudGeometry(Strict):
    """Particle-cloud mode: fill a closed shape with material points."""

    mode: Literal["cloud"]
    shape: Shape
    spacing: float | None = Field(
        None, gt=0, description="Particle spacing h [m]; default half the grid cell size (8 particles per cell)."
    )
    sampling: Literal["relaxed", "jittered", "lattice"] = Field(
        "relaxed",
        description="'relaxed': the jittered points after Lloyd steps towards a centroidal Voronoi tessellation "
        "(blue noise: isotropic and evenly spaced, default); 'jittered': one random point per lattice cell "
        "(isotropic, but clumps make thin bodies about 30 % soft); 'lattice': cell centres (exactly symmetric "
        "families, but anisotropic stiffness).",
    )
    horizon: float = Field(
        2.0, gt=1.0, le=4.0, description="Peridynamic horizon delta as a multiple of the spacing h [-]."
    )
    cutouts: list[Shape] = Field(
        default_factory=list, description="Shapes removed from the body (notches, holes): particles inside any "
        "of them are not created, and no bond crosses them.",
    )


class ShellGeometry(Strict):
    """Shell mode (paper section 7): material points on a surface and in layers under it along the inward
    normal. layers = 1 is a cloth (open surfaces allowed). The surface's vertices ride along with the points
    and are written per frame as an animated mesh."""

    mode: Literal["shell"]
    surface: Surface
    spacing: float | None = Field(
        None, gt=0, description="Particle spacing h on the surface and between layers [m]; default half the grid "
        "cell size.")
    layers: int = Field(1, ge=1, le=64, description="Number of particle layers: 1 is a cloth on the surface; "
                        "N > 1 fills the shell between the surface and depth N h (layer k at depth (k + 1/2) h) [-].")
    horizon: float = Field(
        2.0, gt=1.0, le=4.0, description="Peridynamic horizon delta as a multiple of the spacing h [-].")
    edge: float | None = Field(
        None, gt=0, description="Longest edge of the triangles written as the animated mesh [m]; default the "
        "spacing. Built-in surfaces (sheet, box, sphere, ...) are triangulated at it; a mesh file's longer edges are "
        "split (its shape is kept, its vertices keep their numbers), so that the surface bends with the particles.")


class VoronoiGeometry(Strict):
    """Voronoi mode (paper section 7): seeds inside a convex shape, Voronoi cells clipped to it; each cell's
    centroid is a material point with the cell's volume, and bonds join cells that share a face, so broken
    bonds follow cell faces. The cell polyhedra are written per frame, moving with their points."""

    mode: Literal["voronoi"]
    shape: Shape
    spacing: float | None = Field(
        None, gt=0, description="Seed spacing [m]: one seed per cell of a jittered lattice (cells of about "
        "spacing^3). Default half the grid cell size when `count` is not given either.")
    count: int | None = Field(
        None, ge=2, description="Number of uniformly random seeds instead of a spacing (more varied cell sizes) [-].")
    resolution: int = Field(
        48, ge=8, le=512, description="Curved shapes (sphere, cylinder, capsule) are replaced by an inscribed "
        "polytope with about this many facets around a circle [-].")

    @model_validator(mode="after")
    def _one(self):
        if self.spacing is not None and self.count is not None:
            raise ValueError("give at most one of spacing (m) and count")
        return self


Geometry = Annotated[Union[CloudGeometry, ShellGeometry, VoronoiGeometry], Field(discriminator="mode")]


# ---------------------------------------------------------------- materials


# Each material's section is its own module's Schema (engine/materials); the registry lists them.
Material = Annotated[Union[tuple(kind.schema for kind in MATERIALS.values())], Field(discriminator="model")]


class Fracture(Strict):
    """Fracture by fracture planes (paper section 6, eq. 21). Give exactly one of `threshold` (the paper's critical
    strain, fixed: the energy a crack absorbs then changes with the horizon) and `energy` (a fracture energy, from
    which each body's threshold follows with its stiffness and horizon, so a crack costs the same at every
    resolution)."""

    threshold: float | None = Field(
        None, gt=0, description="Critical bond strain: a bond fails when (stretch - e_p) / (1 + p_inactive) exceeds "
        "it (eq. 21; Table 1: 0.05 for the broken board) [-].")
    energy: float | None = Field(
        None, gt=0, description="Critical energy release rate G_c, the energy a crack absorbs per unit area "
        "[J/m^2]. The threshold becomes s0 = sqrt(4 G_c / (3 M delta)) with M the P-wave modulus lam + 2 mu and "
        "delta the horizon: the energy of every bond crossing a unit area at s0 (docs/method.md, 'Fracture "
        "energy'); `pdmpm validate --explain` prints it.")
    damage_resistance: float | None = Field(
        None, ge=0, description="Weight k of p_inactive in eq. 21, l = (stretch - e_p) / (1 + k p_inactive): 1 is the "
        "paper (a cell that already holds broken bonds resists further breaking); 0 lets a started crack cut through "
        "(a wall hit hard breaks into pieces instead of stalling in bands of partial damage). Default: 1 with a "
        "`threshold`, 0 with an `energy` (p_inactive counts per grid cell, so it would change a crack's cost with "
        "the resolution: docs/method.md, 'Fracture energy') [-].")

    @model_validator(mode="after")
    def _one_criterion(self):
        if (self.threshold is None) == (self.energy is None):
            raise ValueError("give exactly one of threshold (a critical strain [-], the paper's) and energy (a "
                             "fracture energy G_c [J/m^2], the same crack at every resolution)")
        return self


# ---------------------------------------------------------------- bodies


class Pin(Strict):
    """Held particles (a clamp, a clothes peg): they move with `velocity` and ignore forces. Give a `region`, or
    for shell bodies `vertices` of the surface mesh (the particles within one spacing of them are held). With
    `stop`, the pin moves until that time and then holds still where it is (a peg carried to its place, a gripper
    that pulls and stops): it travels velocity * stop."""

    region: Shape | None = Field(None, description="Particles inside this shape are held.")
    vertices: list[int] | None = Field(
        None, min_length=1, description="Shell bodies: indices (0-based) of surface-mesh vertices to hold.")
    velocity: Vec3 = Field((0.0, 0.0, 0.0), description="Prescribed velocity of the pinned particles [m/s].")
    stop: float | None = Field(
        None, gt=0, description="Time at which the pin stops moving and holds still from then on [s]; absent: it "
        "moves with `velocity` for the whole run.")

    @model_validator(mode="after")
    def _one(self):
        if (self.region is None) == (self.vertices is None):
            raise ValueError("give exactly one of region (a shape) and vertices (surface-mesh vertex indices)")
        return self

    @model_validator(mode="after")
    def _stop_moves(self):
        if self.stop is not None and not any(self.velocity):
            raise ValueError(f"stop: {self.stop} s ends the motion of a pin that does not move (velocity is 0); "
                             "give the pin a velocity, or leave out stop")
        return self


class Emitter(Strict):
    """Particles born over time from a nozzle (a liquid poured from a bottle's neck). The lattice points of the body's
    spacing h inside `shape` form one layer of N particles of volume h^3; a layer is born every N h^3 / rate seconds
    from `start` to `stop`, so the emitted volume is rate x time by construction. The layer must clear the nozzle
    before the next one is born: rate at most N h^3 |v| / T, T the layer's thickness along the velocity (a disc one
    spacing thick: rate <= N h^2 |v|, the nozzle's area times the speed)."""

    shape: Shape = Field(description="Nozzle region, e.g. a cylinder one spacing high across the stream: the body's "
                         "lattice points inside it form one layer of born particles.")
    velocity: Vec3 = Field(description="Velocity of the born particles, out of the nozzle [m/s].")
    rate: float = Field(gt=0, description="Volume emitted per second [m^3/s].")
    start: float = Field(0.0, ge=0, description="Time of the first layer [s].")
    stop: float | None = Field(None, gt=0, description="No layer is born after this time [s]; absent: the end of "
                               "the run.")

    @model_validator(mode="after")
    def _leaves(self):
        if math.hypot(*self.velocity) == 0.0:
            raise ValueError("velocity is zero: born particles would never leave the nozzle; give the stream's "
                             "velocity out of it [m/s]")
        if self.stop is not None and self.stop <= self.start:
            raise ValueError(f"stop ({self.stop:g} s) must be after start ({self.start:g} s)")
        return self


class Body(Strict):
    name: str = Field(description="Name of the body, used in messages and outputs.")
    geometry: Geometry
    material: Material
    velocity: Vec3 = Field((0.0, 0.0, 0.0), description="Initial linear velocity [m/s].")
    angular_velocity: Vec3 = Field(
        (0.0, 0.0, 0.0), description="Initial angular velocity about the body's centre of mass [rad/s]."
    )
    pins: list[Pin] = Field(default_factory=list, description="Regions of held particles.")
    fracture: Fracture | None = Field(
        None, description="Fracture thresholds; absent: bonds never break (no damage arrays or fracture pass).")
    emitter: Emitter | None = Field(
        None, description="Particles born over time from a nozzle, joining this body (viscoelastic cloud bodies); "
        "absent: the body keeps its initial particles.")

    @model_validator(mode="after")
    def _emitting_liquid(self):
        if self.emitter is not None and self.material.model != "viscoelastic":
            raise ValueError("an emitter needs a viscoelastic body, whose families are rebuilt as particles arrive; "
                             f"this body is {self.material.model}")
        return self

    @model_validator(mode="after")
    def _viscoelastic_cloud(self):
        if self.material.model == "viscoelastic" and self.geometry.mode != "cloud":
            raise ValueError("viscoelastic bodies rebuild their bonds as they flow, so no mesh can ride along: use "
                             "geometry.mode: cloud")
        return self

    @model_validator(mode="after")
    def _vertex_pins(self):
        if self.geometry.mode != "shell" and any(p.vertices is not None for p in self.pins):
            raise ValueError("pins by vertices need a shell body (geometry.mode: shell); use a pin region here")
        return self

    @model_validator(mode="after")
    def _fracture_solid(self):
        if self.fracture is not None and self.material.model == "viscoelastic":
            raise ValueError("fracture applies to elastic and plastic bodies; viscoelastic bodies break bonds by "
                             "material.break_stretch instead")
        return self


# ---------------------------------------------------------------- colliders


BoundaryKind = Literal["sticky", "slip", "separate"]


class ColliderBase(Strict):
    boundary: Literal["sticky", "slip", "separate", "clamped"] = Field(
        "separate",
        description="'sticky': material takes the collider's velocity; 'slip': no normal motion, "
        "tangential sliding with friction; 'separate': like slip but material may leave the surface; 'clamped' "
        "(planes only, CPU backend): material fixed to the plane, as sticky at the plane itself, while the grid "
        "nodes behind it take the velocity mirrored across it instead of the plane's, so that a clamped end does not "
        "damp a body's vibration (a sticky end's nodes zero the velocity the particles extrapolate through it every "
        "step: a bar clamped by a sticky wall loses 2-4 points more of its amplitude per period).",
    )
    friction: float = Field(0.0, ge=0, description="Coulomb friction coefficient [-].")
    velocity: Vec3 = Field((0.0, 0.0, 0.0), description="Constant velocity of the collider [m/s].")
    response: Literal["auto", "projection", "penalty"] = Field(
        "auto", description="projection: grid nodes inside the collider lose the velocity that approaches it "
        "(Stomakhin et al. 2013), an inelastic impact of the nodes' masses: an elastic ball dropped on a floor "
        "rebounds to 22-31 % of its height. penalty (boundary separate, simulation.flip 0): each particle whose "
        "material touches the surface (its centre within half a spacing) is pushed out by an elastic force "
        "`stiffness` x m c^2 / dx^2 per metre of overlap (c its body's P-wave speed), with Coulomb friction, so the "
        "work of an impact comes back (the same ball: 82 %); nodes and particles more than two cells inside still "
        "take the projection. auto (default): penalty for boundary separate with simulation.flip 0, else "
        "projection.")
    stiffness: float = Field(1.0, gt=0, le=4, description="response penalty: the push per particle, in units of "
                             "m c^2 / dx^2 per metre of overlap; softer keeps more of an impact's energy and lets the "
                             "material sink deeper (the ball: 89 % at 0.5, 82 % at 1, 72 % at 2) [-].")

    @model_validator(mode="after")
    def _clamped_planes(self):
        if self.boundary == "clamped" and self.type != "plane":
            raise ValueError(f"boundary: clamped mirrors the grid across a plane and is for plane colliders only; "
                             f"use sticky for a {self.type}")
        return self

    @model_validator(mode="after")
    def _penalty_separates(self):
        if self.response == "penalty" and self.boundary != "separate":
            raise ValueError(f"response: penalty pushes material out and lets it leave, which is boundary: separate; "
                             f"set boundary: separate or response: projection (boundary is {self.boundary})")
        return self


class PlaneCollider(ColliderBase):
    type: Literal["plane"]
    point: Vec3 = Field(description="A point on the plane [m].")
    normal: Vec3 = Field(description="Normal pointing into the free side [-] (normalised on load).")

    @model_validator(mode="after")
    def _normal(self):
        if sum(c * c for c in self.normal) == 0:
            raise ValueError("normal must not be the zero vector")
        return self


class BoxCollider(ColliderBase):
    type: Literal["box"]
    center: Vec3 = Field(description="Centre [m].")
    size: Vec3 = Field(description="Full edge lengths (axis-aligned) [m].")
    inside_out: bool = Field(False, description="True: material is kept inside the box (a container).")


class SphereCollider(ColliderBase):
    type: Literal["sphere"]
    center: Vec3 = Field(description="Centre at time 0 [m].")
    radius: float = Field(gt=0, description="Radius [m].")
    inside_out: bool = Field(False, description="True: material is kept inside the sphere.")


class CylinderCollider(ColliderBase):
    type: Literal["cylinder"]
    center: Vec3 = Field(description="Centre at time 0 [m].")
    axis: Vec3 = Field((0.0, 1.0, 0.0), description="Axis direction [-] (normalised on load).")
    radius: float = Field(gt=0, description="Radius [m].")
    height: float = Field(gt=0, description="Full length along the axis [m].")
    inside_out: bool = Field(False, description="True: material is kept inside the cylinder (a tube or cup).")


class MeshCollider(ColliderBase, MeshShape):
    """A closed surface mesh file as a collider, placed as a mesh body's shape is (units, scale, rotation,
    translate or fit). Its level set is the mesh's signed distance sampled at half the grid cell."""

    inside_out: bool = Field(False, description="True: material is kept inside the mesh (a closed container, as a "
                                                "bottle's inner surface); false: outside it (a solid bowl's walls).")


Collider = Annotated[
    Union[PlaneCollider, BoxCollider, SphereCollider, CylinderCollider, MeshCollider], Field(discriminator="type")
]


# ---------------------------------------------------------------- run settings


class Simulation(Strict):
    duration: float = Field(gt=0, description="Simulated time [s].")
    fps: float = Field(30.0, gt=0, description="Output frames per simulated second [1/s].")
    dt: float | None = Field(
        None, gt=0, description="Maximum time step [s]; reduced (with a warning) where above the stability bound."
    )
    step: Literal["auto", "conservative"] = Field(
        "conservative",
        description="Time-step rule. conservative: dt <= cfl dx / (wave speed + max speed) and bond_safety times the "
                    "peridynamic bond bound of every body (about 0.15 dx / wave speed) [-]. auto: the same CFL bound, "
                    "and the bond bound of fracture bodies only (their crack particles integrate bonds off the grid); "
                    "grid-integrated bodies are stable to 1.4-2 dx / wave speed. docs/method.md, 'Time step'."
    )
    cfl: float | None = Field(
        None, gt=0, le=1.0,
        description=f"CFL factor: dt <= cfl dx / (wave speed + max speed) [-]; default {CFL['conservative']:g} "
                    f"with step conservative, {CFL['auto']:g} with step auto."
    )
    bond_safety: float = Field(
        0.7, gt=0, le=1.0, description="Safety factor on the peridynamic bond time-step bound [-]."
    )
    seed: int = Field(0, ge=0, description="Seed of the random particle sampling [-].")
    flip: float = Field(
        0.0, ge=0, le=1.0,
        description="FLIP share of the particle update [-]. 0 (APIC): a particle's new velocity and affine matrix are "
                    "the grid's, which filters them at every transfer and damps elastic motion. Above 0: the grid's "
                    "plus this share of what the particle carried and the grid did not (Fei et al. 2021), and "
                    "particles move with their new velocities mapped back to the grid (MUSL, one more transfer per "
                    "step, about half again the time); 1 keeps the energy of elastic motion, with more particle-level "
                    "noise; a ball dropped on a rigid floor rebounds to 81 % of its height at 1, 22 % at 0. "
                    "docs/method.md, 'FLIP share and MUSL', has the measurements."
    )
    backend: Literal["cpu", "cuda"] = Field(
        "cpu", description="Where the step runs: cpu (Numba, all threads) or cuda (one NVIDIA GPU through numba.cuda; "
                           "every material and fracture; not an emitter). `pdmpm run --backend` overrides it."
    )

    precision: Literal["float64", "float32"] = Field(
        "float64",
        description="Storage precision of the per-particle and per-bond float arrays [-]. float32 stores velocities, "
                    "APIC matrices, forces, damage, bond weights, plastic strains and viscoelastic bond forces in "
                    "single precision: 5-18 % less memory (the grids stay float64); on the CPU no faster; results "
                    "within about 1e-6 of float64's, more where fracture or a flow amplifies round-off (1-2 %). "
                    "Positions, 1 / |xi|, Fbar, a liquid's volume ratio, the grids, energies and all arithmetic stay "
                    "float64 (a step's move v dt is below float32's resolution of a position). docs/method.md, "
                    "'Precision'; docs/results.md, 'float32'."
    )

    @field_validator("fps")
    @classmethod
    def _frames(cls, fps: float, info: ValidationInfo) -> float:
        duration = info.data.get("duration")
        if duration is not None and duration * fps > MAX_FRAMES:
            raise ValueError(f"{duration:g} s at {fps:g} frames/s is {duration * fps:.3g} frames, more than "
                             f"{MAX_FRAMES:,}; lower fps (at most {MAX_FRAMES / duration:.3g} for this duration)")
        return fps


class Wind(Strict):
    """A uniform wind: linear drag pulling material towards the wind velocity, a = drag (velocity - v)."""

    velocity: Vec3 = Field(description="Wind velocity [m/s].")
    drag: float = Field(gt=0, description="Drag rate: 1 / the time the wind takes to bring light material to "
                                          "its speed [1/s].")


class Domain(Strict):
    min: Vec3 = Field(description="Lower corner of the simulation box [m].")
    max: Vec3 = Field(description="Upper corner of the simulation box [m].")


class Grid(Strict):
    cell_size: float = Field(gt=0, description="Background grid cell size dx [m].")
    domain: Domain
    boundary: BoundaryKind = Field("separate", description="Condition on the domain walls (see colliders).")
    friction: float = Field(0.0, ge=0, description="Coulomb friction on the domain walls [-].")

    @model_validator(mode="after")
    def _cells(self):
        ext = [b - a for a, b in zip(self.domain.min, self.domain.max)]
        if min(ext) <= 0:
            raise ValueError(f"domain.max must exceed domain.min in every axis (extent {ext})")
        cells = [e / self.cell_size for e in ext]
        if min(cells) < 8:
            raise ValueError(
                f"the domain spans only {min(cells):.1f} cells in one axis; use at least 8 (smaller cell_size)"
            )
        if cells[0] * cells[1] * cells[2] > 2.0e8:
            raise ValueError("the grid would have more than 2e8 cells; use a larger cell_size or a smaller domain")
        return self


# Per-frame fields: the engine's, and those the registered materials compute (plastic strain, ...).
FieldName = Literal[("particle_v", "particle_speed", "particle_C", "particle_force", "particle_Fbar", "particle_damage",
                     *(name for kind in MATERIALS.values() for name in kind.outputs))]


class ContactPair(Strict):
    bodies: tuple[str, str] = Field(description="Names of the two bodies (from bodies[].name) this entry is for.")
    friction: float = Field(ge=0, description="Coulomb friction coefficient between these two bodies [-]: while "
                            "they press together, the tangential impulse is at most this times the normal one.")


class Contact(Strict):
    """How bodies meet. `separate` (default): each body moves on its own grid velocity field; where bodies meet,
    they cannot pass into each other, slide with Coulomb friction and come apart freely. `shared`: all bodies
    share one grid field, so touching bodies stick and move together where they overlap on the grid (the paper's
    single-grid MPM). A one-body scene has no contact either way."""

    mode: Literal["separate", "shared"] = Field(
        "separate", description="separate: a grid field per body, with contact between them; shared: one grid "
        "field for all bodies (they weld where they touch).")
    friction: float = Field(0.0, ge=0, description="Coulomb friction coefficient between any two bodies that no "
                            "`pairs` entry names [-] (0: frictionless).")
    pairs: list[ContactPair] = Field(default_factory=list,
                                     description="Friction of particular body pairs, overriding `friction`.")
    model: Literal["auto", "penalty", "projection"] = Field(
        "auto", description="penalty: where the fields' materials overlap at a node, an elastic force pushes them "
        "apart (its work comes back as they separate: two elastic spheres keep 73 % of their kinetic energy at 10 "
        "particle spacings in radius); APIC only (simulation.flip 0). projection: where two fields meet and "
        "approach, the approaching one loses its normal velocity relative to their centre of mass (Bardenhagen et "
        "al. 2000; an inelastic impact of the nodes' masses: the same spheres keep 44 %). auto (default): penalty "
        "with simulation.flip 0, projection with a FLIP share.")
    cracks: Literal["auto", "separate", "shared"] = Field(
        "auto", description="separate: at every node near a crack or notch (`fracture`, `cutouts`), the material on "
        "its two sides moves on two grid fields, with contact between them (damage-field partitioning after Homel & "
        "Herbold 2017, the sides told apart by the broken and cut bonds and, once a body has come apart, by piece), "
        "so no force crosses an open crack and the crack particles stay on the grid; CPU backend. shared: the paper's "
        "one field per body, with crack particles integrated off the grid (section 6): the grid couples material up "
        "to two cells across a gap and bridges a notch narrower than that. auto (default): separate where it "
        "applies (a field per body or a single body, on the CPU), else shared.")
    stiffness: float = Field(2.0, gt=0, description="penalty: the contact stiffness at a node, in units of "
                             "c^2 m_red / dx^2 (c the pair's larger P-wave speed, m_red the reduced mass of the two "
                             "fields at the node); 4 makes the interface about as stiff as one cell of the material "
                             "[-].")


class Output(Strict):
    hdf5: bool = Field(True, description="Write one HDF5 file (run.h5) with every frame.")
    vtk: bool = Field(True, description="Write a VTU file per frame and a .pvd index for ParaView.")
    meshes: bool = Field(True, description="Shell and Voronoi bodies: write their moving surface or cell "
                                           "polyhedra as one PLY file per frame (meshes/<body>_NNNNN.ply); fluid "
                                           "(viscoelastic) bodies their reconstructed surface "
                                           "(meshes/<body>_surface_NNNNN.ply).")
    usd: bool = Field(False, description="Write one USD file (run.usd: metres, +y up, a time sample per frame) with "
                                         "each body's particles as points (width, velocities, the fields below as "
                                         "primvars) and its shell surface or Voronoi cells as an animated mesh, for "
                                         "Houdini, Blender or Omniverse. Needs usd-core (pip install usd-core).")
    fields: list[FieldName] = Field(
        default_factory=lambda: ["particle_v", "particle_speed"],
        description="Per-frame fields besides particle_x (always written).",
    )
    compression: Literal["none", "lzf", "gzip"] = Field("lzf", description="HDF5 dataset compression.")
    checkpoint_every: int = Field(
        10, ge=0, description="Save the complete simulation state every this many frames (OUTDIR/checkpoints, the "
        "two newest kept, removed when the run finishes) so `pdmpm run --resume OUTDIR` continues a killed run; "
        "0: never [frames].")


class Camera(Strict):
    """A fixed viewpoint for `pdmpm render`."""

    position: Vec3 = Field(description="Camera position [m].")
    focus: Vec3 = Field(description="Point the camera looks at [m].")
    up: Vec3 = Field((0.0, 1.0, 0.0), description="Up direction of the image [-].")
    view_angle: float = Field(30.0, gt=0, lt=180, description="Vertical field of view [degrees].")

    @model_validator(mode="after")
    def _direction(self):
        view = [f - p for p, f in zip(self.position, self.focus)]
        length = math.hypot(*view)
        if length == 0:
            raise ValueError(f"position and focus are the same point {list(self.position)}: the camera has no "
                             f"direction to look in; move the position away from the focus")
        up = math.hypot(*self.up)
        side = math.hypot(*(self.up[i] * view[(i + 1) % 3] - self.up[(i + 1) % 3] * view[i] for i in range(3)))
        if up == 0 or side <= 1e-6 * up * length:
            raise ValueError(f"up {list(self.up)} is zero or along the view direction {[round(v, 6) for v in view]}: "
                             f"the image has no up; give an up direction across the view, e.g. [0, 1, 0] or "
                             f"[0, 0, 1]")
        return self


class RenderSettings(Strict):
    """Defaults for `pdmpm render`; its command-line options override them."""

    camera: Camera | None = Field(
        None, description="Viewpoint; absent: a 3/4 view framing the particles over all frames.")
    field: Literal["speed", "damage", "plastic", "body"] = Field(
        "speed", description="Colour by: particle speed [m/s], damage [-], plastic strain [-] or body index.")
    resolution: tuple[int, int] = Field(
        (1280, 720), description="Image width and height [px].")

    @model_validator(mode="after")
    def _positive(self):
        if min(self.resolution) < 16:
            raise ValueError(f"resolution must be at least 16 x 16 px (got {list(self.resolution)})")
        return self


class Scene(Strict):
    """A pdmpm scene: run settings, grid, bodies, colliders and outputs."""

    name: str = Field("scene", description="Name shown in progress and stored in outputs.")
    description: str = Field("", description="Free text: what the scene shows.")
    simulation: Simulation
    grid: Grid
    gravity: Vec3 = Field((0.0, -9.81, 0.0), description="Gravitational acceleration [m/s^2].")
    bodies: list[Body] = Field(min_length=1, description="Deformable bodies.")
    colliders: list[Collider] = Field(default_factory=list, description="Kinematic level-set colliders.")
    wind: Wind | None = Field(None, description="Uniform wind acting on all material on the grid; absent: none.")
    contact: Contact = Field(default_factory=Contact, description="Contact between bodies: separate grid fields "
                             "(default) or one shared field, and the friction between them.")
    output: Output = Field(default_factory=Output)
    render: RenderSettings = Field(
        default_factory=RenderSettings, description="Defaults for `pdmpm render` (camera, colour field, image size).")
    variants: dict[str, dict[str, Any]] = Field(
        default_factory=dict, description="Named sets of overrides, each a mapping 'dotted.key: value' as in --set "
        "(e.g. soft: {bodies.0.material.mu: 2.0e4}); `pdmpm run scene.yaml --variant soft` applies one.")

    @field_validator("bodies")
    @classmethod
    def _resolved(cls, bodies: list[Body], info: ValidationInfo) -> list[Body]:
        """A particle spacing above the cell leaves cells inside the body without particles: holes in the
        grid's quadrature (MPM wants about 2 particles per cell per axis, the default spacing)."""
        grid = info.data.get("grid")
        if grid is None:
            return bodies
        dx, errors = grid.cell_size, []
        for i, body in enumerate(bodies):
            h = getattr(body.geometry, "spacing", None)
            if h is not None and h > dx and body.geometry.mode != "voronoi":
                message = (f"{h:g} m is larger than the grid cell ({dx:g} m): cells inside the body would hold no "
                           f"particle; use at most {dx:g} m, or leave spacing out for {dx / 2:g} m (2 particles per "
                           f"cell per axis)")
                errors.append(InitErrorDetails(type=PydanticCustomError("spacing_above_cell", message),
                                               loc=(i, "geometry", "spacing"), input=h))
        if errors:
            raise ValidationError.from_exception_data(cls.__name__, errors)
        return bodies

    @field_validator("contact")
    @classmethod
    def _contact_bodies(cls, contact: Contact, info: ValidationInfo) -> Contact:
        """Each friction pair names two different bodies of the scene, and no pair twice."""
        bodies = info.data.get("bodies")
        if bodies is None:
            return contact
        names, errors, seen = [b.name for b in bodies], [], set()
        for i, pair in enumerate(contact.pairs):
            a, b = pair.bodies
            unknown = [n for n in (a, b) if n not in names]
            if unknown:
                message = f"no body is named {', '.join(map(repr, unknown))}; the bodies are {', '.join(names)}"
            elif a == b:
                message = f"a pair needs two different bodies (got {a!r} twice); a body has no contact with itself"
            elif frozenset((a, b)) in seen:
                message = f"the pair {a!r}, {b!r} is listed twice; keep one entry"
            else:
                seen.add(frozenset((a, b)))
                continue
            errors.append(InitErrorDetails(type=PydanticCustomError("contact_pair", message),
                                           loc=("pairs", i, "bodies"), input=list(pair.bodies)))
        if errors:
            raise ValidationError.from_exception_data(cls.__name__, errors)
        return contact

    @model_validator(mode="after")
    def _emitter_last(self):
        """Born particles are appended to the arrays, so the emitting body's range stays contiguous only if it is
        the last body."""
        emitting = [i for i, b in enumerate(self.bodies) if b.emitter is not None]
        if emitting and emitting != [len(self.bodies) - 1]:
            raise ValueError(f"only the last body may have an emitter (born particles are appended after every other "
                             f"particle); move body '{self.bodies[emitting[0]].name}' to the end of the list, and "
                             f"give at most one body an emitter")
        return self

    @model_validator(mode="after")
    def _unique_names(self):
        names = [b.name for b in self.bodies]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"body names must be unique (repeated: {', '.join(dup)})")
        return self
