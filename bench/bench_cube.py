"""Throughput of the full step on an elastic cube: particle-steps/s and bond-updates/s per size.

Usage: python bench/bench_cube.py [--sizes 32000 128000 512000] [--steps 20] [--taichi] [--horizon 2.0] [--cpu-time]
                                  [--precision float64|float32]
Prints one markdown table (for docs/results.md): per size the step time, particle-steps/s, the bond pass's
bond-updates/s (directed bonds over the Fbar and force phases together, and over the force phase alone), the
per-phase split of the step time, memory per particle and the cost per particle-step relative to the smallest
size; with --taichi (pip install taichi) also a plain Taichi MLS-MPM step on the same cube without bonds
(bench/taichi_cube.py, f32 and f64) and our ratio to it. --horizon sets delta / h (default 2, about 33 bonds per
particle), to compare with a scene of another horizon (bench/table1_suite.py) at the same bonds per particle.
--precision sets simulation.precision (docs/results.md, 'float32').
"""

import argparse
import platform
import subprocess
import sys
import time
from pathlib import Path

import numba

from pdmpm_cli.runner import prepare_scene, start_in_memory
from pdmpm_cli.scene.schema import Scene


def cube_scene(n_target: int, horizon: float = 2.0, precision: str = "float64") -> Scene:
    """A jittered elastic cube of about n_target particles (8 per cell, delta = horizon h), free in space."""
    h = 0.01
    side = h * round(n_target ** (1 / 3))
    dx = 2 * h
    pad = 6 * dx
    return Scene.model_validate({
        "simulation": {"duration": 1.0, "fps": 10, "precision": precision},
        "grid": {"cell_size": dx, "domain": {"min": [0, 0, 0], "max": [side + 2 * pad] * 3}},
        "gravity": [0, 0, 0],
        "bodies": [{"name": "cube",
                    "geometry": {"mode": "cloud", "sampling": "jittered", "horizon": horizon,
                                 "shape": {"type": "box", "center": [pad + side / 2] * 3, "size": [side] * 3}},
                    "material": {"model": "elastic", "density": 1000.0, "lam": 1e5, "mu": 1e5},
                    "angular_velocity": [0.0, 0.5, 0.0]}],
    })


def bench(n_target: int, steps: int, clock=time.perf_counter, horizon: float = 2.0, precision: str = "float64"
          ) -> dict:
    prep = prepare_scene(cube_scene(n_target, horizon, precision), "bench.yaml")
    state, solver = start_in_memory(prep)
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
        "bond_pass_per_s": nb / bond_s, "forces_per_s": nb * steps / solver.phase_time["bonds:elastic"],
        "ns_per_particle_step": 1e9 * wall / (n * steps),
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
    ap.add_argument("--horizon", type=float, default=2.0, help="peridynamic horizon delta / h (default 2)")
    ap.add_argument("--precision", choices=("float64", "float32"), default="float64",
                    help="simulation.precision of the cube (default float64)")
    args = ap.parse_args()
    clock = time.process_time if args.cpu_time else time.perf_counter
    rows = [bench(n, args.steps, clock, args.horizon, args.precision) for n in args.sizes]
    print(f"machine: {platform.processor() or platform.machine()}, {numba.get_num_threads()} threads, "
          f"numba {numba.__version__}, {args.precision}, {'CPU' if args.cpu_time else 'wall'} time, "
          f"horizon {args.horizon} h")
    phases = list(rows[0]["phases"])
    taichi = {}
    if args.taichi:
        taichi = {r["particles"]: [taichi_rate(r["particles"], args.steps, p) for p in ("f64", "f32")] for r in rows}
    print("| particles | bonds/particle | step [ms] | particle-steps/s | ns per particle-step | cost / smallest size "
          "| bond pass (fbar + forces) [bond-updates/s] | forces only [bond-updates/s] | "
          + " | ".join(f"{p} [ms]" for p in phases) + " | plan memory [MiB] | bytes/particle |"
          + (" Taichi f64 / f32 (no bonds) | ours / Taichi f64 / f32 |" if taichi else ""))
    print("|" + "---|" * (10 + len(phases) + 2 * bool(taichi)))
    base = rows[0]["ns_per_particle_step"]
    for r in rows:
        line = (f"| {r['particles']} | {r['bonds_per_particle']:.1f} | {r['step_ms']:.1f} | "
                f"{r['particle_steps_per_s'] / 1e6:.2f} M | {r['ns_per_particle_step']:.0f} | "
                f"{r['ns_per_particle_step'] / base:.2f} | {r['bond_pass_per_s'] / 1e6:.0f} M | "
                f"{r['forces_per_s'] / 1e6:.0f} M | " + " | ".join(f"{r['phases'][p]:.1f}" for p in phases)
                + f" | {r['memory_mib']:.0f} | {r['bytes_per_particle']:.0f} |")
        if taichi:
            t64, t32 = taichi[r["particles"]]
            ours = r["particle_steps_per_s"]
            line += f" {t64 / 1e6:.2f} M / {t32 / 1e6:.2f} M | {ours / t64:.2f} / {ours / t32:.2f} |"
        print(line)
    print(f"\ncost per particle-step, {rows[-1]['particles']} / {rows[0]['particles']} particles: "
          f"{rows[-1]['ns_per_particle_step'] / base:.2f}")


if __name__ == "__main__":
    main()
