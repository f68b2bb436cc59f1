"""Shared helpers: build scenes in code and run them without touching the disk."""

import copy

import numpy as np
import pytest

from pdmpm_cli.engine.model import State
from pdmpm_cli.engine.solver import Solver
from pdmpm_cli.runner import prepare_scene
from pdmpm_cli.scene.schema import Scene

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


def merge(base: dict, changes: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in changes.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


class Sim:
    """A prepared scene with its solver and state, for stepping in tests."""

    def __init__(self, scene_dict: dict, tmp_path="."):
        self.scene = Scene.model_validate(scene_dict)
        self.prep = prepare_scene(self.scene, tmp_path / "scene.yaml" if hasattr(tmp_path, "joinpath") else "x")
        self.model, self.plan = self.prep.model, self.prep.plan
        self.state = State.allocate(self.model, self.prep.disc, self.plan.fields)
        self.solver = Solver(self.model, self.plan)
        self.solver.start(self.state)

    def advance(self, t_end, on_substep=None):
        """Advance to t_end frame by frame, as the runner does (the blow-up check runs at every frame)."""
        frames = np.arange(self.state.time, t_end, self.plan.frame_dt)[1:]
        for t in [*frames[frames < t_end - 1e-12], t_end]:
            self.solver.advance(self.state, t, on_substep)

    def momentum(self):
        return self.model.particle_mass @ self.state.particle_v

    def angular_momentum(self, about):
        return self.solver.angular_momentum(self.state, about)

    def com(self):
        m = self.model.particle_mass
        return m @ self.state.particle_x / m.sum()


@pytest.fixture
def sim_factory(tmp_path):
    return lambda changes=None, base=BASE: Sim(merge(base, changes or {}), tmp_path)
