"""Shared helpers: build scenes in code and run them without touching the disk."""

import os

import numba
import pytest

from pdmpm_cli.scene.loader import merge
from pdmpm_cli.study.sim import Sim

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


def pytest_configure(config):
    """Under pytest-xdist (the default run: `-n auto`) the workers share the cores: each runs Numba's parallel loops,
    and the pdmpm processes it starts, on its share of the threads, so the workers do not oversubscribe the cores
    (and a run a test starts takes the thread count, hence the sums, of the reference it is compared with)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    threads = max(1, numba.config.NUMBA_NUM_THREADS // workers)
    numba.set_num_threads(threads)
    os.environ["NUMBA_NUM_THREADS"] = str(threads)


@pytest.fixture
def sim_factory(tmp_path):
    return lambda changes=None, base=BASE: Sim(merge(base, changes or {}), tmp_path / "scene.yaml")
