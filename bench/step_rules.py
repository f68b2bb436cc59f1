"""Step of each Table 1 scene (scenes/*.yaml) under each step rule (simulation.step, simulation.cfl): the step in
dx / c, the binding bound and the steps over the scene's duration (at the at-rest step, so a lower bound).
Run: NUMBA_NUM_THREADS=1 python bench/step_rules.py (discretisation only, no stepping; docs/results.md,
'The step rule')."""

from pathlib import Path

from pdmpm_cli.runner import prepare

RULES = (("conservative", None), ("auto", 0.2), ("auto", 0.25), ("auto", 0.3), ("auto", 0.4))


def main():
    for scene in sorted(Path("scenes").glob("*.yaml")):
        row = []
        for rule, cfl in RULES:
            plan = prepare(scene, [f"simulation.step={rule}"] + ([f"simulation.cfl={cfl}"] if cfl else []), None).plan
            steps = plan.frames * plan.frame_dt / plan.dt_max
            row.append(f"{plan.dt_max * plan.wave_speed / plan.cell_size:.3f} {plan.binding} {steps:.0f}")
        print(f"{scene.stem:16s} " + " | ".join(row), flush=True)


if __name__ == "__main__":
    main()
