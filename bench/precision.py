"""float32 against float64 on the reduced Table 1 cases (tests/table1.py): metrics and final positions.

Usage: NUMBA_NUM_THREADS=1 python bench/precision.py [board_elastic bunnies_plastic ...]

Runs each case at simulation.precision float64, then float32, in this process, and prints one markdown table: per
case and metric the two values and their relative difference, the metric's regression tolerance, and the RMS and
largest difference of the final particle positions over the bodies' bounding-box diagonal. docs/results.md,
'float32'.
"""

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.table1 import CASES, run_case  # noqa: E402

SINGLE = ("simulation.precision=float32",)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", default=["board_elastic", "bunnies_plastic"], help="tests/table1.py cases")
    args = ap.parse_args()
    print("| case | metric | float64 | float32 | relative difference | tolerance | positions: RMS / max over the "
          "bodies' diagonal |")
    print("|---|---|---|---|---|---|---|")
    for name in args.cases:
        (t64, m64), (t32, m32) = run_case(name), run_case(name, extra=SINGLE)
        x64, x32 = t64.state.particle_x, t32.state.particle_x
        diag = float(np.linalg.norm(np.ptp(t64.model.rest_x, axis=0)))
        d = np.linalg.norm(x32 - x64, axis=1) / diag
        where = f"{np.sqrt(np.mean(d * d)):.1e} / {d.max():.1e}"
        for k, v in m64.items():
            rel = abs(m32[k] - v) / max(abs(v), 1e-300)
            tol = f"{CASES[name].tolerance[k]:g}" + (f" + {CASES[name].absolute[k]:g}" if k in CASES[name].absolute
                                                      else "")
            print(f"| {name} | {k} | {v:.5g} | {m32[k]:.5g} | {rel:.1e} | {tol} | {where} |", flush=True)


if __name__ == "__main__":
    main()
