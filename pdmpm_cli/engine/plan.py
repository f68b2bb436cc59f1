"""What a run will do and allocate, decided once before any step (pdmpm_cli.plan.make_plan decides it from a scene).

The Solver reads the switches (`fbar`, `fracture`, `contact`, `remap`) and never tests a material's type: a step a scene does not
need is absent. `phases` lists the step's phases for people (`pdmpm validate --explain`, run.h5)."""

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class BodyPlan:
    name: str
    model: str  # registry entry the body runs (a plastic body that cannot yield runs as elastic)
    particles: int
    bonds: int
    spacing: float  # h [m]
    horizon: float  # delta [m]
    effective: dict  # effective isotropic constants of the calibration [Pa, -, m/s]
    dt_bond: float  # bond bound, before the safety factor [s]
    fracture_threshold: float | None = None  # eq. 21 threshold the body breaks at (given or from its energy) [-]
    fracture_energy: float | None = None  # fracture energy G_c it came from [J/m^2]
    damage_resistance: float | None = None  # weight k of p_inactive in eq. 21 [-]
    crack_fields: bool = False  # its cracks and notches split its grid field in two (engine/crack.py)


@dataclass(frozen=True)
class Plan:
    phases: tuple[str, ...]
    fields: dict  # name -> (shape, dtype) of every per-particle, per-bond or grid array the run allocates
    bodies: tuple[BodyPlan, ...]
    particles: int
    bonds: int
    grid_nodes: tuple[int, int, int]
    cell_size: float
    frames: int
    frame_dt: float
    dt_user: float | None
    step: str  # simulation.step: conservative (bond bound of every body) or auto (of fracture bodies only)
    dt_cfl: float  # cfl dx / wave speed, at rest [s]
    dt_bond: float  # bond_safety * min of the bond bound over the particles the rule bounds; inf if none [s]
    dt_max: float  # the largest step the solver will take [s]
    binding: str  # which bound sets dt_max: user, cfl, bonds or frame
    dt_reduced: bool  # the user's dt was above a bound and was reduced
    wave_speed: float  # fastest P-wave speed over bodies [m/s]
    memory_bytes: int
    notes: tuple[str, ...] = ()  # what loading changed in the input (a flipped mesh, welded vertices)
    backend: str = "cpu"  # simulation.backend: cpu or cuda
    fbar: bool = False  # some body's forces read Fbar (eq. 4)
    fracture: bool = False  # some body can fracture (section 6): crack particles and the fracture pass
    contact: bool = False  # one grid field per body and the contact pass between them (engine/contact.py)
    remap: bool = False  # a FLIP share: FLIP grid channels and MUSL's position pass (engine/transfer.py: advect_at)
    precision: str = "float64"  # simulation.precision: the dtype of the per-particle and per-bond float arrays in
    # `fields` (engine.fields: Field.dtype_for)
    emitted: int = 0  # particles an emitter bears over the run (engine.emitter), after the initial `particles`: the
    # layers due before the end (one due within the last step's span is not born, so this bounds the count)

    @property
    def capacity(self) -> int:
        """The most particles the run holds: the initial ones and every one an emitter bears."""
        return self.particles + self.emitted

    def to_dict(self) -> dict:
        return asdict(self)

    def warnings(self) -> list[str]:
        out = list(self.notes)
        if self.dt_reduced:
            out.append(f"simulation.dt = {self.dt_user:.3g} s is above the stability bound; using {self.dt_max:.3g} s "
                       f"(CFL bound {self.dt_cfl:.3g} s, bond bound {self.dt_bond:.3g} s, step {self.step})")
        return out
