"""Parameter sweeps on Dask distributed: the cartesian product of `--param` values (and scene variants), each
variant a normal `simulate` into its own folder on a worker, and a summary table of every variant's parameters,
status, run time and final-state metrics.

A variant is a list of `--set` overrides, so it is validated by the scene loader like any run, all of them before
the first is submitted. Failures that only show at run time (a mesh that is missing, a body outside the domain, a
simulation that blows up) are the variant's status; the others go on.
"""

from __future__ import annotations

import hashlib
import itertools
import logging
import math
import os
import re
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pdmpm_cli.errors import InputError, PdmpmError
from pdmpm_cli.io.atomic import atomic_write_text
from pdmpm_cli.scene.loader import OVERRIDE, SceneError, load_scene
from pdmpm_cli.scene.schema import Scene

PARAM = "--param"
VARIANT_KEY = "variant"
METRICS = ("steps", "particles", "frames", "max_displacement_m", "kinetic_energy_J", "max_speed_m_s",
           "broken_bond_fraction")
_UNSAFE = re.compile(r"[^A-Za-z0-9._=,+-]+")
_MAX_NAME = 120


@dataclass(frozen=True)
class Variant:
    """One point of the sweep: its folder name, its values (as written) and what `prepare` takes."""

    name: str
    params: dict[str, str]  # dotted key (or "variant") -> value text
    overrides: tuple[str, ...]  # the common --set items, then this variant's --param values
    variant: str | None


def split_values(text: str) -> list[str]:
    """Split `v1,v2,...` at the commas outside brackets, braces and quotes: `[0,1,0],[0,2,0]` is two values."""
    values, current, depth, quote = [], "", 0, ""
    for ch in text:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            values.append(current.strip())
            current = ""
            continue
        current += ch
    return values + [current.strip()]


def parse_param(item: str) -> tuple[str, list[str]]:
    """`dotted.key=v1,v2,...` -> (key, [v1, v2, ...])."""
    key, sep, text = item.partition("=")
    key = key.strip()
    values = split_values(text)
    if not sep or not key or not all(key.split(".")) or not all(values):
        raise InputError(f"{PARAM} {item!r}: expected KEY=V1,V2,... e.g. {PARAM} bodies.0.material.mu=2e4,1e5,1.5e5")
    if len(set(values)) < len(values):
        raise InputError(f"{PARAM} {key}: repeated value in {text!r}")
    return key, values


def _labels(keys: list[str]) -> dict[str, str]:
    """Folder-name label of each key: its last segment where no other key ends the same way, else the full key."""
    last = [k.rsplit(".", 1)[-1] for k in keys]
    return {k: s if last.count(s) == 1 else k for k, s in zip(keys, last)}


def _folder(params: dict[str, str], labels: dict[str, str]) -> str:
    """`key=value,...` with filesystem- and shell-safe characters only: [0, 1.5, 0] -> 0_1.5_0."""
    values = {k: re.sub(r"[\[\]{}'\" ]", "", v).replace(",", "_") for k, v in params.items()}
    name = _UNSAFE.sub("_", ",".join(f"{labels.get(k, k)}={v}" for k, v in values.items()))
    if len(name) > _MAX_NAME:
        name = f"{name[:_MAX_NAME - 9]}-{hashlib.sha1(name.encode()).hexdigest()[:8]}"
    return name


def expand(scene: Path, params: list[str], variants: list[str], common: list[str]) -> list[Variant]:
    """Every combination of the scene variants and --param values, each validated; InputError (naming the key)
    on the first that is not a valid scene."""
    grid = [parse_param(p) for p in params]
    keys = [k for k, _ in grid]
    if len(set(keys)) < len(keys):
        raise InputError(f"{PARAM}: the key {next(k for k in keys if keys.count(k) > 1)} is given twice; list all "
                         f"its values in one {PARAM}")
    if not grid and not variants:
        raise InputError(f"nothing to sweep: give {PARAM} KEY=V1,V2,... or --variant NAME (or both)")
    labels = _labels(keys)
    out = []
    for scene_variant in variants or [None]:
        for values in itertools.product(*(v for _, v in grid)):
            chosen = dict(zip(keys, values))
            shown = ({VARIANT_KEY: scene_variant} if scene_variant else {}) | chosen
            v = Variant(_folder(shown, labels), shown, (*common, *(f"{k}={x}" for k, x in chosen.items())),
                        scene_variant)
            try:
                load_scene(scene, Scene, v.overrides, v.variant)
            except SceneError as error:
                # name the --param, not --set, where one of its values is at fault
                ours = lambda p: p.file == OVERRIDE and any(f"{p.key}.".startswith(f"{k}.") for k in keys)  # noqa: E731
                problems = [replace(p, file=PARAM) if ours(p) else p for p in error.problems]
                raise InputError(f"sweep variant {v.name}:\n" + "\n".join(map(str, problems))) from None
            out.append(v)
    names = [v.name for v in out]
    if len(set(names)) < len(names):
        raise InputError(f"two variants would share the folder {next(n for n in names if names.count(n) > 1)}; "
                         f"make the --param values differ in more than punctuation")
    return out


