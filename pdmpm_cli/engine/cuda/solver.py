"""The step on one NVIDIA GPU: the Plan's phases as CUDA kernels on device-resident arrays."""

import time

import numba
import numpy as np
from numba import cuda

from pdmpm_cli.engine.cuda import kernels as k
from pdmpm_cli.engine.materials.elastic import DUMMY_FBAR
from pdmpm_cli.engine.model import Model, State
from pdmpm_cli.engine.solver import Solver
from pdmpm_cli.plan import Plan

THREADS = 128  # threads per block


def device_name() -> str:
    """The GPU the kernels run on, for benchmark tables."""
    if numba.config.ENABLE_CUDASIM:
        return "numba.cuda simulator"
    name = cuda.get_current_device().name
    return name.decode() if isinstance(name, bytes) else name


def launch(kernel, n: int, *args):
    """Run `kernel` on n threads (none when n = 0)."""
    if n > 0:
        kernel[(n + THREADS - 1) // THREADS, THREADS](*args)


# State arrays the step changes: uploaded by start, copied back by to_host
DYNAMIC = ("particle_x", "particle_v", "particle_C", "particle_force", "particle_Fbar", "bond_ep", "particle_theta")


class CudaSolver(Solver):
    """A Solver whose substeps run on the GPU. The State's arrays live on the device between frames; the host
    State is refreshed (`to_host`) when the runner needs it: at the end of `advance` (a frame), for the energy
    diagnostics and before an error message. `start` uploads the host State, so call it again after editing it.

    The host reads back one small statistics array per step: the max speed (for dt), the non-finite count and the
    position bounds, from which it both sizes the next P2G's node box and detects particles leaving the domain
    before any kernel could index off the grid. With `profile`, every phase is synchronised and timed."""

    def __init__(self, model: Model, plan: Plan, profile: bool = False):
        super().__init__(model, plan)
        self.profile = profile
        self.device_name = device_name()
        self.dirty = False  # the device holds steps the host State has not seen
        m = model
        self.origin = tuple(float(v) for v in m.origin)
        self.gravity = tuple(float(v) for v in m.gravity)
        self.wind = tuple(float(v) for v in m.wind_velocity)
        self.dev = {name: cuda.to_device(getattr(m, name)) for name in (
            "rest_x", "particle_volume", "particle_mass", "particle_coef", "pin_mask", "pin_velocity", "pin_stop", "colliders")}
        self.dev["particle_Kinv"] = cuda.to_device(m.particle_Kinv if self.fbar_bodies else DUMMY_FBAR)
        self.dev["grid"] = cuda.device_array(m.grid_shape + (4,))
        self.stats = np.zeros(k.N_STATS)

    # ---- host <-> device
    def start(self, state: State):
        """The CPU start (energy budget, on the host), then upload the State's arrays: the host State is the
        truth here, whatever the device still holds."""
        self.dirty = False
        super().start(state)
        for name in DYNAMIC + ("bond_start", "bond_nbr"):
            self.dev[name] = cuda.to_device(getattr(state, name))
        if not len(state.particle_Fbar):
            self.dev["particle_Fbar"] = cuda.to_device(DUMMY_FBAR)
        self.stats[k.STAT_LO:k.STAT_LO + 3] = state.particle_x.min(axis=0)
        self.stats[k.STAT_HI:k.STAT_HI + 3] = state.particle_x.max(axis=0)
        self.stats[k.STAT_VMAX] = self.vmax
        self.stats[k.STAT_YIELD] = self.yield_residual
        self.dev["stats"] = cuda.to_device(self.stats)

    def to_host(self, state: State):
        """Copy the device's dynamic arrays into the host State (once per frame, or before an error)."""
        if self.dirty:
            for name in DYNAMIC:
                if len(getattr(state, name)):
                    self.dev[name].copy_to_host(getattr(state, name))
            self.dirty = False

    # ---- diagnostics run on the host copy
    def kinetic_energy(self, state: State) -> float:
        self.to_host(state)
        return super().kinetic_energy(state)

    def strain_energy(self, state: State) -> float:
        self.to_host(state)
        return super().strain_energy(state)

    def angular_momentum(self, state: State, about) -> np.ndarray:
        self.to_host(state)
        return super().angular_momentum(state, about)

    def check_energy(self, state: State):
        self.to_host(state)
        super().check_energy(state)

    # ---- phases on the device
    def substep(self, state: State, dt: float):
        """One explicit step: the Plan's phases in order, as CUDA kernels."""
        self.dirty = True
        for phase in self.plan.phases:
            t0 = time.perf_counter()
            stage, _, kind = phase.partition(":")
            if kind:
                for body in self.bodies_of[kind]:
                    getattr(self, f"gpu_{stage}")(body, dt)
            else:
                getattr(self, f"gpu_{phase}")(state, dt)
            if self.profile:
                cuda.synchronize()
                self.phase_time[phase] += time.perf_counter() - t0
        state.step += 1
        state.time += dt
        state.dt_prev = dt

    def gpu_fbar(self, state: State, dt: float):
        d, m = self.dev, self.model
        for body in self.fbar_bodies:
            start, end = m.body_ranges[body]
            launch(k.averaged_deformation, end - start, start, end, m.body_horizon[body], d["particle_x"], d["rest_x"],
                   d["particle_volume"], d["bond_start"], d["bond_nbr"], d["particle_Kinv"], d["particle_Fbar"])

    def gpu_return_map(self, body: int, dt: float):
        d, m = self.dev, self.model
        start, end = m.body_ranges[body]
        mat = m.materials[body]
        launch(k.bond_dilatation, end - start, start, end, m.body_horizon[body], d["particle_x"], d["rest_x"],
               d["particle_volume"], d["bond_start"], d["bond_nbr"], d["particle_theta"])
        launch(k.plastic_return_map, end - start, start, end, mat.lam, mat.mu, mat.yield_psi, d["particle_x"],
               d["rest_x"], d["bond_start"], d["bond_nbr"], d["particle_Fbar"], d["particle_theta"], d["bond_ep"],
               d["stats"])

    def gpu_bonds(self, body: int, dt: float):
        d, m = self.dev, self.model
        start, end = m.body_ranges[body]
        mat = m.materials[body]
        launch(k.elastic_forces, end - start, start, end, mat.lam, mat.mu, m.body_horizon[body], d["particle_x"],
               d["rest_x"], d["particle_volume"], d["bond_start"], d["bond_nbr"], d["bond_ep"], d["particle_coef"],
               d["particle_Fbar"], d["particle_force"])

    def gpu_p2g(self, state: State, dt: float):
        """Node box and domain test from the bounds of the last G2P (transfer.stencil_on_grid on the extreme
        particles is the test on all of them), then P2G."""
        d, m = self.dev, self.model
        nodes = np.asarray(m.grid_shape)
        xlo, xhi = self.stats[k.STAT_LO:k.STAT_LO + 3], self.stats[k.STAT_HI:k.STAT_HI + 3]
        if ((xlo - m.origin) * (1.0 / m.dx) < 1.0).any() or ((xhi - m.origin) * (1.0 / m.dx) >= nodes - 3).any():
            self.to_host(state)
            self.fail_outside(state)
        lo = np.clip(np.floor((xlo - m.origin) / m.dx).astype(np.int64) - 2, 0, nodes)
        hi = np.clip(np.floor((xhi - m.origin) / m.dx).astype(np.int64) + 4, 0, nodes)
        self.box = (int(lo[0]), int(hi[0]), int(lo[1]), int(hi[1]), int(lo[2]), int(hi[2]))
        launch(k.zero_box, int(np.prod(hi - lo)), self.box, d["grid"])
        launch(k.p2g, m.n_particles, d["particle_x"], d["particle_v"], d["particle_C"], d["particle_mass"],
               d["particle_force"], d["pin_mask"], dt, self.origin, 1.0 / m.dx, d["grid"])

    def gpu_grid_update(self, state: State, dt: float):
        d, m = self.dev, self.model
        b = self.box
        launch(k.grid_update, (b[1] - b[0]) * (b[3] - b[2]) * (b[5] - b[4]), d["grid"], dt, self.gravity, self.wind,
               m.wind_drag, self.origin, m.dx, b, state.time + dt, d["colliders"], m.wall_boundary, m.wall_friction)

    def gpu_g2p(self, state: State, dt: float):
        """G2P, then the one read-back of the step: speed, non-finite count, bounds and the yield residual."""
        d, m = self.dev, self.model
        launch(k.reset_stats, 1, d["stats"])
        launch(k.g2p, m.n_particles, d["grid"], dt, self.origin, 1.0 / m.dx, state.time + dt, d["colliders"],
               d["pin_mask"], d["pin_velocity"], d["pin_stop"], d["particle_x"], d["particle_v"], d["particle_C"],
               d["stats"])
        d["stats"].copy_to_host(self.stats)
        self.vmax = float(self.stats[k.STAT_VMAX])
        self.yield_residual = float(self.stats[k.STAT_YIELD])
        if self.stats[k.STAT_BAD]:
            self.to_host(state)
            self.fail_nonfinite(state)
