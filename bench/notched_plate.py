"""Mode-I crack from a notch half a cell wide: where the damage goes (pdmpm_cli/study/fracture.py: plate_scene).

Usage: python bench/notched_plate.py [--cells 0.04 0.02] [--energy 2.0] [--damage-resistance K] [--until 0.3]
    [--cracks auto|shared|separate]
A 0.48 x 0.48 x 0.06 m plate with an edge notch 0.12 m long at mid-height is pulled apart by grips on its top and
bottom edges. Printed per grid cell size, at the first separation (two pieces over 5 % of the mass; or at --until):
how far the damage reached along the crack's path, and how wide its band is, as the damaged particles' rest
distance from the notch's plane (median, 90th percentile, largest), in metres and in particle spacings h, among the
particles more than a horizon from the grips (damage at the grips' edges is counted apart).
"""

import argparse
import time

import numpy as np

from pdmpm_cli.study.fracture import GRIP, damage_band, large_pieces, plate_scene
from pdmpm_cli.study.sim import Sim

COLUMNS = ("cell [m]", "h [m]", "particles", "threshold", "time [s]", "large pieces", "damaged", "at grips",
           "along the notch", "reach [m]", "band p50 [h]", "band p90 [h]", "band max [h]", "band p90 [m]", "run [s]")
NOTCH = 0.12  # plate_scene's notch length [m]


def run(cell: float, energy: float, resistance: float | None, until: float, cracks: str) -> list[str]:
    t0 = time.perf_counter()
    scene = plate_scene(cell, energy, notch=NOTCH, duration=until)
    if resistance is not None:
        scene["bodies"][0]["fracture"]["damage_resistance"] = resistance
    scene["contact"] = {"cracks": cracks}
    sim = Sim(scene)
    state, model = sim.state, sim.model
    while state.time < until - 1e-12:
        sim.solver.advance(state, min(state.time + sim.plan.frame_dt, until))
        if state.bonds_cut and large_pieces(state, model) >= 2:
            break
    size = model.rest_x[:, 1].max() - model.rest_x[:, 1].min()
    band = damage_band(model, state, grip=GRIP * size, notch=NOTCH)
    b = model.bodies[0]
    h = b.spacing
    return [f"{cell:g}", f"{h:g}", str(b.end - b.start), f"{b.fracture.threshold:.4g}", f"{state.time:.3f}",
            str(large_pieces(state, model)), str(band["damaged"]), str(band["at_grips"]), str(band["at_faces"]),
            f"{band['reach']:.3f}", f"{band['p50'] / h:.1f}",
            f"{band['p90'] / h:.1f}", f"{band['max'] / h:.1f}", f"{band['p90']:.3f}", f"{time.perf_counter() - t0:.0f}"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=float, nargs="+", default=[0.04, 0.02])
    ap.add_argument("--energy", type=float, default=2.0, help="G_c [J/m^2]")
    ap.add_argument("--damage-resistance", type=float, default=None, help="default: the scene's (0 with an energy)")
    ap.add_argument("--until", type=float, default=0.3, help="stop here if it has not separated [s]")
    ap.add_argument("--cracks", choices=("auto", "shared", "separate"), default="auto", help="contact.cracks")
    args = ap.parse_args()
    np.set_printoptions(precision=3)
    print("| " + " | ".join(COLUMNS) + " |")
    print("|" + "---|" * len(COLUMNS))
    for cell in args.cells:
        cells = run(cell, args.energy, args.damage_resistance, args.until, args.cracks)
        print("| " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
