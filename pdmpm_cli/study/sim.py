"""A scene given as a dict, prepared and stepped in memory: no scene file, no output folder."""

import dataclasses
import math
from pathlib import Path

import numpy as np

from pdmpm_cli.runner import prepare_scene, start_in_memory
from pdmpm_cli.scene.schema import Scene


class Sim:
    """A prepared scene with its solver and state, for stepping from code (studies and tests)."""

    def __init__(self, scene_dict: dict, path=Path("scene.yaml")):
        self.scene = Scene.model_validate(scene_dict)
        self.prep = prepare_scene(self.scene, Path(path))
        self.plan = self.prep.plan
        self.state, self.solver = start_in_memory(self.prep)

    def force_step(self, k: float):
        """Step at k dx / c (c the fastest P-wave speed) in place of the Plan's bounds, frames still capping it: for
        studies of the step itself (`pdmpm run` always takes the Plan's). Replaces this Sim's Plan by a copy."""
        self.plan = self.solver.plan = dataclasses.replace(
            self.plan, dt_max=k * self.model.dx / self.plan.wave_speed, dt_cfl=math.inf, dt_bond=math.inf)

    @property
    def model(self):
        """The solver's Model: an emitter grows it as particles are born."""
        return self.solver.model

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
