"""The bonds' first-order patch test on each sampling: docs/results.md ('Vibrating bar: the sampling, the
calibration and the fixed end').

Usage: python bench/patch_test.py [--sampling lattice relaxed jittered]
A 0.5 m cube of tests/conftest.py's material (lam = mu = 1e5 Pa, 2 particles per 4 cm cell) under a homogeneous
strain of 1e-3 (isotropic, uniaxial along x, shear in xy): the net bond force on the particles whose family lies
inside the body, over M s h^2 (the force of that strain's stress on one particle's face). Exactly zero on a lattice;
on an irregular cloud each particle's family is lopsided and the force is not, though it sums to zero.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pdmpm_cli.study.sim import Sim  # noqa: E402
from tests.conftest import BASE, merge  # noqa: E402
from tests.test_elastic import deform, interior  # noqa: E402

STRAIN = 1e-3
M = 3e5  # lam + 2 mu of BASE's material [Pa]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sampling", nargs="+", default=["lattice", "relaxed", "jittered"])
    a = ap.parse_args()
    cases = {"isotropic": (1 + STRAIN) * np.eye(3), "uniaxial x": np.diag([1 + STRAIN, 1.0, 1.0]),
             "shear xy": np.eye(3) + STRAIN * np.array([[0, 1, 0], [1, 0, 0], [0, 0, 0.0]])}
    print("| sampling | strain | interior particles | mean | p99 | max |  (net force / (M s h^2))")
    print("|---|---|---|---|---|---|")
    for sampling in a.sampling:
        body = merge(BASE["bodies"][0], {"geometry": {"mode": "cloud", "sampling": sampling, "shape": {
            "type": "box", "center": [0.5, 0.5, 0.5], "size": [0.5, 0.5, 0.5]}}})
        sim = Sim(merge(BASE, {"grid": {"cell_size": 0.04}, "bodies": [body]}))
        inner = interior(sim, sim.model.body_horizon[0] * 1.01)
        typical = M * STRAIN * sim.model.particle_volume[0] ** (2 / 3)
        for name, F in cases.items():
            f = np.linalg.norm(deform(sim, F)[0][inner], axis=1) / typical
            print(f"| {sampling} | {name} | {len(inner)} | {f.mean():.3f} | {np.percentile(f, 99):.3f} | "
                  f"{f.max():.3f} |", flush=True)


if __name__ == "__main__":
    main()
