"""`pdmpm validate`: check a scene without running it; `--explain` prints the Plan."""

from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from pdmpm_cli.cli.options import SceneArg, SetOpt, VariantOpt


def validate(
    scene: SceneArg,
    set_: SetOpt = [],
    variant: VariantOpt = None,
    explain: Annotated[bool, typer.Option("--explain", help="Print the Plan: phases, arrays, dt bounds, counts.")] = False,
    limits: Annotated[bool, typer.Option(
        "--limits", help="Also predict the largest stable step (linear stability of the grid and crack-particle "
        "operators at the start; costs tens of force evaluations).")] = False,
):
    """Validate a scene file: schema, geometry, bonds, memory and output size. Exit code 2 on any problem."""
    from pdmpm_cli.scene.loader import load_scene
    from pdmpm_cli.scene.schema import Scene

    load_scene(scene, Scene, set_, variant)  # bad input is refused before the engine loads

    from pdmpm_cli.budget import gib, output_bytes, warnings
    from pdmpm_cli.runner import prepare

    console = Console(highlight=False, emoji=False, soft_wrap=True)
    prep = prepare(scene, set_, variant)
    if prep.scene.output.usd:
        from pdmpm_cli.io.usd import require

        require()
    plan = prep.plan
    for w in [*plan.warnings(), *warnings(prep)]:
        console.print(f"[yellow]warning:[/] {escape(w)}")
    born = f" + {plan.emitted} emitted" if plan.emitted else ""
    console.print(f"{escape(str(scene))}: OK ({plan.particles} particles{born}, {plan.bonds} bonds, {plan.frames} "
                  f"frames; arrays {gib(plan.memory_bytes)}, output about {gib(output_bytes(prep))})")
    if explain:
        print_plan(console, plan)
    if limits:
        print_limits(console, prep)


def print_limits(console: Console, prep):
    """The predicted stability limits (engine.spectrum) beside the step the Plan takes."""
    from pdmpm_cli.engine.spectrum import critical_steps
    from pdmpm_cli.runner import start_in_memory

    plan = prep.plan
    state, solver = start_in_memory(prep)
    crit = critical_steps(solver, state)
    wave = plan.cell_size / plan.wave_speed
    table = Table(title="predicted stability limits (largest stable constant step)")
    table.add_column("limit")
    table.add_column(escape("value [s]"), justify="right")
    table.add_column(escape("[dx / c]"), justify="right")
    table.add_column(escape("/ step used"), justify="right")
    rows = {"grid, 2 / omega_max": crit.grid, "crack particles, 2 / omega_max": crit.particles}
    if state.vmax > 0:
        rows[f"tunnelling, {crit.tunnel_depth:.3g} m / initial speed"] = crit.tunnel_depth / state.vmax
    for label, value in rows.items():
        table.add_row(escape(label), f"{value:.4g}", f"{value / wave:.3g}", f"{value / plan.dt_max:.3g}")
    console.print(table)


def print_plan(console: Console, plan):
    console.print(f"phases per step: {' -> '.join(plan.phases)}")
    console.print(f"backend: {plan.backend}")
    bodies = Table(title="bodies")
    bodies.add_column("")
    for b in plan.bodies:
        bodies.add_column(b.name, justify="right")
    rows = {
        "model": [b.model for b in plan.bodies],
        "particles": [str(b.particles) for b in plan.bodies],
        "bonds per particle": [f"{b.bonds / max(b.particles, 1):.1f}" for b in plan.bodies],
        "spacing h [m]": [f"{b.spacing:.4g}" for b in plan.bodies],
        "horizon delta [m]": [f"{b.horizon:.4g}" for b in plan.bodies],
        "E_eff [Pa]": [f"{b.effective['youngs_modulus']:.4g}" for b in plan.bodies],
        "nu_eff": [f"{b.effective['poisson_ratio']:.3g}" for b in plan.bodies],
        "P-wave speed [m/s]": [f"{b.effective['wave_speed']:.4g}" for b in plan.bodies],
        "bond dt bound [s]": [f"{b.dt_bond:.3g}" for b in plan.bodies],
    }
    if any(b.fracture_threshold is not None for b in plan.bodies):
        rows["fracture energy G_c [J/m^2]"] = ["-" if b.fracture_energy is None else f"{b.fracture_energy:.4g}"
                                               for b in plan.bodies]
        rows["fracture threshold [-]"] = ["-" if b.fracture_threshold is None else f"{b.fracture_threshold:.4g}"
                                          for b in plan.bodies]
        rows["damage resistance k [-]"] = ["-" if b.damage_resistance is None else f"{b.damage_resistance:g}"
                                           for b in plan.bodies]
    if any(b.fracture_threshold is not None or b.crack_fields for b in plan.bodies):
        rows["crack fields (contact.cracks)"] = ["separate" if b.crack_fields else "shared" for b in plan.bodies]
    for label, values in rows.items():
        bodies.add_row(escape(label), *values)
    console.print(bodies)
    steps = Table(title="time step")
    steps.add_column("bound")
    steps.add_column(escape("value [s]"), justify="right")
    steps.add_row("user dt", "-" if plan.dt_user is None else f"{plan.dt_user:.4g}")
    steps.add_row(f"CFL (at rest; {plan.dt_cfl * plan.wave_speed / plan.cell_size:.3g} dx / c)", f"{plan.dt_cfl:.4g}")
    steps.add_row("bonds (x safety, " + ("every body)" if plan.step == "conservative" else "fracture bodies)"),
                  "-" if plan.dt_bond == float("inf") else f"{plan.dt_bond:.4g}")
    steps.add_row("frame", f"{plan.frame_dt:.4g}")
    steps.add_row(f"used (max; rule: {plan.step}; binding: {plan.binding}; "
                  f"{plan.dt_max * plan.wave_speed / plan.cell_size:.3g} dx / c)", f"{plan.dt_max:.4g}")
    steps.add_row("substeps per frame (>=)", f"{plan.frame_dt / plan.dt_max:.1f}")
    console.print(steps)
    arrays = Table(title=f"arrays ({plan.memory_bytes / 2**20:.1f} MiB, precision {plan.precision})")
    arrays.add_column("field")
    arrays.add_column("shape", justify="right")
    arrays.add_column("dtype")
    for name, (shape, dtype) in plan.fields.items():
        arrays.add_row(name, " x ".join(map(str, shape)), dtype)
    console.print(arrays)
    console.print(f"grid: {' x '.join(map(str, plan.grid_nodes))} nodes, cell {plan.cell_size:.4g} m")