def metrics(prep, state) -> dict:
    """Cheap, generic numbers about the final state (broken_bond_fraction only where bodies can fracture)."""
    from pdmpm_cli.engine.solver import kinetic_energy

    speed = np.linalg.norm(state.particle_v, axis=1)
    return {
        "steps": state.step, "particles": prep.plan.particles, "frames": prep.plan.frames,
        "max_displacement_m": float(np.linalg.norm(state.particle_x - prep.model.rest_x, axis=1).max()),
        "kinetic_energy_J": kinetic_energy(prep.model.particle_mass, state.particle_v),
        "max_speed_m_s": float(speed.max()),
        "broken_bond_fraction": float(1.0 - state.bond_active.mean()) if len(state.bond_active) else None,
    }


def run_variant(scene: str, overrides: tuple[str, ...], variant: str | None, out: str, overwrite: bool) -> dict:
    """Run one variant (on a Dask worker). Bad input and failed simulations are the row's status, not exceptions."""
    from pdmpm_cli.runner import prepare, simulate

    t0 = time.perf_counter()
    try:
        prep = prepare(scene, overrides, variant)
        row = {"status": "ok", "message": ""} | metrics(prep, simulate(prep, Path(out), overwrite=overwrite))
    except PdmpmError as error:
        row = {"status": "bad input" if error.exit_code == 2 else "failed", "message": str(error)}
    return row | {"wall_s": time.perf_counter() - t0}


@contextmanager
def connect(scheduler: str | None, workers: int | None) -> Iterator:
    """A Dask client: of the scheduler at `scheduler`, else of a LocalCluster of `workers` single-threaded worker
    processes (default: one per core) that share the cores among their Numba threads."""
    from distributed import Client, LocalCluster

    if scheduler:
        if workers:
            raise InputError("--workers sizes the local cluster; a --scheduler's cluster has its own workers")
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as error:
            raise InputError(f"--scheduler {scheduler}: cannot connect ({error}); start one with `dask scheduler` "
                             f"(and workers with `dask worker {scheduler}`), or leave out --scheduler to use this "
                             f"machine") from None
        with client:
            yield client
        return
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    workers = workers or cores
    threads = os.environ.get("NUMBA_NUM_THREADS") or str(max(1, cores // workers))
    # memory_limit=0: a simulation's memory is its own business; Dask would restart a worker over its share
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, memory_limit=0,
                      dashboard_address=None, silence_logs=logging.ERROR,
                      env={"NUMBA_NUM_THREADS": threads}) as cluster, Client(cluster) as client:
        yield client


def run_sweep(client, scene: Path, out: Path, variants: list[Variant], overwrite: bool,
              done: Callable[[Variant, dict], None] | None = None) -> dict[str, dict]:
    """Submit every variant, collect the rows as they finish (calling `done` on each); a variant whose task
    raised (a crash, a lost worker) gets status 'crashed'. Returns the rows by variant name, in sweep order."""
    from distributed import as_completed

    futures = {client.submit(run_variant, str(scene.resolve()), v.overrides, v.variant,
                             str((out / v.name).resolve()), overwrite, key=f"pdmpm-{v.name}-{time.time_ns()}",
                             pure=False): v for v in variants}
    rows = {}
    for future in as_completed(futures):
        v = futures[future]
        try:
            row = future.result()
        except Exception as error:  # the worker's traceback is in its log; the row keeps the message
            row = {"status": "crashed", "message": f"{type(error).__name__}: {error}", "wall_s": math.nan}
        rows[v.name] = row
        if done:
            done(v, row)
    return {v.name: rows[v.name] for v in variants}


COLUMNS = ("status", "wall_s", *METRICS, "message")


def summary_rows(variants: list[Variant], rows: dict[str, dict], digits: int = 6
                 ) -> tuple[list[str], list[list[str]]]:
    """Header and text cells of the summary: folder name, each parameter, status, wall time, metrics, message;
    numbers to `digits` significant digits."""
    keys = list(dict.fromkeys(k for v in variants for k in v.params))
    header = ["folder", *keys, *COLUMNS]
    cell = lambda x: "" if x is None else f"{x:.{digits}g}" if isinstance(x, float) else str(x)  # noqa: E731
    cells = [[v.name, *(v.params.get(k, "") for k in keys), *(cell(rows[v.name].get(c)) for c in COLUMNS)]
             for v in variants]
    return header, cells


def write_summary(out: Path, variants: list[Variant], rows: dict[str, dict]) -> tuple[Path, Path]:
    """`out/summary.csv` and `out/summary.md`, written atomically."""
    import csv
    import io

    header, cells = summary_rows(variants, rows)
    text = io.StringIO()
    csv.writer(text, lineterminator="\n").writerows([header, *cells])
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "summary.csv", text.getvalue())
    md = [header, ["---"] * len(header), *([c.replace("|", "\\|").replace("\n", " ") for c in row] for row in cells)]
    atomic_write_text(out / "summary.md", "".join(f"| {' | '.join(row)} |\n" for row in md))
    return out / "summary.csv", out / "summary.md"
