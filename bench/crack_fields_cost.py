"""What crack fields cost per step: the notched bar of pdmpm_cli/study/fracture.py (bar_scene) stepped from 5 to
60 ms, before it breaks, with one field (`contact.cracks: shared`) and with crack fields (`auto`), in turn.

Usage: NUMBA_NUM_THREADS=1 python bench/crack_fields_cost.py [--cell 0.02] [--repeat 2]
Prints process CPU time per particle-step and the costliest phases (Solver.phase_time), per run.
"""

import argparse
import time

from pdmpm_cli.study.fracture import bar_scene
from pdmpm_cli.study.sim import Sim


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cell", type=float, default=0.02, help="grid cell [m]")
    ap.add_argument("--repeat", type=int, default=2, help="runs of each, alternating")
    args = ap.parse_args()
    print("| contact.cracks | ns per particle-step | steps | costliest phases [ns per particle-step] |")
    print("|---|---|---|---|")
    for cracks in ("shared", "auto") * args.repeat:
        sim = Sim(bar_scene(args.cell, 2.0, duration=0.4, cracks=cracks))
        state, solver = sim.state, sim.solver
        solver.advance(state, 0.005)  # compiles, and fills the caches
        solver.phase_time.clear()
        t0, n0 = time.process_time(), state.step
        solver.advance(state, 0.06)
        steps = state.step - n0
        scale = 1e9 / (steps * sim.model.n_particles)
        top = sorted(solver.phase_time.items(), key=lambda kv: -kv[1])[:5]
        print(f"| {cracks} | {(time.process_time() - t0) * scale:.0f} | {steps} | "
              + ", ".join(f"{k} {v * scale:.0f}" for k, v in top) + " |", flush=True)


if __name__ == "__main__":
    main()
