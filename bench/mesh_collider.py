"""Mesh colliders: the sampled signed distance of a closed mesh against the exact one, and its build time.

    python bench/mesh_collider.py [--spacings 0.02 0.01 0.005]

A 0.2 m sphere (icosphere, 20480 triangles; its facets lie at most 0.02 mm inside the sphere) sampled at each
spacing; 20,000 random points within 2 samples of the surface give the distance error (against |x| - R) and the
normal's angle error. Prints a markdown table.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pdmpm_cli.assemble import collider_table  # noqa: E402
from pdmpm_cli.engine.colliders import signed_distance  # noqa: E402
from pdmpm_cli.geometry.mesh import SurfaceMesh, validate_surface  # noqa: E402
from pdmpm_cli.geometry.sdf import distance_samples  # noqa: E402
from tests.mesh_corpus import icosphere  # noqa: E402

R = 0.2


def row(mesh: SurfaceMesh, spacing: float, rng) -> str:
    t0 = time.perf_counter()
    samples = distance_samples(mesh, spacing)
    built = time.perf_counter() - t0
    collider = type("C", (), {"type": "mesh", "velocity": (0.0, 0.0, 0.0), "boundary": "slip", "friction": 0.0,
                              "inside_out": False})()
    table = collider_table([collider], {0: samples})
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    r = R + rng.uniform(-2 * spacing, 2 * spacing, 20000)
    n = np.zeros(3)
    err, ang = np.empty(len(r)), np.empty(len(r))
    for k, (u, rk) in enumerate(zip(d, r)):
        phi = signed_distance(table, 0, *(rk * u), 0.0, n)
        err[k] = phi - (rk - R)
        ang[k] = np.degrees(np.arccos(min(1.0, float(n @ u))))
    return (f"| {spacing:g} | {samples.values.size:,} | {built:.2f} | {np.abs(err).max() / spacing:.3f} | "
            f"{np.sqrt(np.mean(err**2)) / spacing:.4f} | {ang.max():.2f} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spacings", type=float, nargs="+", default=[0.02, 0.01, 0.005])
    args = ap.parse_args()
    V, T, _ = validate_surface(*icosphere(5, R), "sphere")
    mesh = SurfaceMesh(V, T)
    distance_samples(mesh, 0.05)  # compile or load the kernels
    rng = np.random.default_rng(1)
    print("| spacing [m] | samples | build [s] | max error / spacing | RMS error / spacing | max normal error [deg] |")
    print("|---|---|---|---|---|---|")
    for h in args.spacings:
        print(row(mesh, h, rng))


if __name__ == "__main__":
    main()
