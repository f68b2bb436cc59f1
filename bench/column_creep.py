"""An elastic column at rest: does it stay there? docs/results.md ('Self-weight column').

Usage: python bench/column_creep.py [--sampling lattice relaxed jittered] [--cell 0.0884] [--periods 1.5 3 9 30]
       [--set simulation.step=auto --set simulation.cfl=0.4] [--lam-share 0]
`pdmpm study column`'s column (1 m, confined by slip walls, sticky floor, critical air drag on its first mode) run
for up to 30 periods of that mode. Per time: the settlement above the exact rho g (H0 Y - Y^2 / 2) / M, averaged
over bands of rest height (in cells above the floor), in mm, and the kinetic energy; the top's error is `pdmpm study
column`'s, which reads it at 1.5 periods. A static answer stays put once the drag has taken the motion out.
--lam-share: the share of M = lam + 2 mu carried by lam (the study's column has lam = 0: Fbar's term alone).
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pdmpm_cli.scene.loader import merge  # noqa: E402
from pdmpm_cli.study.ladder import simulation_changes  # noqa: E402
from pdmpm_cli.study.problems import COLUMN_H, COLUMN_M, COLUMN_SETTLE, G, RHO, column_scene  # noqa: E402
from pdmpm_cli.study.sim import Sim  # noqa: E402

BANDS = [0, 0.5, 1, 2, 4]  # rest height above the floor [cells]; then 4 cells to H0 / 2 and H0 / 2 to the top


def run(sampling: str, cell: float, periods: list[float], sets: list[str], lam_share: float):
    period = 4 * COLUMN_H / np.sqrt(COLUMN_M / RHO)  # first mode of a column fixed at its foot
    d = merge(column_scene(cell, max(periods)), simulation_changes(sets))
    body = d["bodies"][0]
    body["geometry"]["sampling"] = sampling
    body["material"]["lam"], body["material"]["mu"] = lam_share * COLUMN_M, (1 - lam_share) * COLUMN_M / 2
    sim = Sim(d)
    x0 = sim.model.rest_x
    y = x0[:, 1] - sim.scene.colliders[0].point[1]
    exact = RHO * G * (COLUMN_H * y - y**2 / 2) / COLUMN_M
    edges = np.append(np.array(BANDS) * cell, [COLUMN_H / 2, np.inf])
    bands = [(y >= a) & (y < b) for a, b in zip(edges[:-1], edges[1:])]
    top = y > COLUMN_H - 0.6 * cell
    for per in periods:
        sim.advance(per * period)
        u = -(sim.state.particle_x[:, 1] - x0[:, 1])
        excess = [f"{1e3 * (u[b].mean() - exact[b].mean()):+.3f}" if b.any() else "-" for b in bands]
        ke = 0.5 * float(sim.model.particle_mass @ (sim.state.particle_v**2).sum(axis=1))
        err = u[top].mean() / COLUMN_SETTLE - 1
        print(f"| {sampling} | {' '.join(sets) or 'defaults'} | {per:g} | {sim.state.step} | "
              + " | ".join(excess) + f" | {err:+.4f} | {ke:.1e} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sampling", nargs="+", default=["lattice", "relaxed", "jittered"])
    ap.add_argument("--cell", type=float, default=0.0884, help="cell size [m]")
    ap.add_argument("--periods", type=float, nargs="+", default=[1.5, 3, 9, 30])
    ap.add_argument("--set", dest="sets", action="append", default=[], help="simulation.key=value")
    ap.add_argument("--lam-share", type=float, default=0.0)
    a = ap.parse_args()
    heads = [f"{lo:g}-{hi:g} cells" for lo, hi in zip(BANDS[:-1], BANDS[1:])] + [f"{BANDS[-1]} cells-H0/2", "H0/2-top"]
    print("| sampling | step rule | periods | steps | " + " | ".join(f"excess {h} [mm]" for h in heads)
          + " | top's error | kinetic energy [J] |")
    print("|---" * (len(heads) + 6) + "|")
    for sampling in a.sampling:
        run(sampling, a.cell, sorted(a.periods), a.sets, a.lam_share)


if __name__ == "__main__":
    main()
