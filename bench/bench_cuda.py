"""Throughput of the CUDA backend on bench_cube.py's elastic cube: particle-steps/s and bond-updates/s per size.

Usage: python bench/bench_cuda.py [--sizes 128000 512000 2000000] [--steps 50] [--profile]
Prints a markdown table. The step time includes the one small read-back per step (the time step needs the max
speed); --profile synchronises after every phase and adds the per-phase split (slightly slower in total).
Without an NVIDIA GPU it says so and exits 2. NUMBA_ENABLE_CUDASIM=1 runs it on numba's simulator, which checks
the script, not the speed: use tiny sizes (--sizes 60 --steps 2).
"""

import argparse
import platform
import sys
import time

import numba

from bench_cube import cube_scene
from pdmpm_cli.errors import InputError
from pdmpm_cli.runner import prepare_scene, start_in_memory


def bench(n_target: int, steps: int, profile: bool) -> dict:
    scene = cube_scene(n_target)
    scene = scene.model_copy(update={"simulation": scene.simulation.model_copy(update={"backend": "cuda"})})
    prep = prepare_scene(scene, "bench.yaml")
    state, solver = start_in_memory(prep)
    solver.profile = profile
    dt = prep.plan.dt_max
    for _ in range(2):  # compile (or load the cache) and warm up
        solver.substep(state, dt)
    solver.phase_time.clear()
    t0 = time.perf_counter()
    for _ in range(steps):
        solver.substep(state, dt)  # ends with the step's read-back, so the GPU has finished
    wall = time.perf_counter() - t0
    solver.check_energy(state)  # copies the State back: the run stayed finite and bounded
    n, nb = prep.plan.particles, prep.plan.bonds
    return {
        "particles": n, "bonds_per_particle": nb / n, "step_ms": 1e3 * wall / steps,
        "particle_steps_per_s": n * steps / wall, "bond_updates_per_s": nb * steps / wall,
        "phases": {k: 1e3 * v / steps for k, v in solver.phase_time.items()},
        "memory_mib": prep.plan.memory_bytes / 2**20, "device": solver.backend.device_name,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[128_000, 512_000, 2_000_000])
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--profile", action="store_true", help="per-phase times (synchronises after each phase)")
    args = ap.parse_args()
    try:
        rows = [bench(n, args.steps, args.profile) for n in args.sizes]
    except InputError as e:
        print(f"bench_cuda: {e}", file=sys.stderr)
        sys.exit(2)
    print(f"device: {rows[0]['device']}; host: {platform.processor() or platform.machine()}, "
          f"numba {numba.__version__}, float64")
    phases = list(rows[0]["phases"])
    print("| particles | bonds/particle | step [ms] | particle-steps/s | bond-updates/s | "
          + "".join(f"{p} [ms] | " for p in phases) + "plan memory [MiB] |")
    print("|" + "---|" * (6 + len(phases)))
    for r in rows:
        print(f"| {r['particles']} | {r['bonds_per_particle']:.1f} | {r['step_ms']:.2f} | "
              f"{r['particle_steps_per_s'] / 1e6:.2f} M | {r['bond_updates_per_s'] / 1e6:.1f} M | "
              + "".join(f"{r['phases'][p]:.2f} | " for p in phases) + f"{r['memory_mib']:.0f} |")


if __name__ == "__main__":
    main()
