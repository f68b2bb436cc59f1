"""What a material is to the engine: one MaterialKind per module, listed once in the registry (materials/__init__).

A material module holds everything about its material: its scene section (`Schema`, a pydantic model whose
fields carry their SI units), its typed parameters (`params(section)`: a frozen dataclass the kernels read), the
per-particle and per-bond arrays it needs (declared once as `Field`s: allocated, checkpointed and carried through
family rebuilds from that declaration), its per-particle formulae with their CPU loops (`Kernel`s, which the CUDA
backend compiles for the GPU from the same source), its hooks in the step, its outputs and its effective constants.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from pdmpm_cli.engine.fields import Field


@dataclass(frozen=True, eq=False)
class MaterialKind:
    """One material: hooks are fn(solver, body, dt) with body an index into solver.model.bodies; kernels read the
    backend's arrays (solver.a) and launch through solver.backend.run(kernel, start, end, *args)."""

    name: str  # the scene's `model:` value
    schema: type  # pydantic model of the scene's `material:` section (model: Literal[name], density, ...)
    params: Callable[[Any], Any]  # validated section -> typed parameters (frozen dataclass of floats)
    forces: Callable  # writes solver.a.particle_force over the body's particles (eqs. 2, 7)
    constants: Callable[[Any], dict]  # params -> effective isotropic constants (p_wave_modulus, wave_speed, ...)
    energy: Callable | None = None  # (solver, body) -> stored strain energy [J] on the host State (Fbar current)
    fields: tuple[Field, ...] = ()  # the material's own arrays
    bond_forces: Callable | None = None  # the forces alone, for Solver.bond_forces (the stiffness probes), where
    # `forces` also does other work of the step (the plastic return map); None: forces
    before_forces: Callable | None = None  # e.g. the plastic dilatations
    after_forces: Callable | None = None  # e.g. rebuilding the families of a flowing body
    after_move: Callable | None = None  # after the particles moved (G2P), e.g. a liquid's particle shift
    moves: Callable[[Any], bool] = lambda params: True  # whether after_move has work for a body with these params
    # (the Plan lists its phase, and the solver calls it, only for those bodies)
    start: Callable | None = None  # (solver, body): initial values of its arrays, on the host State
    born: Callable | None = None  # (solver, state, body, first): values of particles first.. an emitter just
    # appended (families with their neighbours), on the host State; None: the material cannot be emitted
    outputs: dict[str, Callable] = field(default_factory=dict)  # frame field name -> fn(model, state) -> array
    uses_fbar: Callable[[Any], bool] = lambda params: False  # whether its forces read Fbar (eq. 4)
    reads_grid_density: Callable[[Any], bool] = lambda params: False  # whether its after_move reads the grid's mass
    # density at each particle (particle_rho, which G2P then gathers)
    flows: bool = False  # its families are rebuilt from current neighbours: no reference frame a crack's sides can
    # be told in (engine/crack.py leaves it out)
    computes_fbar: bool = False  # its before_forces computes its Fbar itself, with its own sums over the same bonds
    # (plastic: the dilatations), so the step's fbar phase leaves it out (Solver.bond_forces' does not)
    with_flow_speed: Callable[[Any, float], Any] | None = None  # (params, largest expected flow speed [m/s]) ->
    # params with the defaults that depend on the scene (a liquid's bulk modulus); None: params need no scene
    runs_as: Callable[[Any], str] | None = None  # section -> the registry entry that runs it (a plastic body that
    # can never yield runs as elastic); None: itself
