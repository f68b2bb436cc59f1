"""The step rules' errors at equal resolution on each sampling: docs/results.md ('The step rule').

Usage: NUMBA_NUM_THREADS=1 python bench/study_sampling.py [--problems bar column] [--sampling lattice relaxed jittered]
       [--cfl 0.25 0.4] [--levels 4]
`pdmpm study`'s space ladder of a built-in problem (its errors against the analytic answer) with the body's
sampling replaced, under `simulation.step: conservative` and `auto` at each cfl. The studies themselves use
jittered clouds; the scenes' default is relaxed; a lattice passes the bonds' patch test (no particle-scale forces
under a smooth strain, so no creep: bench/column_creep.py).
"""

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pdmpm_cli.study.ladder import problem_study  # noqa: E402
from pdmpm_cli.study.problems import PROBLEMS  # noqa: E402


def errors(name: str, sampling: str, levels: int, sets: list[str]):
    problem = PROBLEMS[name]

    def scene(cell, *args, _make=problem.scene):
        d = _make(cell, *args)
        for body in d["bodies"]:
            body["geometry"]["sampling"] = sampling
        return d

    study = problem_study(dataclasses.replace(problem, scene=scene), levels, 0, overrides=sets)
    return [(r.cell_size_m, r.error, r.steps) for r in study.runs]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", nargs="+", default=["bar", "column"])
    ap.add_argument("--sampling", nargs="+", default=["lattice", "relaxed", "jittered"])
    ap.add_argument("--cfl", type=float, nargs="+", default=[0.25, 0.4])
    ap.add_argument("--levels", type=int, default=4)
    a = ap.parse_args()
    print("| problem | sampling | dx [m] | conservative: error (steps) | "
          + " | ".join(f"auto {c:g}: error (steps), change" for c in a.cfl) + " |")
    print("|---" * (4 + len(a.cfl)) + "|")
    for name in a.problems:
        for sampling in a.sampling:
            base = errors(name, sampling, a.levels, [])
            rules = [errors(name, sampling, a.levels, ["simulation.step=auto", f"simulation.cfl={c}"]) for c in a.cfl]
            for i, (dx, err, steps) in enumerate(base):
                cells = [f"{r[i][1]:.4g} ({r[i][2]}), {100 * (r[i][1] / err - 1):+.0f} %" for r in rules]
                print(f"| {name} | {sampling} | {dx:.3g} | {err:.4g} ({steps}) | " + " | ".join(cells) + " |",
                      flush=True)


if __name__ == "__main__":
    main()
