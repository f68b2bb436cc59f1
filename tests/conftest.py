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
    """Under pytest-xdist (the default run: `-n 2`) the workers share the cores: each runs Numba's parallel loops on
    its share of the threads, so two workers on two cores do not oversubscribe them."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    numba.set_num_threads(max(1, numba.config.NUMBA_NUM_THREADS // workers))


@pytest.fixture
def sim_factory(tmp_path):
    return lambda changes=None, base=BASE: Sim(merge(base, changes or {}), tmp_path / "scene.yaml")
