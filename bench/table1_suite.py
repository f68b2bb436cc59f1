"""Time to solution: every bundled Table 1 scene at its shipped resolution, as a user would run it.

Usage: python bench/table1_suite.py [--scenes cloth:soft beams ...] [--set simulation.duration=0.1] [--ref REV]

Prints one markdown table: per scene the particles and bonds, the steps taken, the set-up (sampling, bonds) and
simulation wall seconds, nanoseconds per particle-step, the mean step used and the predicted stable limit at the
start (engine.spectrum, as `pdmpm validate --limits` prints it), and the total. Each scene runs in its own process
(a warm-up of two steps first, so compiling or loading the Numba cache is not counted; frame writing is left out:
it is off the critical path). With --ref REV the same scenes run, in turn with ours, on commit REV checked out in a
temporary git worktree, and the table gains the ratio REV / ours of the simulation time: a speed-up measured in one
sitting on one machine. --set applies scene overrides to every scene (e.g. a shorter duration for a quick look).
"""

import argparse
import copy
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = ("cloth:soft", "cloth:medium", "cloth:stiff", "beams", "board_elastic", "board_plastic", "bunnies_elastic",
          "bunnies_plastic", "wall_break", "honey", "cream_pie")


def measure(scene: str, overrides: list[str]) -> dict:
    """Run one scene (name[:variant]) of the checkout this process imports pdmpm_cli from; one JSON row."""
    import numpy as np

    from pdmpm_cli.engine.spectrum import critical_steps
    from pdmpm_cli.runner import prepare, start_in_memory

    name, _, variant = scene.partition(":")
    t0 = time.perf_counter()
    prep = prepare(Path("scenes") / f"{name}.yaml", overrides, variant or None)
    state, solver = start_in_memory(prep)
    setup = time.perf_counter() - t0
    v0 = float(np.linalg.norm(state.particle_v, axis=1).max()) if len(state.particle_v) else 0.0
    limit = critical_steps(solver, state).predicted(v0, False)
    warm = copy.deepcopy(state)  # a throw-away copy for the compile warm-up
    for _ in range(2):
        solver.substep(warm, prep.plan.dt_max)
    solver.start(state)
    steps0, t0 = state.step, time.perf_counter()
    solver.advance(state, prep.plan.frames * prep.plan.frame_dt)
    wall = time.perf_counter() - t0
    n, steps = prep.disc.n_particles, state.step - steps0
    return {"scene": scene, "particles": n, "bonds": int(prep.plan.bonds), "steps": steps, "setup_s": setup,
            "wall_s": wall, "ns_per_particle_step": 1e9 * wall / max(n * steps, 1),
            "dt_mean": state.time / max(steps, 1), "dt_limit": limit}


def run_scene(checkout: Path, scene: str, overrides) -> dict:
    """One scene in its own process, importing pdmpm_cli from `checkout`: its row, or its error."""
    sets = [a for o in overrides for a in ("--set", o)]
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", scene, *sets], cwd=checkout,
                         env=dict(os.environ, PYTHONPATH=str(checkout)), capture_output=True, text=True)
    row = (json.loads(out.stdout.strip().splitlines()[-1]) if out.returncode == 0
           else {"scene": scene, "error": (out.stderr.strip().splitlines() or ["?"])[-1]})
    print(f"  {checkout.name}: {scene} {row.get('wall_s', row.get('error'))}", file=sys.stderr, flush=True)
    return row


def table(ours: dict, ref: dict | None, ref_name: str) -> str:
    cols = ["scene", "particles", "bonds", "steps", "set-up [s]", "simulation [s]", "ns / particle-step",
            "mean dt [s]", "predicted limit [s]", "limit / dt"]
    if ref is not None:
        cols += [f"{ref_name} simulation [s]", f"speed-up over {ref_name}"]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    total, total_ref = 0.0, 0.0
    for scene, r in ours.items():
        if "error" in r:
            lines.append(f"| {scene} | failed: {r['error']} |")
            continue
        total += r["wall_s"]
        cells = [scene, r["particles"], r["bonds"], r["steps"], f"{r['setup_s']:.1f}", f"{r['wall_s']:.1f}",
                 f"{r['ns_per_particle_step']:.0f}", f"{r['dt_mean']:.3g}", f"{r['dt_limit']:.3g}",
                 f"{r['dt_limit'] / r['dt_mean']:.1f}"]
        if ref is not None:
            b = ref.get(scene, {})
            if "wall_s" in b:
                total_ref += b["wall_s"]
                cells += [f"{b['wall_s']:.1f}", f"{b['wall_s'] / r['wall_s']:.2f}"]
            else:
                cells += ["failed", ""]
        lines.append("| " + " | ".join(map(str, cells)) + " |")
    summary = f"\ntotal simulation time: {total:.1f} s"
    if ref is not None and total > 0:
        summary += f"; {ref_name}: {total_ref:.1f} s; speed-up {total_ref / total:.2f}"
    return "\n".join(lines) + summary


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), help="scene[:variant] names (default: all)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="scene override for every scene")
    ap.add_argument("--ref", help="also run the suite on this git revision (a temporary worktree) in turn")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(measure(args.child, args.overrides)))
        return
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # still remove the reference worktree
    ours, ref = {}, None
    with tempfile.TemporaryDirectory(prefix="pdmpm-ref-") as tmp:
        if args.ref:
            ref_dir = Path(tmp) / args.ref.replace("/", "_")
            subprocess.run(["git", "worktree", "add", "--detach", str(ref_dir), args.ref], cwd=ROOT, check=True,
                           capture_output=True)
            ref = {}
        try:
            for scene in args.scenes:  # in turn, so a drift in the machine's speed hits both alike
                ours[scene] = run_scene(ROOT, scene, args.overrides)
                if ref is not None:
                    ref[scene] = run_scene(ref_dir, scene, args.overrides)
        finally:
            if args.ref:
                subprocess.run(["git", "worktree", "remove", "--force", str(ref_dir)], cwd=ROOT, capture_output=True)
    print(table(ours, ref, args.ref or ""))


if __name__ == "__main__":
    main()
