"""Liquids that keep their volume: the figures of docs/results.md ('Liquids').

Usage: python bench/fluids.py [column|dam|couette|all] [--long] [--cell 0.01] [--shift 0]
- column: a liquid column at rest in a tank at 1000 and 1400 kg/m^3 over 100 relaxation times: height, particle
  volume (bulk Voronoi cells) and nearest spacing relative to the start, worst over the run; the same column without
  the volume pressure (bulk_modulus 1 Pa) for comparison.
- dam: a released block of liquid, its particle volume and surface height over time; `--cell` sets the grid cell
  (default 0.02 m, the tests'; at 0.01 m the layer it spreads into is six spacings deep instead of three, deep
  enough for the bulk Voronoi measure), `--shift` the liquid's shift_distance (0: no particle shift).
- couette: start-up Couette flow, mid-layer velocity against the analytic series with the stated viscosity.
--long runs the slow tests' sizes and durations (tests/test_fluids.py)."""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pdmpm_cli.scene.loader import merge  # noqa: E402
from pdmpm_cli.study.sim import Sim  # noqa: E402
from tests import fluid_cases as F  # noqa: E402


def column(long: bool):
    print("| density [kg/m^3] | bulk modulus [Pa] | duration [s] | tau [s] | height | volume | nearest spacing "
          "| wall [s] |")
    print("|---|---|---|---|---|---|---|---|")
    cases = [(rho, None) for rho in (1000.0, 1400.0)] + [(1000.0, 1.0)]
    for rho, bulk in cases:
        scene = F.column(rho, 1.0, size=(0.08, 0.2, 0.08), tau=0.01) if long else F.column(rho, 0.1, tau=0.001)
        if bulk is not None:
            scene = merge(scene, {"bodies": [merge(scene["bodies"][0], {"material": {"bulk_modulus": bulk}})]})
        t0 = time.perf_counter()
        sim = Sim(scene)
        h = sim.model.bodies[0].spacing
        x0 = sim.state.particle_x.copy()
        start = np.array([F.surface_height(x0, h, 0.1), F.occupied_volume(x0, h), F.nearest_spacing(x0)])
        worst = np.zeros(3)
        duration = scene["simulation"]["duration"]
        for t in np.linspace(0, duration, 11)[1:]:
            sim.advance(t)
            x = sim.state.particle_x
            now = np.array([F.surface_height(x, h, 0.1), F.occupied_volume(x, h), F.nearest_spacing(x)]) / start - 1
            worst = np.where(np.abs(now) > np.abs(worst), now, worst)
        k = sim.model.bodies[0].params.bulk_modulus
        tau = scene["bodies"][0]["material"]["relaxation_time"]
        print(f"| {rho:.0f} | {k:.3g} | {duration:g} | {tau:g} | {worst[0]:+.2%} | {worst[1]:+.2%} | {worst[2]:+.2%} "
              f"| {time.perf_counter() - t0:.0f} |", flush=True)


def dam(long: bool, cell: float = 0.02, shift: float | None = None):
    duration = 0.4 if long else 0.12
    sim = Sim(F.dam_break(duration, dx=cell, **({} if shift is None else {"shift_distance": shift})))
    h = sim.model.bodies[0].spacing
    x0 = sim.state.particle_x
    v0, s0 = F.occupied_volume(x0, h), F.nearest_spacing(x0)
    print(f"dam break, {sim.plan.particles} particles, bulk modulus {sim.model.bodies[0].params.bulk_modulus:.3g} Pa")
    print("| t [s] | particle volume / start | mean J | surface height [mm] | nearest spacing / start |")
    print("|---|---|---|---|---|")
    for t in np.linspace(0, duration, 9)[1:]:
        sim.advance(t)
        x = sim.state.particle_x
        print(f"| {t:.3f} | {F.occupied_volume(x, h) / v0:.4f} | {sim.state.particle_J.mean():.4f} | "
              f"{F.surface_height(x, h, 0.1) * 1e3:.1f} | {F.nearest_spacing(x) / s0:.3f} |", flush=True)


def couette(long: bool):
    length = 0.4 if long else 0.2
    scene = F.couette(0.3, length=length)
    sim = Sim(scene)
    mat, plate = scene["bodies"][0]["material"], scene["colliders"][1]
    nu = mat["relaxing_fraction"] * mat["mu"] * mat["relaxation_time"] / mat["density"]
    y0, depth, speed = scene["colliders"][0]["point"][1], plate["point"][1] - scene["colliders"][0]["point"][1], \
        plate["velocity"][0]
    dx, h = sim.model.dx, sim.model.bodies[0].spacing
    held = depth + dx  # the held node rows lie half a cell beyond each wall
    centre = (0.1 + length / 2, y0 + depth / 2)
    print(f"start-up Couette flow: {sim.plan.particles} particles, nu = l mu tau / rho = {nu:g} m^2/s, "
          f"U = {speed} m/s, H = {depth} m between the walls ({held:.3g} m between the held node rows)")
    print("| t [s] | u_mid [m/s] | series, H between walls | error | series, H between held nodes | error |")
    print("|---|---|---|---|---|---|")
    for t in np.linspace(0, 0.3, 11)[1:]:
        sim.advance(t)
        u = F.mid_layer_velocity(sim.state.particle_x, sim.state.particle_v, h, centre, depth)
        a, b = F.couette_mid_velocity(t, depth, nu, speed), F.couette_mid_velocity(t, held, nu, speed)
        print(f"| {t:.2f} | {u:.4f} | {a:.4f} | {u / a - 1:+.1%} | {b:.4f} | {u / b - 1:+.1%} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", nargs="?", default="all", choices=["column", "dam", "couette", "all"])
    ap.add_argument("--long", action="store_true")
    ap.add_argument("--cell", type=float, default=0.02, help="dam: grid cell size [m]")
    ap.add_argument("--shift", type=float, default=None, help="dam: shift_distance (default: the material's)")
    args = ap.parse_args()
    for name, fn in (("column", column), ("dam", lambda long: dam(long, args.cell, args.shift)),
                     ("couette", couette)):
        if args.case in (name, "all"):
            fn(args.long)


if __name__ == "__main__":
    main()
