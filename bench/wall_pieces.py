"""Pieces of a fractured body in a finished run, frame by frame, from run.h5 alone.

Usage: python bench/wall_pieces.py RUNDIR SCENE.yaml [--variant V] [--set KEY=VALUE]... [--body 0] [--threshold 0.05]
run.h5 stores positions, not bond states, so a bond counts as intact while its current stretch is below the
fracture threshold; the families are rebuilt from the scene (the seeded discretisation gives the same particles,
which is checked). Pieces over 5 % of the body, the share they hold, and dust (pieces under 5 particles) as in
tests/table1.py::wall_pieces. Used for the wall at Table 1's resolution in docs/results.md.
"""

import argparse

import h5py
import numpy as np

from pdmpm_cli.engine.fracture import pieces
from pdmpm_cli.runner import prepare


def stretch_intact(bond_start, bond_nbr, X, x, threshold) -> np.ndarray:
    """Bonds whose stretch from rest positions X to x is below threshold: the intact ones, as far as positions tell."""
    owner = np.repeat(np.arange(len(bond_start) - 1), np.diff(bond_start))
    rest = np.linalg.norm(X[bond_nbr] - X[owner], axis=1)
    return (np.linalg.norm(x[bond_nbr] - x[owner], axis=1) - rest) / rest < threshold


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("scene")
    ap.add_argument("--variant", default=None)
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="as for pdmpm run")
    ap.add_argument("--body", type=int, default=0)
    ap.add_argument("--threshold", type=float, default=0.05, help="the body's fracture threshold [-]")
    args = ap.parse_args()
    model = prepare(args.scene, args.overrides, args.variant).model
    with h5py.File(f"{args.run}/run.h5", "r") as f:
        X = f["static/particle_X"][:]
        if not np.allclose(X, model.rest_x):
            raise SystemExit(f"{args.run} was not made from {args.scene} with these overrides: particles differ")
        start, end = model.body_ranges[args.body]
        print("| t [s] | pieces over 5 % | share they hold | dust (pieces under 5) | largest pieces |")
        print("|---|---|---|---|---|")
        for k, t in enumerate(f["frames/time"][:]):
            intact = stretch_intact(model.bond_start, model.bond_nbr, X, f["frames/particle_x"][k], args.threshold)
            sizes = np.sort(np.bincount(pieces(model.bond_start, model.bond_nbr, intact, start, end)))[::-1]
            n = sizes.sum()
            large = sizes[sizes > 0.05 * n]
            print(f"| {t:.3g} | {len(large)} | {100 * large.sum() / n:.1f} % | {100 * sizes[sizes < 5].sum() / n:.1f} % "
                  f"| {', '.join(map(str, sizes[:3]))} |")


if __name__ == "__main__":
    main()
