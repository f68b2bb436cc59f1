"""The wall of wall_break, unbreakable, against resolution: how far its bonds stretch under the ball's impact, and
the threshold `fracture.energy` would give them. docs/results.md ('Fracture energy').

Usage: python bench/wall_stretch.py [--cells 0.04 0.02 0.01] [--energy 41] [--duration 0.06]
scenes/wall_break.yaml at grid cell `cell` with Voronoi seeds at half the cell (the scene's ratio), its wall without
a fracture section, stepped in memory. Each bond's largest stretch |eta| / |xi| - 1 over every step (eq. 21's
bond strain) is kept; the row gives their quantiles, how many bonds passed s0 = sqrt(4 G_c / (3 M delta)) (the
threshold G_c gives at that cell's horizon) and when the largest occurred. If the impact's stretches converge
with the cell while s0 grows as delta^-1/2, a crack starts at one resolution and not at another.
"""

import argparse
import time

import numpy as np
from wall_fracture_energy import wall_scene

from pdmpm_cli.engine.fracture import critical_stretch
from pdmpm_cli.study.sim import Sim


def run(cell: float, energy: float, duration: float) -> list[str]:
    t0 = time.perf_counter()
    scene = wall_scene(cell, duration)
    scene["bodies"][0].pop("fracture")
    sim = Sim(scene)
    m, b = sim.model, sim.model.bodies[0]
    start, end = m.bond_start[b.start], m.bond_start[b.end]
    own = np.repeat(np.arange(b.start, b.end), np.diff(m.bond_start[b.start:b.end + 1]))
    nbr = m.bond_nbr[start:end]
    rest = np.linalg.norm(m.rest_x[nbr] - m.rest_x[own], axis=1)
    peak, when = np.zeros(len(own)), [0.0, 0.0]

    def on_substep(st, dt):
        s = np.linalg.norm(st.particle_x[nbr] - st.particle_x[own], axis=1) / rest - 1.0
        np.maximum(peak, s, out=peak)
        largest = peak.max()
        if largest > when[1]:
            when[:] = [st.time, largest]

    sim.advance(duration, on_substep)
    mat = m.materials[0]
    s0 = critical_stretch(energy, mat.lam + 2 * mat.mu, b.horizon)
    q = np.quantile(peak, [0.99, 0.999, 1.0])
    return [f"{cell:g}", str(b.end - b.start), f"{b.horizon:.4g}", str(len(own)), f"{s0:.4f}",
            f"{q[0]:.4f}", f"{q[1]:.4f}", f"{q[2]:.4f}", f"{when[0]:.4f}", str(int((peak > s0).sum())),
            f"{time.perf_counter() - t0:.0f}"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=float, nargs="+", default=[0.04, 0.02, 0.01])
    ap.add_argument("--energy", type=float, default=41.0, help="G_c [J/m^2]")
    ap.add_argument("--duration", type=float, default=0.06, help="[s] (the ball touches the wall at about 8 ms)")
    args = ap.parse_args()
    cols = ("cell [m]", "wall particles", "horizon [m]", "bonds", "s0 from G_c", "peak stretch p99", "p99.9", "max",
            "max at [s]", "bonds past s0", "run [s]")
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for cell in args.cells:
        print("| " + " | ".join(run(cell, args.energy, args.duration)) + " |", flush=True)


if __name__ == "__main__":
    main()
