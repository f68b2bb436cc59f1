"""Numba's disk cache must serve a second process: a CLI that recompiled every run would cost a minute each."""

import subprocess
import sys

PROBE = """
import numpy as np
from pdmpm_cli.engine import bonds, transfer
from pdmpm_cli.engine.materials import elastic
from tests.conftest import BASE, Sim
sim = Sim(BASE)
sim.solver.substep(sim.state, sim.plan.dt_max)
kernels = [transfer.p2g, transfer.grid_update, transfer.g2p, bonds.averaged_deformation,
           bonds.reference_family_terms, elastic.elastic_forces]
print(sum(len(k.stats.cache_misses) for k in kernels), sum(len(k.stats.cache_hits) for k in kernels))
"""


def test_second_process_hits_the_cache():
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    runs = [subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, cwd=root, timeout=600)
            for _ in range(2)]
    for r in runs:
        assert r.returncode == 0, r.stderr
    misses, hits = map(int, runs[1].stdout.split())
    assert misses == 0 and hits >= 6
