"""Contact between bodies: the figures of docs/results.md ('Contact between bodies').

Usage: python bench/contact.py [spheres|rebound|sliding|passing|cost|all] [--radius 5 10] [--steps 20]
- spheres: two identical elastic spheres (radius in particle spacings, spacing half a cell) meeting head-on at
  `--closing` (default 0.05) of the P-wave speed (tests/contact_cases.py): where contact starts relative to the
  geometric touch, the smallest gap, momentum, kinetic energy after over before, separation; with a field per body
  (the penalty, the default with APIC, and the projection) and one shared field. `--stiffness 0.5 1 2 4` runs the
  penalty alone at each contact.stiffness; `--step 0.4 0.8` forces the step to those multiples of dx / c (the
  number of transfers, against APIC's loss).
- rebound: an elastic ball (radius in spacings) dropped 0.1 m on a rigid, frictionless floor collider: rebound
  height over drop height (e^2; 1 for an elastic impact), with APIC (simulation.flip 0) and FLIP shares;
  `--response penalty` the floor's penalty response instead (APIC only) at each `--stiffness` (default 1).
- sliding: a block sliding on an elastic slab with friction 0.3 and 0: deceleration against mu g (both models);
  then a block sliding on a penalty floor collider (deceleration, and how deep its particles sank).
- passing: two blocks half a cell apart, one sliding past the other: momentum the resting one picks up.
- cost: time per step of the sphere pair with one field per body against one shared field, by phase.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pdmpm_cli.study.sim import Sim  # noqa: E402
from tests import contact_cases as C  # noqa: E402


def spheres(radii, closing: float, stiffnesses, steps):
    runs = [("penalty", k) for k in stiffnesses] or [(m, None) for m in ("projection", "penalty", "shared")]
    print(f"Closing at {closing:g} of the P-wave speed.")
    print("| radius [spacings] | fields | contact.stiffness | step [dx/c] | particles | steps | "
          "contact starts at gap [cells] | smallest gap [cells] | momentum change | KE after / before | "
          "energy after / before | gap at end [cells] | wall [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in radii:
        for (mode, k), step in ((run, step) for run in runs for step in steps):
            o = C.sphere_collision(r, closing, mode=mode, stiffness=k, step=step)
            gap = "none" if o["contact_gap"] is None else f"{o['contact_gap']:+.2f}"
            stiff = "-" if mode != "penalty" else "default" if k is None else f"{k:g}"
            forced = "Plan's" if step is None else f"{step:g}"
            print(f"| {r:g} | {mode} | {stiff} | {forced} | {o['particles']} | {o['steps']} | {gap} | "
                  f"{o['smallest_gap']:+.2f} | {o['momentum']:.1e} | {100 * o['ke']:.1f} % | "
                  f"{100 * o['energy']:.1f} % | "
                  f"{o['apart']:+.2f} | {o['seconds']:.0f} |", flush=True)


def rebound(radii, flips, response="projection", stiffnesses=()):
    print("| radius [spacings] | simulation.flip | floor response | stiffness | particles | steps | rebound / drop "
          "height | wall [s] |")
    print("|---|---|---|---|---|---|---|---|")
    runs = [(f, None) for f in flips] if response == "projection" else [(0.0, k) for k in (stiffnesses or [1.0])]
    for r in radii:
        for flip, k in runs:
            o = C.ball_drop(r, flip=flip, response=response, stiffness=k)
            print(f"| {r:g} | {flip:g} | {response} | {'-' if k is None else f'{k:g}'} | {o['particles']} | "
                  f"{o['steps']} | {o['rebound']:.3f} | {o['seconds']:.0f} |", flush=True)


def sliding():
    print("| contact model | friction | deceleration [m/s^2] | / (mu g) | speed at 0.15 s / v0 |")
    print("|---|---|---|---|---|")
    for mode in ("projection", "penalty"):
        for mu in (0.3, 0.0):
            o = C.sliding(mu, mode=mode)
            ratio = f"{o['deceleration'] / (mu * C.G):.4f}" if mu else "-"
            print(f"| {mode} | {mu:g} | {o['deceleration']:.4f} | {ratio} | "
                  f"{o['v'][-1]:.5f} |", flush=True)
    print("\nOn a penalty floor collider:\n")
    print("| friction | deceleration [m/s^2] | / (mu g) | speed at 0.15 s / v0 | deepest particle below the floor "
          "[cells] |")
    print("|---|---|---|---|---|")
    for mu in (0.3, 0.0):
        o = C.floor_slide(mu)
        ratio = f"{o['deceleration'] / (mu * C.G):.4f}" if mu else "-"
        print(f"| {mu:g} | {o['deceleration']:.4f} | {ratio} | {o['v'][-1]:.5f} | {o['deepest']:.3f} |", flush=True)


def passing():
    print("| fields | momentum picked up / m v0 | moving block's speed / v0 |")
    print("|---|---|---|")
    for mode in ("projection", "penalty", "shared"):
        o = C.passing(mode)
        print(f"| {mode} | {o['picked_up']:.2e} | {o['speed']:.5f} |", flush=True)


def cost(radii, steps: int):
    print("| radius [spacings] | particles | fields | step [ms] | p2g | grid_update | contact | g2p | forces |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in radii:
        for mode in ("shared", "separate"):
            sim = Sim(C.sphere_pair(r, mode=mode))
            sim.solver.clock = time.process_time  # a busy machine: CPU time of this process
            dt = sim.plan.dt_max
            for _ in range(3):  # warm-up: compiled kernels loaded
                sim.solver.substep(sim.state, dt)
            sim.solver.phase_time.clear()
            t0 = time.process_time()
            for _ in range(steps):
                sim.solver.substep(sim.state, dt)
            per = 1e3 * (time.process_time() - t0) / steps
            pt = {k: 1e3 * v / steps for k, v in sim.solver.phase_time.items()}
            forces = sum(v for k, v in pt.items() if k not in ("p2g", "grid_update", "contact", "g2p"))
            print(f"| {r:g} | {sim.model.n_particles} | {'one per body' if mode == 'separate' else 'one'} | "
                  f"{per:.2f} | {pt.get('p2g', 0):.2f} | {pt.get('grid_update', 0):.2f} | "
                  f"{pt.get('contact', 0):.2f} | {pt.get('g2p', 0):.2f} | {forces:.2f} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", nargs="?", default="all",
                    choices=["spheres", "rebound", "sliding", "passing", "cost", "all"])
    ap.add_argument("--radius", type=float, nargs="+", default=[5.0, 10.0], help="sphere radius [spacings]")
    ap.add_argument("--flip", type=float, nargs="+", default=[0.0, 0.95, 0.99, 1.0], help="FLIP shares (rebound)")
    ap.add_argument("--steps", type=int, default=20, help="steps timed per cost row")
    ap.add_argument("--closing", type=float, default=0.05, help="closing speed over the P-wave speed (spheres)")
    ap.add_argument("--stiffness", type=float, nargs="*", default=[],
                    help="penalty contact.stiffness values (spheres; none: the three models at their defaults)")
    ap.add_argument("--response", choices=["projection", "penalty"], default="projection",
                    help="rebound: the floor collider's response")
    ap.add_argument("--step", type=float, nargs="+", default=[None],
                    help="spheres: force the step to these multiples of dx / c (default: the Plan's)")
    args = ap.parse_args()
    np.set_printoptions(precision=4)
    if args.what in ("spheres", "all"):
        spheres(args.radius, args.closing, args.stiffness, args.step)
    if args.what in ("rebound", "all"):
        rebound(args.radius, args.flip, args.response, args.stiffness)
    if args.what in ("sliding", "all"):
        sliding()
    if args.what in ("passing", "all"):
        passing()
    if args.what in ("cost", "all"):
        cost(args.radius, args.steps)


if __name__ == "__main__":
    main()
