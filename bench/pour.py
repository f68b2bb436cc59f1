"""The honey pour (scenes/honey.yaml, or a reduced version with --set overrides): emitted volume against rate x time
and the pile's volume against what was poured, sum V0 J and from positions alone (N x the mean Voronoi cell of the
bulk particles, tests/fluid_cases.occupied_volume), with the nearest-neighbour spacing, the pile's height and
spread, every few frames.
The figures in docs/results.md ('Liquids'). Run: NUMBA_NUM_THREADS=1 python bench/pour.py [--set key=value ...]"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from pdmpm_cli.runner import prepare, start_in_memory

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.fluid_cases import nearest_spacing, occupied_volume  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "honey.yaml"))
    parser.add_argument("--set", action="append", default=[], dest="overrides")
    parser.add_argument("--every", type=int, default=12, help="print every this many frames")
    args = parser.parse_args()
    prep = prepare(args.scene, args.overrides)
    em, plan = prep.scene.bodies[-1].emitter, prep.plan
    state, solver = start_in_memory(prep)
    head = float(prep.model.particle_volume.sum())
    print(f"{plan.particles} initial particles, capacity {plan.capacity}, dt_max {plan.dt_max:.3g} s, layer "
          f"{len(solver.model.emitter.layer)} particles every {solver.model.emitter.interval:.4g} s")
    print("| t [s] | particles | emitted / (rate x t) | sum V0 J / poured | Voronoi volume / poured | nearest spacing "
          "/ h | top above plate [m] | RMS radius [m] | wall [s] |")
    print("|---|---|---|---|---|---|---|---|---|")
    t0 = time.perf_counter()
    for f in range(1, plan.frames + 1):
        t = f * plan.frame_dt
        solver.advance(state, t)
        if f % args.every and f != plan.frames:
            continue
        m = solver.model
        poured_for = max(0.0, min(t, em.stop or t) - em.start)
        emitted = (m.n_particles - plan.particles) * m.emitter.volume
        volume = float(m.particle_volume @ state.particle_J)
        x = state.particle_x
        below = x[:, 1] < 0.4 + 0.5  # the pile: what is within 0.5 m of the plate
        r = np.sqrt(((x[below][:, [0, 2]] - x[below][:, [0, 2]].mean(axis=0)) ** 2).sum(axis=1).mean()) \
            if below.any() else 0.0
        h = m.bodies[-1].spacing
        print(f"| {t:.3f} | {m.n_particles} | {emitted / (em.rate * poured_for) if poured_for else 1:.4f} | "
              f"{volume / (head + em.rate * poured_for):.4f} | "
              f"{occupied_volume(x, h) / (head + em.rate * poured_for):.4f} | {nearest_spacing(x) / h:.3f} | "
              f"{x[below, 1].max() - 0.4 if below.any() else 0:.3f} | "
              f"{r:.3f} | {time.perf_counter() - t0:.0f} |", flush=True)
    print(f"{state.step} steps")


if __name__ == "__main__":
    main()
