"""Time to solution: every bundled Table 1 scene at its shipped resolution, as a user would run it.

Usage: python bench/table1_suite.py [--scenes cloth:soft beams ...] [--set simulation.duration=0.1] [--ref REV|DIR]
                                   [--cpu-time] [--phases]

Prints one markdown table: per scene the particles and bonds, the steps taken, the set-up (sampling, bonds) and
simulation wall seconds, nanoseconds per particle-step, the mean step used and the predicted stable limit at the
start (engine.spectrum, as `pdmpm validate --limits` prints it), and the total. Each scene runs in its own process
(a warm-up of two steps first, so compiling or loading the Numba cache is not counted; frame writing is left out:
it is off the critical path). With --ref REV the same scenes run, in turn with ours, on commit REV checked out in a
temporary git worktree (or, given a directory, on the checkout there, e.g. a `git worktree` of an older commit),
and the table gains the ratio REV / ours of the simulation time: a speed-up measured in one sitting on one machine.
--set applies scene overrides to every scene (e.g. a shorter duration for a quick look). --cpu-time times in
process CPU seconds (steadier on a shared machine; with NUMBA_NUM_THREADS=1 the single-core cost). --phases adds a
table per checkout of each scene's step split into its parts (solver.phase_time), in ns per particle-step. An
emitter's particle count grows: particle-steps are counted step by step.
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


def measure(scene: str, overrides: list[str], clock=time.perf_counter) -> dict:
    """Run one scene (name[:variant]) of the checkout this process imports pdmpm_cli from; one JSON row."""
    import numpy as np

    from pdmpm_cli.engine.spectrum import critical_steps
    from pdmpm_cli.runner import prepare, start_in_memory

    name, _, variant = scene.partition(":")
    t0 = clock()
    prep = prepare(Path("scenes") / f"{name}.yaml", overrides, variant or None)
    state, solver = start_in_memory(prep)
    setup = clock() - t0
    v0 = float(np.linalg.norm(state.particle_v, axis=1).max()) if len(state.particle_v) else 0.0
    limit = critical_steps(solver, state).predicted(v0, False)
    # the compile warm-up on throw-away copies of both: an emitter's births grow the model's bodies too
    warm_state, warm_solver = copy.deepcopy((state, solver))
    for _ in range(2):
        warm_solver.substep(warm_state, prep.plan.dt_max)
    solver.start(state)
    solver.clock = clock
    solver.phase_time.clear()
    work = [0]  # particle-steps, counted per step (an emitter adds particles)

    def count(st, _dt):
        work[0] += len(st.particle_x)

    steps0, t0 = state.step, clock()
    solver.advance(state, prep.plan.frames * prep.plan.frame_dt, count)
    wall = clock() - t0
    n, steps = len(state.particle_x), state.step - steps0
    return {"scene": scene, "particles": n, "bonds": int(prep.plan.bonds), "steps": steps, "setup_s": setup,
            "wall_s": wall, "ns_per_particle_step": 1e9 * wall / max(work[0], 1),
            "dt_mean": state.time / max(steps, 1), "dt_limit": limit,
            "phases_ns": {k: 1e9 * v / max(work[0], 1) for k, v in solver.phase_time.items()}}


def run_scene(checkout: Path, scene: str, overrides, cpu_time: bool) -> dict:
    """One scene in its own process, importing pdmpm_cli from `checkout`: its row, or its error."""
    sets = [a for o in overrides for a in ("--set", o)] + ["--cpu-time"] * cpu_time
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


def phase_table(rows: dict, name: str) -> str:
    """Each scene's step split into its parts (solver.phase_time) [ns per particle-step]."""
    phases = list(dict.fromkeys(p for r in rows.values() for p in r.get("phases_ns", {})))
    lines = [f"\n{name}: ns per particle-step by phase", "| scene | " + " | ".join(phases) + " | total |",
             "|" + "---|" * (len(phases) + 2)]
    for scene, r in rows.items():
        if "phases_ns" in r:
            ph = r["phases_ns"]
            lines.append(f"| {scene} | " + " | ".join(f"{ph[p]:.0f}" if p in ph else "" for p in phases)
                         + f" | {r['ns_per_particle_step']:.0f} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), help="scene[:variant] names (default: all)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="scene override for every scene")
    ap.add_argument("--ref", help="also run the suite in turn on this git revision (a temporary worktree) or on the "
                    "checkout in this directory")
    ap.add_argument("--cpu-time", action="store_true", help="time in process CPU seconds instead of wall seconds")
    ap.add_argument("--phases", action="store_true", help="also print each scene's time per phase")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        clock = time.process_time if args.cpu_time else time.perf_counter
        print(json.dumps(measure(args.child, args.overrides, clock)))
        return
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # still remove the reference worktree
    ours, ref = {}, None
    with tempfile.TemporaryDirectory(prefix="pdmpm-ref-") as tmp:
        temporary = bool(args.ref) and not Path(args.ref).is_dir()
        if temporary:
            ref_dir = Path(tmp) / args.ref.replace("/", "_")
            subprocess.run(["git", "worktree", "add", "--detach", str(ref_dir), args.ref], cwd=ROOT, check=True,
                           capture_output=True)
        elif args.ref:
            ref_dir = Path(args.ref).resolve()
        if args.ref:
            ref = {}
        try:
            for scene in args.scenes:  # in turn, so a drift in the machine's speed hits both alike
                ours[scene] = run_scene(ROOT, scene, args.overrides, args.cpu_time)
                if ref is not None:
                    ref[scene] = run_scene(ref_dir, scene, args.overrides, args.cpu_time)
        finally:
            if temporary:
                subprocess.run(["git", "worktree", "remove", "--force", str(ref_dir)], cwd=ROOT, capture_output=True)
    ref_name = Path(args.ref).name if args.ref and not temporary else (args.ref or "")
    print(table(ours, ref, ref_name))
    if args.phases:
        print(phase_table(ours, "ours"))
        if ref is not None:
            print(phase_table(ref, ref_name))


if __name__ == "__main__":
    main()
