"""The FLIP share (simulation.flip): the figures of docs/results.md ('FLIP share and MUSL').

Usage: python bench/flip.py [bar|free|spheres] --flip 0 0.95 1 [--radius 10] [--sampling jittered relaxed lattice]
       [--bond-safety 0.35 0.7 1] [--step 0.133 0.4] [--walls 1]
- bar: Sulsky's bar as tests/test_dynamics.py runs it (fixed end, slip walls, 2 periods): period, first amplitude,
  decay of the centre-of-mass velocity's amplitude per period, energy at the end over the initial kinetic energy.
  `--step k` forces the step to k dx / c on a copy of the Plan (as `pdmpm stability`'s forced rows do; the 0.05 s
  frames still cap it): how the number of transfers, not the bound that sets it, changes the bar.
- free: the same column free at both ends in its first mode (period 2 L / c = 5 s), 20 s: period and decay per
  period of its ends' velocity, and energy (kinetic with APIC's affine part, plus strain) at the end over the start.
- spheres: the sphere pair of bench/contact.py (tests/contact_cases.py) with the FLIP share.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pdmpm_cli.study.problems import BAR_LENGTH, BAR_V0, bar_scene, bar_start, period  # noqa: E402
from pdmpm_cli.study.sim import Sim  # noqa: E402
from tests import contact_cases as C  # noqa: E402


def with_flip(d: dict, flip: float) -> dict:
    return {**d, "simulation": {**d["simulation"], "flip": flip}}


def energy(sim: Sim) -> float:
    """Kinetic (particles and APIC's affine part 1/2 m (dx^2 / 3) C:C) plus strain energy [J]."""
    s, m, dx = sim.state, sim.model.particle_mass, sim.model.dx
    affine = 0.5 * m @ np.einsum("ijk,ijk->i", s.particle_C, s.particle_C) * dx * dx / 3
    return sim.solver.kinetic_energy(s) + sim.solver.strain_energy(s) + affine


def bar(flip: float, sampling: str, bond_safety: float, step: float | None = None):
    d = with_flip(bar_scene(1.25, 2.0), flip)
    d["bodies"][0]["geometry"]["sampling"] = sampling
    d["simulation"]["bond_safety"] = bond_safety
    sim = Sim(d)
    if step is not None:
        sim.force_step(step)
    bar_start(sim)
    mass = sim.model.particle_mass.sum()
    e0 = energy(sim)
    t, v = [0.0], [sim.momentum()[0] / mass]
    t0 = time.perf_counter()
    def record(st, dt):
        t.append(st.time)
        v.append(sim.momentum()[0] / mass)

    sim.advance(20.0, record)
    t, v = np.array(t), np.array(v)
    amp = [np.abs(v[(t >= a) & (t < a + 10.0)]).max() for a in (0.0, 10.0)]
    forced = "-" if step is None else f"{step:g}"
    print(f"| {flip:g} | {sampling} | {bond_safety:g} | {forced} | {period(t, v):.4f} | {amp[0]:.5f} | "
          f"{100 * (1 - amp[1] / amp[0]):.2f} % | "
          f"{energy(sim) / e0:.3f} | {sim.state.step} | {time.perf_counter() - t0:.0f} |", flush=True)


def free(flip: float, sampling: str, walls: bool):
    d = with_flip(bar_scene(1.25, 2.0), flip)
    d["colliders"] = d["colliders"][1:] if walls else []
    d["bodies"][0]["geometry"]["sampling"] = sampling
    sim = Sim(d)
    s, m = sim.state, sim.model.particle_mass
    x = s.particle_x[:, 0] - s.particle_x[:, 0].min()
    s.particle_v[:, 0] = BAR_V0 * np.cos(np.pi * x / BAR_LENGTH)
    sim.solver.start(s)
    end = x > BAR_LENGTH - 2 * sim.model.dx
    e0 = energy(sim)
    t, v = [0.0], [float(m[end] @ s.particle_v[end, 0] / m[end].sum())]
    def record(st, dt):
        t.append(st.time)
        v.append(float(m[end] @ st.particle_v[end, 0] / m[end].sum()))

    sim.advance(20.0, record)
    t, v = np.array(t), np.array(v)
    amp = [np.abs(v[(t >= a) & (t < a + 5.0)]).max() for a in (0.0, 5.0, 10.0, 15.0)]
    decay = ", ".join(f"{100 * (1 - b / a):.1f}" for a, b in zip(amp, amp[1:]))
    print(f"| {flip:g} | {sampling} | {'slip' if walls else 'none'} | {period(t, v):.3f} | {decay} % | "
          f"{energy(sim) / e0:.3f} | {s.step} |", flush=True)


def spheres(flip: float, radius: float):
    pair = C.sphere_pair
    C.sphere_pair = lambda *a, **k: with_flip(pair(*a, **k), flip)
    try:
        o = C.sphere_collision(radius)
    finally:
        C.sphere_pair = pair
    print(f"| {radius:g} | {flip:g} | {o['steps']} | {o['momentum']:.1e} | {100 * o['ke']:.1f} % | "
          f"{100 * o['energy']:.1f} % | {o['apart']:+.2f} | {o['seconds']:.0f} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["bar", "free", "spheres"])
    ap.add_argument("--flip", type=float, nargs="+", default=[0.0, 0.95, 1.0])
    ap.add_argument("--radius", type=float, default=10.0, help="sphere radius [spacings]")
    ap.add_argument("--sampling", nargs="+", default=["jittered"], help="bar, free: the column's sampling")
    ap.add_argument("--bond-safety", type=float, nargs="+", default=[0.7],
                    help="bar: simulation.bond_safety (the step, hence the number of transfers)")
    ap.add_argument("--step", type=float, nargs="+", default=[None],
                    help="bar: force the step to these multiples of dx / c (default: the Plan's)")
    ap.add_argument("--walls", type=int, default=1, help="free: 1 keeps the slip walls on the long sides")
    a = ap.parse_args()
    if a.what == "bar":
        print("| flip | sampling | bond_safety | forced step [dx/c] | period [s] | v_com amplitude | "
              "decay per period | energy end / start | steps | wall [s] |")
        print("|---|---|---|---|---|---|---|---|---|---|")
    elif a.what == "free":
        print("| flip | sampling | walls | period [s] | end-velocity decay per period | energy end / start | steps |")
        print("|---|---|---|---|---|---|---|")
    else:
        print("| radius [spacings] | flip | steps | momentum change | KE after / before | energy after / before | "
              "gap at end [cells] | wall [s] |")
        print("|---|---|---|---|---|---|---|---|")
    for flip in a.flip:
        for sampling in a.sampling:
            if a.what == "bar":
                for safety in a.bond_safety:
                    for step in a.step:
                        bar(flip, sampling, safety, step)
            elif a.what == "free":
                free(flip, sampling, bool(a.walls))
        if a.what == "spheres":
            spheres(flip, a.radius)


if __name__ == "__main__":
    main()
