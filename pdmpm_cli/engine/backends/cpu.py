"""The CPU backend: kernels run on the host State's arrays with Numba's parallel loops."""

from contextlib import contextmanager

import numpy as np

from pdmpm_cli.engine.fracture import crack_contact, crack_particle_update, inactive_fraction
from pdmpm_cli.engine.parallel import particle_chunks
from pdmpm_cli.engine.transfer import g2p, grid_update, p2g, position_bounds


class CpuBackend:
    """Arrays are the host State's and the Model's own; a kernel runs as its CPU loop (Kernel.cpu)."""

    name = "cpu"

    def start(self, solver, state):
        solver.a, solver.m = state, solver.model

    def sync(self, state):
        """Make the host State current (it always is here)."""

    def synchronize(self):
        """Wait for queued work (none is queued here)."""

    @contextmanager
    def on_host(self, state, names, changed=None):
        """Work on the host State's arrays `names` (which may be replaced) within the block: nothing to move here."""
        yield

    def run(self, kernel, start, end, *args):
        return kernel.cpu(start, end, *args)

    def node_box(self, solver, state) -> np.ndarray:
        """Node index box [i0, i1) x [j0, j1) x [k0, k1) touched by the particles' B-spline stencils."""
        lo, hi = position_bounds(state.particle_x)
        return solver.box_of(lo, hi)

    def p2g(self, solver, state, dt) -> int:
        m = solver.model
        solver.box = self.node_box(solver, state)
        return p2g(state.particle_x, state.particle_v, state.particle_C, m.particle_mass, state.particle_force,
                   state.particle_crack, m.pin_mask, dt, m.origin, 1.0 / m.dx, solver.box, state.grid_private,
                   state.grid)

    def grid_update(self, solver, state, dt):
        m = solver.model
        grid_update(state.grid, dt, m.gravity, m.wind_velocity, m.wind_drag, m.origin, m.dx, solver.box,
                    state.time + dt, m.colliders, m.wall_boundary, m.wall_friction)

    def g2p(self, solver, state, dt) -> tuple[float, int]:
        m = solver.model
        return g2p(state.grid, dt, m.origin, 1.0 / m.dx, state.time + dt, m.colliders, m.pin_mask, m.pin_velocity,
                   m.pin_stop, state.particle_crack, state.particle_x, state.particle_v, state.particle_C,
                   particle_chunks())

    def crack(self, solver, state, dt) -> tuple[float, int]:
        m, idx = solver.model, solver.crack_index
        crack_contact(state.grid, dt, m.gravity, m.origin, 1.0 / m.dx, idx, state.particle_damage, m.particle_mass,
                      m.particle_volume, state.particle_force, state.particle_x, state.particle_v)
        return crack_particle_update(dt, state.time + dt, m.colliders, solver.valid_lo, solver.valid_hi, idx,
                                     state.particle_x, state.particle_v, state.particle_C)

    def inactive_fraction(self, solver, state):
        m = solver.model
        inactive_fraction(state.particle_x, m.origin, 1.0 / m.dx, solver.cells, state.bond_start, state.bond_active,
                          state.particle_inactive)

    def crack_particles_changed(self, solver, state):
        """particle_crack changed on the host: nothing to upload here."""
