"""Scene schema: what a scene YAML file may say, with SI units on every field.

The models are frozen and forbid unknown keys, so a misspelt key is an error (reported with its file
position by `pdmpm_cli.scene.loader`). Field descriptions feed `pdmpm schema`. Geometry shapes, body
geometry modes, materials and colliders are discriminated unions keyed by `type`, `mode` and `model`.
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, model_validator

Vec3 = tuple[float, float, float]


class Strict(BaseModel):
    """Base for every scene model: immutable, unknown keys rejected."""

    model_config = ConfigDict(extra="forbid", frozen=True)


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


class MeshShape(Strict):
    type: Literal["mesh"]
    path: str = Field(description="Closed surface mesh readable by meshio (OBJ, STL, PLY, OFF, VTK...), "
                                  "relative to the scene file.")
    scale: float = Field(1.0, gt=0, description="Uniform scale applied to the mesh's vertices [-].")
    translate: Vec3 = Field((0.0, 0.0, 0.0), description="Translation applied after scale and rotation [m].")
    rotation: Vec3 = Field((0.0, 0.0, 0.0), description="Rotation about x, y then z through the origin [degrees].")


Shape = Annotated[
    Union[BoxShape, SphereShape, CylinderShape, CapsuleShape, MeshShape], Field(discriminator="type")
]


# ---------------------------------------------------------------- geometry modes


class CloudGeometry(Strict):
    """Particle-cloud mode: fill a closed shape with material points."""

    mode: Literal["cloud"]
    shape: Shape
    spacing: float | None = Field(
        None, gt=0, description="Particle spacing h [m]; default half the grid cell size (8 particles per cell)."
    )
    sampling: Literal["jittered", "lattice"] = Field(
        "jittered",
        description="'jittered': one random point per lattice cell (statistically isotropic bonds, default); "
        "'lattice': cell centres (exactly symmetric families, but anisotropic stiffness).",
    )
    horizon: float = Field(
        2.0, gt=1.0, le=4.0, description="Peridynamic horizon delta as a multiple of the spacing h [-]."
    )


Geometry = Annotated[Union[CloudGeometry], Field(discriminator="mode")]


# ---------------------------------------------------------------- materials


class ElasticMaterial(Strict):
    """Elastic peridynamic bonds (paper eqs. 5-7). See docs/method.md for the calibration to E and nu."""

    model: Literal["elastic"]
    density: float = Field(gt=0, description="Mass density rho [kg/m^3].")
    lam: float = Field(ge=0, description="Lame's first parameter lambda: isotropic (bond-stretch) term [Pa].")
    mu: float = Field(ge=0, description="Shear modulus mu: deviatoric (averaged-deformation) term [Pa].")

    @model_validator(mode="after")
    def _stiff(self):
        if self.lam + 2 * self.mu <= 0:
            raise ValueError("lam + 2 mu must be positive: a material with no stiffness cannot hold its shape")
        return self


Material = Annotated[Union[ElasticMaterial], Field(discriminator="model")]


# ---------------------------------------------------------------- bodies


class Pin(Strict):
    """Particles inside `region` are held: they move with `velocity` and ignore forces."""

    region: Shape
    velocity: Vec3 = Field((0.0, 0.0, 0.0), description="Prescribed velocity of the pinned particles [m/s].")


class Body(Strict):
    name: str = Field(description="Name of the body, used in messages and outputs.")
    geometry: Geometry
    material: Material
    velocity: Vec3 = Field((0.0, 0.0, 0.0), description="Initial linear velocity [m/s].")
    angular_velocity: Vec3 = Field(
        (0.0, 0.0, 0.0), description="Initial angular velocity about the body's centre of mass [rad/s]."
    )
    pins: list[Pin] = Field(default_factory=list, description="Regions of held particles.")


# ---------------------------------------------------------------- colliders


BoundaryKind = Literal["sticky", "slip", "separate"]


class ColliderBase(Strict):
    boundary: BoundaryKind = Field(
        "separate",
        description="'sticky': material takes the collider's velocity; 'slip': no normal motion, "
        "tangential sliding with friction; 'separate': like slip but material may leave the surface.",
    )
    friction: float = Field(0.0, ge=0, description="Coulomb friction coefficient [-].")
    velocity: Vec3 = Field((0.0, 0.0, 0.0), description="Constant velocity of the collider [m/s].")


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


Collider = Annotated[
    Union[PlaneCollider, BoxCollider, SphereCollider, CylinderCollider], Field(discriminator="type")
]


# ---------------------------------------------------------------- run settings


class Simulation(Strict):
    duration: float = Field(gt=0, description="Simulated time [s].")
    fps: float = Field(30.0, gt=0, description="Output frames per simulated second [1/s].")
    dt: float | None = Field(
        None, gt=0, description="Maximum time step [s]; reduced (with a warning) where above the stability bound."
    )
    cfl: float = Field(0.4, gt=0, le=1.0, description="CFL factor: dt <= cfl dx / (wave speed + max speed) [-].")
    bond_safety: float = Field(
        0.7, gt=0, le=1.0, description="Safety factor on the peridynamic bond time-step bound [-]."
    )
    seed: int = Field(0, ge=0, description="Seed of the random particle sampling [-].")


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


FieldName = Literal["particle_v", "particle_speed", "particle_C", "particle_force", "particle_Fbar"]


class Output(Strict):
    hdf5: bool = Field(True, description="Write one HDF5 file (run.h5) with every frame.")
    vtk: bool = Field(True, description="Write a VTU file per frame and a .pvd index for ParaView.")
    fields: list[FieldName] = Field(
        default_factory=lambda: ["particle_v", "particle_speed"],
        description="Per-frame fields besides particle_x (always written).",
    )
    compression: Literal["none", "lzf", "gzip"] = Field("lzf", description="HDF5 dataset compression.")


class Scene(Strict):
    """A pdmpm scene: run settings, grid, bodies, colliders and outputs."""

    name: str = Field("scene", description="Name shown in progress and stored in outputs.")
    description: str = Field("", description="Free text: what the scene shows.")
    simulation: Simulation
    grid: Grid
    gravity: Vec3 = Field((0.0, -9.81, 0.0), description="Gravitational acceleration [m/s^2].")
    bodies: list[Body] = Field(min_length=1, description="Deformable bodies.")
    colliders: list[Collider] = Field(default_factory=list, description="Kinematic level-set colliders.")
    output: Output = Field(default_factory=Output)

    @model_validator(mode="after")
    def _unique_names(self):
        names = [b.name for b in self.bodies]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"body names must be unique (repeated: {', '.join(dup)})")
        return self
