"""Regression of the paper's Table 1 scenes (scenes/*.yaml) at a reduced resolution.

Each case runs one bundled scene with overrides that make it small enough for CI, then measures the behaviour
its figure shows as numbers (a board springs back or keeps a dent, a wall breaks into a few large pieces, ...).
tests/test_table1.py asserts the behaviour and compares every metric with the stored baseline
(tests/baselines/table1.json) within its tolerance, so an unintended change of the physics fails CI.

Regenerate the baselines after an intended change, and review the diff:

    python -m tests.table1 --update          # all cases; or name some: python -m tests.table1 --update cloth_soft

`--set key=value` adds an override to every case (e.g. `--set simulation.precision=float32`) and prints the metrics
outside their tolerance of the stored baselines.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.spatial import cKDTree

from pdmpm_cli.engine.fracture import pieces
from pdmpm_cli.engine.state import State
from pdmpm_cli.runner import prepare, start_in_memory

ROOT = Path(__file__).resolve().parents[1]
BASELINES = Path(__file__).resolve().parent / "baselines" / "table1.json"


@dataclass
class Trace:
    """A finished reduced run: the model, the final state, and particle positions at every frame."""

    model: object
    state: State
    x: list[np.ndarray]
    seconds: float

    def body(self, index: int) -> slice:
        s, e = self.model.body_ranges[index]
        return slice(s, e)


@dataclass(frozen=True)
class Case:
    """One Table 1 scene at CI resolution: its overrides, its metrics with their relative (and optional
    absolute, for values near zero) tolerances, and a material change that the baseline comparison must catch."""

    scene: str
    reduced: tuple[str, ...]
    metrics: Callable[[Trace], dict[str, float]]
    tolerance: dict[str, float]
    perturb: str
    variant: str | None = None
    absolute: dict[str, float] = field(default_factory=dict)


# ---------------------------------------------------------------- metrics


def rigid_residual(x: np.ndarray, x0: np.ndarray) -> float:
    """RMS distance of x from the best rigid motion of x0 (Kabsch): how far a body is from its rest shape."""
    a, b = x0 - x0.mean(axis=0), x - x.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(u @ vt))
    r = u @ np.diag([1.0, 1.0, d]) @ vt
    return float(np.sqrt(((a @ r - b) ** 2).sum(axis=1).mean()))


def fragments(trace: Trace, body: int = 0) -> np.ndarray:
    """Sizes (particles) of the connected pieces of a body over its intact bonds, largest first."""
    st, sl = trace.state, trace.body(body)
    return np.sort(np.bincount(pieces(st.bond_start, st.bond_nbr, st.bond_active == 1, sl.start, sl.stop)))[::-1]


FOLD_DEGREE = 6


def fold_amplitude(trace: Trace) -> dict[str, float]:
    """Cloth: the folds are what a smooth fit of the hanging cloth misses; their RMS amplitude, and the mean sag.
    The fit is a polynomial of degree FOLD_DEGREE in the sheet's rest coordinates: the swag between the pegs is
    no quadratic (a quadratic's residual is the swag itself, ~10 mm, and does not follow mu), while degree 6
    follows shapes down to about a third of the cloth and leaves the folds."""
    x0, x = trace.model.rest_x, trace.x[-1]
    u, v = x0[:, 0] - x0[:, 0].mean(), x0[:, 2] - x0[:, 2].mean()
    basis = np.stack([u ** i * v ** j for i in range(FOLD_DEGREE + 1) for j in range(FOLD_DEGREE + 1 - i)], axis=1)
    fit = basis @ np.linalg.lstsq(basis, x, rcond=None)[0]
    return {"fold_rms_mm": 1e3 * float(np.sqrt(((x - fit) ** 2).sum(axis=1).mean())),
            "sag_mm": 1e3 * float((x0[:, 1] - x[:, 1]).mean())}


def beam_sags(trace: Trace) -> dict[str, float]:
    """Beams: the final sag of each beam's middle (particles within 5 cm of mid-span)."""
    out = {}
    for i, name in enumerate(("mu0", "mu50", "mu500")):
        sl = trace.body(i)
        x0, x = trace.model.rest_x[sl], trace.x[-1][sl]
        mid = np.abs(x0[:, 0] - x0[:, 0].mean()) < 0.05
        out[f"sag_{name}_mm"] = 1e3 * float((x0[mid, 1] - x[mid, 1]).mean())
    return out


def board_dent(trace: Trace) -> dict[str, float]:
    """Boards: the deflection (along the throw, x) of the board's centre patch, its peak over the run and
    what is left at the end."""
    sl = trace.body(0)
    x0 = trace.model.rest_x[sl]
    c = x0.mean(axis=0)
    patch = np.hypot(x0[:, 1] - c[1], x0[:, 2] - c[2]) < 0.06
    defl = np.array([(x[sl][patch, 0] - x0[patch, 0]).mean() for x in trace.x])
    residual = defl[-5:].mean()  # over the last 5 frames (0.1 s), so a left-over swing averages out
    return {"peak_mm": 1e3 * float(defl.max()), "residual_mm": 1e3 * float(residual),
            "residual_ratio": float(residual / defl.max())}


def bunny_shapes(trace: Trace) -> dict[str, float]:
    """Bunnies: distance from the rest shape (rigid fit removed), mean of the two bunnies, at its peak and at the
    end (relative to the bunny height); the gap between them at the end (closest particles of the two, less one
    spacing: surface to surface); and their restitution: the fastest the centres of mass move apart after their
    closest approach, over how fast they closed in the first frame (before they bounce off the domain walls)."""
    x0, x, m = trace.model.rest_x, trace.x[-1], trace.model.particle_mass
    height = np.ptp(x0[trace.body(0), 1])
    dev = np.array([np.mean([rigid_residual(x[trace.body(i)], x0[trace.body(i)]) for i in (0, 1)])
                    for x in trace.x]) / height
    gap = cKDTree(x[trace.body(0)]).query(x[trace.body(1)])[0].min() - trace.model.bodies[0].spacing
    d = np.array([np.subtract(*[m[trace.body(i)] @ x[trace.body(i), 0] / m[trace.body(i)].sum() for i in (1, 0)])
                  for x in trace.x])
    step = np.diff(d)
    return {"peak_deformation": float(dev.max()), "final_deformation": float(dev[-1]),
            "recovery_ratio": float(dev[-1] / dev.max()), "gap_mm": 1e3 * float(gap),
            "restitution": float(max(step[np.argmin(d):].max(), 0.0) / -step[0])}


def wall_pieces(trace: Trace) -> dict[str, float]:
    """Wall: pieces over 5 % of the wall, the share of the wall they hold, and the share left as dust (pieces of
    fewer than 5 cells)."""
    sizes = fragments(trace, 0)
    n = sizes.sum()
    large = sizes[sizes > 0.05 * n]
    return {"large_pieces": float(len(large)), "large_share": float(large.sum() / n),
            "dust_share": float(sizes[sizes < 5].sum() / n)}


def pile(trace: Trace) -> dict[str, float]:
    """Honey: the poured pile's height and its RMS radius on the plate, relative to the stream's radius (the rest
    positions: the head and the nozzle's layers), and its volume sum V0 J over the volume poured (head and every
    born particle's h^3: rate x time)."""
    x0, x = trace.model.rest_x, trace.x[-1]
    r0 = np.sqrt(((x0[:, [0, 2]] - x0[:, [0, 2]].mean(axis=0)) ** 2).sum(axis=1).mean())
    r = np.sqrt(((x[:, [0, 2]] - x[:, [0, 2]].mean(axis=0)) ** 2).sum(axis=1).mean())
    volume = trace.model.particle_volume
    return {"spread_ratio": float(r / r0), "height_mm": 1e3 * float(np.ptp(x[:, 1])),
            "volume_ratio": float(volume @ trace.state.particle_J / volume.sum())}


def splat(trace: Trace) -> dict[str, float]:
    """Cream pie: on the wall (normal x) the RMS radius in the wall's plane and the thickness off the wall, each
    relative to the pie's initial radius and thickness."""
    x0, x = trace.model.rest_x, trace.x[-1]
    rms = lambda p: np.sqrt(((p[:, [1, 2]] - p[:, [1, 2]].mean(axis=0)) ** 2).sum(axis=1).mean())  # noqa: E731
    return {"spread_ratio": float(rms(x) / rms(x0)),
            "thickness_ratio": float(np.ptp(x[:, 0]) / np.ptp(x0[:, 0]))}


# ---------------------------------------------------------------- the cases

CLOTH = ("grid.cell_size=0.02", "simulation.duration=0.8")
BOARD = ("grid.cell_size=0.04", "bodies.0.geometry.spacing=0.02", "bodies.0.geometry.layers=1",
         "bodies.1.geometry.spacing=0.02")
BUNNIES = ("grid.cell_size=0.03",)

CASES: dict[str, Case] = {
    **{f"cloth_{v}": Case("cloth.yaml", CLOTH, fold_amplitude, {"fold_rms_mm": 0.1, "sag_mm": 0.02},
                          "bodies.0.material.mu=5e4", variant=v) for v in ("soft", "medium", "stiff")},
    "beams": Case("beams.yaml", ("grid.cell_size=0.075", *(f"bodies.{i}.geometry.spacing=0.0375" for i in range(3)),
                                 *(f"bodies.{i}.geometry.layers=2" for i in range(3)), "simulation.duration=2.0"),
                  beam_sags, {"sag_mu0_mm": 0.03, "sag_mu50_mm": 0.03, "sag_mu500_mm": 0.03},
                  "bodies.2.material.mu=250"),
    "board_elastic": Case("board_elastic.yaml", BOARD, board_dent,
                          {"peak_mm": 0.1, "residual_mm": 0.5, "residual_ratio": 0.5}, "bodies.0.material.lam=1.5e6",
                          absolute={"residual_mm": 0.5, "residual_ratio": 0.05}),
    "board_plastic": Case("board_plastic.yaml", BOARD, board_dent,
                          {"peak_mm": 0.1, "residual_mm": 0.15, "residual_ratio": 0.15},
                          "bodies.0.material.yield_stress=5.3e4"),
    "bunnies_elastic": Case("bunnies_elastic.yaml", BUNNIES, bunny_shapes,
                            {"peak_deformation": 0.1, "final_deformation": 0.5, "recovery_ratio": 0.5, "gap_mm": 0.1,
                             "restitution": 0.1},
                            "bodies.0.material.mu=2.5e4", absolute={"final_deformation": 0.003, "recovery_ratio": 0.05}),
    "bunnies_plastic": Case("bunnies_plastic.yaml", BUNNIES, bunny_shapes,
                            {"peak_deformation": 0.1, "final_deformation": 0.15, "recovery_ratio": 0.15, "gap_mm": 0.5,
                             "restitution": 0.2},
                            "bodies.0.material.yield_stress=3.2e4", absolute={"gap_mm": 2.0, "restitution": 0.02}),
    "wall_break": Case("wall_break.yaml", ("simulation.duration=0.4",), wall_pieces,
                       {"large_pieces": 0.0, "large_share": 0.1, "dust_share": 0.3}, "bodies.0.fracture.threshold=0.1",
                       absolute={"large_pieces": 1.0, "dust_share": 0.02}),
    "honey": Case("honey.yaml", ("grid.cell_size=0.1", "bodies.0.geometry.shape.radius=0.1",
                                 "bodies.0.emitter.shape.radius=0.1", "bodies.0.emitter.shape.height=0.05",
                                 "bodies.0.emitter.stop=1.2", "simulation.duration=2.0"),
                  pile, {"spread_ratio": 0.1, "height_mm": 0.1, "volume_ratio": 0.01},
                  "bodies.0.material.bulk_modulus=2e4"),
    "cream_pie": Case("cream_pie.yaml", ("grid.cell_size=0.06", "simulation.duration=0.5"), splat,
                      {"spread_ratio": 0.05, "thickness_ratio": 0.1}, "bodies.0.material.bulk_modulus=2e4"),
}


# ---------------------------------------------------------------- running and comparing


@cache
def run_case(name: str, perturbed: bool = False, extra: tuple[str, ...] = ()) -> tuple[Trace, dict[str, float]]:
    """Run a case (once per process; with its material perturbation if asked, and `extra` overrides) and measure
    it."""
    case = CASES[name]
    overrides = [*case.reduced, *([case.perturb] if perturbed else []), *extra]
    prep = prepare(ROOT / "scenes" / case.scene, overrides, case.variant)
    plan = prep.plan
    state, solver = start_in_memory(prep)
    t0 = time.perf_counter()
    xs = [state.particle_x.copy()]
    for i in range(1, plan.frames + 1):
        solver.advance(state, i * plan.frame_dt)
        xs.append(state.particle_x.copy())
    trace = Trace(solver.model, state, xs, time.perf_counter() - t0)  # the solver's: an emitter grows it
    return trace, case.metrics(trace)


def load_baselines() -> dict[str, dict[str, float]]:
    return json.loads(BASELINES.read_text()) if BASELINES.exists() else {}


def deviations(name: str, metrics: dict[str, float], baseline: dict[str, float]) -> list[str]:
    """The metrics outside their tolerance of the baseline: |value - base| > rel * |base| + abs."""
    case = CASES[name]
    out = []
    for key, base in baseline.items():
        allowed = case.tolerance[key] * abs(base) + case.absolute.get(key, 0.0)
        if abs(metrics[key] - base) > allowed:
            out.append(f"{name}.{key} = {metrics[key]:.4g}, baseline {base:.4g} +- {allowed:.3g}")
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("cases", nargs="*", help="case names (default all)")
    parser.add_argument("--update", action="store_true", help="write the measured metrics as the new baselines")
    parser.add_argument("--perturbed", action="store_true", help="also run each case's material perturbation")
    parser.add_argument("--set", dest="extra", action="append", default=[],
                        help="an override for every case; the metrics are then compared with the baselines")
    args = parser.parse_args(argv)
    if args.extra and args.update:
        parser.error("--set runs other cases than the baselines': leave out --update")
    names = args.cases or list(CASES)
    baselines = load_baselines()
    for name in names:
        trace, metrics = run_case(name, extra=tuple(args.extra))
        line = ", ".join(f"{k} {v:.4g}" for k, v in metrics.items())
        print(f"{name:16s} {trace.model.n_particles:6d} particles {trace.seconds:6.1f} s  {line}", flush=True)
        if args.extra and name in baselines:
            bad = deviations(name, metrics, baselines[name])
            print(f"{'':16s} against the baselines: {'; '.join(bad) if bad else 'all within tolerance'}", flush=True)
        if args.perturbed:
            _, pm = run_case(name, perturbed=True, extra=tuple(args.extra))
            bad = deviations(name, pm, metrics)
            print(f"{'':16s} perturbed ({CASES[name].perturb}): " + ", ".join(f"{k} {v:.4g}" for k, v in pm.items())
                  + f"  -> {'caught' if bad else 'NOT caught'}", flush=True)
        if args.update:
            baselines[name] = metrics
    if args.update:
        BASELINES.parent.mkdir(exist_ok=True)
        BASELINES.write_text(json.dumps(baselines, indent=2, sort_keys=True) + "\n")
        print(f"wrote {BASELINES}")


if __name__ == "__main__":
    main()
