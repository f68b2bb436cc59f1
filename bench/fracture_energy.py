"""Fracture energy against resolution: a notched bar pulled apart slowly (pdmpm_cli/study/fracture.py).

Usage: python bench/fracture_energy.py [--cells 0.04 0.03 0.02] [--energy 2.0] [--damage-resistance K]
    [--cracks auto|shared|separate] [--flip F] [--seeds 0 1 2]
Prints one row per grid cell size (and seed): large pieces (over 5 % of the mass), time of first separation, the
strain energy stored when the first bond broke (what an unstable crack releases as motion), the energy balance
D = W - strain - kinetic against G_c A (A the ligament), split into what the bonds held when they were cut (and the
part of it in the bonds across the notch's mid-plane, the crack's own) and the rest (numerical loss: transfers,
crack contacts), the balance's own error before any bond broke, and the broken-bond area (sum of the broken bonds'
energy at the threshold / G_c, and its part across the mid-plane) against A. --seeds runs each cell on several
samplings of the same bar (simulation.seed) and ends with D / G_c A's mean and range per cell.
"""

import argparse

import numpy as np

from pdmpm_cli.study.fracture import pull

COLUMNS = ("cell [m]", "seed", "h [m]", "delta [m]", "particles", "threshold", "large pieces", "separation [s]",
           "stored at first cut / G_c A", "D / G_c A", "cut bonds' energy / G_c A", "of it across the plane",
           "rest of D / G_c A", "D before breaking / W", "broken area / A", "of it across the plane", "run [s]")


def row(r, seed: int) -> list[str]:
    ga = r.expected
    return [f"{r.cell:g}", str(seed), f"{r.spacing:g}", f"{r.horizon:g}", str(r.particles), f"{r.threshold:.4g}",
            str(r.large), f"{r.separation:.3f}", f"{r.stored / ga:.2f}", f"{r.dissipated / ga:.2f}",
            f"{r.cut_energy / ga:.2f}", f"{r.plane_energy / ga:.2f}", f"{(r.dissipated - r.cut_energy) / ga:.2f}",
            f"{r.before / r.work_before:.3f}", f"{r.bond_area / r.area:.2f}", f"{r.plane_area / r.area:.2f}",
            f"{r.seconds:.0f}"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=float, nargs="+", default=[0.04, 0.03, 0.02])
    ap.add_argument("--energy", type=float, default=2.0, help="G_c [J/m^2]")
    ap.add_argument("--damage-resistance", type=float, default=None, help="default: the scene's (0 with an energy)")
    ap.add_argument("--cracks", choices=("auto", "shared", "separate"), default="auto", help="contact.cracks")
    ap.add_argument("--flip", type=float, default=0.0, help="simulation.flip")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="simulation.seed: one row per cell and seed")
    args = ap.parse_args()
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + "---|" * len(COLUMNS))
    spread = []
    for cell in args.cells:
        d = []
        for seed in args.seeds:
            r = pull(cell, args.energy, damage_resistance=args.damage_resistance, cracks=args.cracks, flip=args.flip,
                     seed=seed)
            d.append(r.dissipated / r.expected)
            print("| " + " | ".join(row(r, seed)) + " |", flush=True)
        spread.append(f"{cell:g} m: mean {np.mean(d):.2f}, {min(d):.2f}-{max(d):.2f} over {len(d)} seeds")
    if len(args.seeds) > 1:
        print("D / G_c A by cell: " + "; ".join(spread))


if __name__ == "__main__":
    main()
