"""Where the vibrating bar's period and decay come from: docs/results.md ('Vibrating bar: the sampling, the
calibration and the fixed end').

Usage: python bench/bar_ends.py [--sampling relaxed jittered lattice] [--ends fixed clamped mirrored]
       [--width 4] [--flip 0] [--step 0.133 0.0667]
- fixed: Sulsky's bar as tests/test_dynamics.py runs it (a sticky wall at x0, slip walls on the long sides,
  2 periods).
- clamped: the same with the wall at x0 `boundary: clamped` (its nodes mirrored, not zeroed).
- mirrored: the same bar twice as long with no wall at x0, in its antisymmetric first mode: its middle is the fixed
  end's node by symmetry, so each half is the fixed bar without the wall's grid nodes. Analytic period 10 s for both.
- --width: the bar's width in cells (the bar of the tests is 4 cells, 8 particles, wide).
- --step k: the step forced to k dx / c (`Sim.force_step`; the 0.05 s frames still cap it) instead of the Plan's.
Per row: the mean stiffness along the axis over M (`axial_stiffness`), the period from the zero crossings of the
(half-)bar's centre-of-mass velocity, the decay of its amplitude per period and the steps.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pdmpm_cli.study.problems import BAR_LENGTH, BAR_V0, bar_scene, bar_start, period  # noqa: E402
from pdmpm_cli.study.sim import Sim  # noqa: E402

CELL = 1.25


def axial_stiffness(sim: Sim) -> float:
    """Mass-weighted mean over the particles of their energy under a uniaxial strain along x over the continuum's
    M eps^2 / 2: 5 sum_q w V_q n_x^4 / omega_p (1 for a family whose bond directions are spread evenly; the bond
    passes' weights and c_p = 5 / omega_p)."""
    m = sim.model
    own = np.repeat(np.arange(len(m.rest_x)), np.diff(m.bond_start))
    xi = m.rest_x[m.bond_nbr] - m.rest_x[own]
    nx4 = (xi[:, 0] / np.linalg.norm(xi, axis=1)) ** 4
    per_particle = m.particle_coef * np.bincount(own, sim.state.bond_wv * nx4, len(m.rest_x))
    return float(m.particle_mass @ per_particle / m.particle_mass.sum())


def scene(sampling: str, ends: str, width: int, flip: float) -> tuple[dict, float]:
    """The bar's scene and the x of its fixed end (the mirrored bar's middle)."""
    d = bar_scene(CELL, 2.0)
    d["simulation"]["flip"] = flip
    body = d["bodies"][0]["geometry"]
    body["sampling"] = sampling
    x0 = d["colliders"][0]["point"][0]
    if width != 4:  # the long sides' slip walls stay on node planes: 5 cells from the domain's low side
        top = (5 + width) * CELL
        d["grid"]["domain"]["max"][1] = d["grid"]["domain"]["max"][2] = top + 5 * CELL
        body["shape"]["center"][1] = body["shape"]["center"][2] = (5 + width / 2) * CELL
        body["shape"]["size"][1] = body["shape"]["size"][2] = width * CELL
        for c in d["colliders"][1:]:
            c["point"] = [top if v == 9 * CELL else v for v in c["point"]]
    if ends == "clamped":
        d["colliders"][0]["boundary"] = "clamped"
    if ends == "mirrored":
        d["colliders"] = d["colliders"][1:]
        d["grid"]["domain"]["max"][0] = x0 + 2 * BAR_LENGTH + 6 * CELL
        body["shape"]["center"][0] = x0 + BAR_LENGTH
        body["shape"]["size"][0] = 2 * BAR_LENGTH
        return d, x0 + BAR_LENGTH
    return d, x0


def bar(sampling: str, ends: str, width: int, flip: float, step: float | None = None):
    d, mid = scene(sampling, ends, width, flip)
    sim = Sim(d)
    if step is not None:
        sim.force_step(step)
    s, m = sim.state, sim.model.particle_mass
    if ends == "mirrored":
        s.particle_v[:, 0] = BAR_V0 * np.sin(np.pi * (s.particle_x[:, 0] - mid) / (2 * BAR_LENGTH))
        half = s.particle_x[:, 0] > mid
        sim.solver.start(s)
    else:
        half = np.ones(len(m), bool)
        bar_start(sim)
    mh = m[half].sum()
    t, v = [0.0], [float(m[half] @ s.particle_v[half, 0] / mh)]

    def record(st, dt):
        t.append(st.time)
        v.append(float(m[half] @ st.particle_v[half, 0] / mh))

    t0 = time.perf_counter()
    sim.advance(20.0, record)
    t, v = np.array(t), np.array(v)
    amp = [np.abs(v[(t >= a) & (t < a + 10.0)]).max() for a in (0.0, 10.0)]
    print(f"| {sampling} | {ends} | {width} | {flip:g} | {'-' if step is None else f'{step:g}'} | "
          f"{axial_stiffness(sim):.3f} | {period(t, v):.3f} | "
          f"{100 * (1 - amp[1] / amp[0]):.2f} % | {s.step} | {time.perf_counter() - t0:.0f} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sampling", nargs="+", default=["relaxed", "jittered", "lattice"])
    ap.add_argument("--ends", nargs="+", default=["fixed", "clamped", "mirrored"])
    ap.add_argument("--width", type=int, nargs="+", default=[4], help="cells")
    ap.add_argument("--flip", type=float, nargs="+", default=[0.0])
    ap.add_argument("--step", type=float, nargs="+", default=[None], help="k: the step forced to k dx / c")
    a = ap.parse_args()
    print("| sampling | ends | width [cells] | flip | step [dx/c] | axial stiffness / M | period [s] | decay per period "
          "| steps | wall [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for sampling in a.sampling:
        for width in a.width:
            for ends in a.ends:
                for flip in a.flip:
                    for step in a.step:
                        bar(sampling, ends, width, flip, step)


if __name__ == "__main__":
    main()
