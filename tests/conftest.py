"""Shared helpers: build scenes in code and run them without touching the disk."""

import os

# Under pytest-xdist (`-n auto --dist loadfile`) the workers share the cores: each gets its share of Numba's
# threads, set before Numba is imported so that its thread pool, its private grids and the pdmpm processes a test
# starts (which inherit the variable) all agree: a run compared bitwise with an in-process reference takes the
# reference's thread count, hence its sums.
WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
if WORKERS > 1 and "NUMBA_NUM_THREADS" not in os.environ:
    os.environ["NUMBA_NUM_THREADS"] = str(max(1, (os.cpu_count() or 1) // WORKERS))

import pytest  # noqa: E402

from pdmpm_cli.scene.loader import merge  # noqa: E402
from pdmpm_cli.study.sim import Sim  # noqa: E402

BASE = {
    "simulation": {"duration": 1.0, "fps": 10},
    "grid": {"cell_size": 0.05, "domain": {"min": [0, 0, 0], "max": [1, 1, 1]}},
    "gravity": [0, 0, 0],
    "bodies": [{
        "name": "cube",
        "geometry": {"mode": "cloud", "shape": {"type": "box", "center": [0.5, 0.5, 0.5], "size": [0.3, 0.3, 0.3]},
                     "sampling": "lattice"},
        "material": {"model": "elastic", "density": 1000.0, "lam": 1e5, "mu": 1e5},
    }],
}


@pytest.fixture
def sim_factory(tmp_path):
    return lambda changes=None, base=BASE: Sim(merge(base, changes or {}), tmp_path / "scene.yaml")
