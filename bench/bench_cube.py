"""Throughput of the full step on an elastic cube: particle-steps/s and bond-updates/s per size.

Usage: python bench/bench_cube.py [--sizes 32000 128000 512000] [--steps 20] [--taichi]
Prints a markdown table (for docs/results.md) with the per-phase split of the step time, the bond passes'
throughput (Fbar and forces together), memory per particle and, with --taichi (pip install taichi), a plain
Taichi MLS-MPM step on the same cube without bonds (bench/taichi_cube.py, f32 and f64) and our ratio to it.
"""

import argparse
import platform
import subprocess
import sys
import time
from pathlib import Path

import numba
import numpy as np

from pdmpm_cli.engine.model import State
from pdmpm_cli.engine.solver import Solver
from pdmpm_cli.runner import prepare_scene
from pdmpm_cli.scene.schema import Scene


def cube_scene(n_target: int) -> Scene:
    """A jittered elastic cube of about n_target particles (8 per cell, delta = 2h), free in space."""
    h = 0.01
    side = h * round(n_target ** (1 / 3))
    dx = 2 * h
    pad = 6 * dx
    return Scene.model_validate({
        "simulation": {"duration": 1.0, "fps": 10},
        "grid": {"cell_size": dx, "domain": {"min": [0, 0, 0], "max": [side + 2 * pad] * 3}},
        "gravity": [0, 0, 0],
        "bodies": [{"name": "cube",
                    "geometry": {"mode": "cloud", "sampling": "jittered",
                                 "shape": {"type": "box", "center": [pad + side / 2] * 3, "size": [side] * 3}},
                    "material": {"model": "elastic", "density": 1000.0, "lam": 1e5, "mu": 1e5},
                    "angular_velocity": [0.0, 0.5, 0.0]}],
    })


def bench(n_target: int, steps: int, clock=time.perf_counter) -> dict:
    prep = prepare_scene(cube_scene(n_target), "bench.yaml")
    state = State.allocate(prep.model, prep.disc, prep.plan.fields)
    solver = Solver(prep.model, prep.plan)
    solver.clock = clock
    dt = prep.plan.dt_max
    for _ in range(2):  # compile (or load the cache) and warm up
        solver.substep(state, dt)
    solver.phase_time.clear()
    t0 = clock()
    for _ in range(steps):
        solver.substep(state, dt)
    wall = clock() - t0
    n, nb = prep.plan.particles, prep.plan.bonds
    bond_s = (solver.phase_time["fbar"] + solver.phase_time["bonds:elastic"]) / steps
    return {
        "bond_pass_per_s": nb / bond_s, "ns_per_particle_step": 1e9 * wall / (n * steps),
        "particles": n, "bonds_per_particle": nb / n, "step_ms": 1e3 * wall / steps,
        "particle_steps_per_s": n * steps / wall, "bond_updates_per_s": nb * steps / wall,
        "phases": {k: 1e3 * v / steps for k, v in solver.phase_time.items()},
        "memory_mib": prep.plan.memory_bytes / 2**20, "bytes_per_particle": prep.plan.memory_bytes / n,
    }


def taichi_rate(n: int, steps: int, precision: str) -> float:
    """Particle-steps/s of bench/taichi_cube.py with our thread count, in its own process."""
    out = subprocess.run([sys.executable, str(Path(__file__).with_name("taichi_cube.py")), str(n), str(steps),
                          precision, str(numba.get_num_threads())], capture_output=True, text=True, check=True)
    return float(out.stdout.split()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[32_000, 128_000, 512_000])
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--taichi", action="store_true", help="also time bench/taichi_cube.py (needs taichi)")
    ap.add_argument("--cpu-time", action="store_true",
                    help="time in process CPU seconds (all threads) instead of wall seconds: steadier on a busy "
                         "machine; with NUMBA_NUM_THREADS=1 it is the single-core cost")
    args = ap.parse_args()
    rows = [bench(n, args.steps, time.process_time if args.cpu_time else time.perf_counter) for n in args.sizes]
    print(f"machine: {platform.processor() or platform.machine()}, {numba.get_num_threads()} threads, "
          f"numba {numba.__version__}, float64, {'CPU' if args.cpu_time else 'wall'} time")
    phases = list(rows[0]["phases"])
    print("| particles | bonds/particle | step [ms] | particle-steps/s | ns per particle-step | bond-updates/s "
          "(step) | bond pass (fbar + forces) | " + " | ".join(f"{p} [ms]" for p in phases)
          + " | plan memory [MiB] | bytes/particle |")
    print("|" + "---|" * (9 + len(phases)))
    for r in rows:
        print(f"| {r['particles']} | {r['bonds_per_particle']:.1f} | {r['step_ms']:.1f} | "
              f"{r['particle_steps_per_s'] / 1e6:.2f} M | {r['ns_per_particle_step']:.0f} | "
              f"{r['bond_updates_per_s'] / 1e6:.1f} M | {r['bond_pass_per_s'] / 1e6:.0f} M/s | "
              + " | ".join(f"{r['phases'][p]:.1f}" for p in phases)
              + f" | {r['memory_mib']:.0f} | {r['bytes_per_particle']:.0f} |")
    if args.taichi:
        print("\n| particles | ours (f64, bonds) | Taichi f64 (no bonds) | Taichi f32 (no bonds) | ours / Taichi f64 "
              "| ours / Taichi f32 |\n|---|---|---|---|---|---|")
        for r in rows:
            t64, t32 = (taichi_rate(r["particles"], args.steps, p) for p in ("f64", "f32"))
            ours = r["particle_steps_per_s"]
            print(f"| {r['particles']} | {ours / 1e6:.2f} M | {t64 / 1e6:.2f} M | {t32 / 1e6:.2f} M | "
                  f"{ours / t64:.2f} | {ours / t32:.2f} |")


if __name__ == "__main__":
    main()
