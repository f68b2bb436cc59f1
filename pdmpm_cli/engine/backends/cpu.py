"""The CPU backend: kernels run on the host State's arrays with Numba's parallel loops."""

from contextlib import contextmanager

import numpy as np

from pdmpm_cli.engine.contact import contact_update, overlap_box, surfaces
from pdmpm_cli.engine.fracture import crack_contact, crack_particle_update, inactive_fraction
from pdmpm_cli.engine.parallel import particle_chunks
from pdmpm_cli.engine.transfer import advect, g2p, grid_update, p2g, position_bounds


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

    def node_boxes(self, solver, state) -> tuple[np.ndarray, np.ndarray | None]:
        """Node index box [i0, i1) x [j0, j1) x [k0, k1) touched by the particles' B-spline stencils, and with a
        field per body (plan.contact) `contact.overlap_box` of the bodies' own boxes, the only nodes where two fields
        can have mass. The node box is then the union of the bodies' boxes, so every position is read once."""
        if not solver.plan.contact:
            return solver.box_of(*position_bounds(state.particle_x)), None
        boxes = [solver.box_of(*position_bounds(state.particle_x[b.start:b.end])) if b.end > b.start else None
                 for b in solver.model.bodies]
        live = np.array([b for b in boxes if b is not None])
        if not len(live):
            return solver.box_of(*position_bounds(state.particle_x)), overlap_box(boxes)
        union = np.empty(6, dtype=np.int64)
        union[0::2], union[1::2] = live[:, 0::2].min(axis=0), live[:, 1::2].max(axis=0)
        return union, overlap_box(boxes)

    @staticmethod
    def fields(solver, state):
        """(grid, start, end) per grid field: the one grid and every particle, or each body's field and its
        particles (plan.contact)."""
        if not solver.plan.contact:
            return ((state.grid, 0, solver.model.n_particles),)
        return tuple((state.grid_field[f], b.start, b.end) for f, b in enumerate(solver.model.bodies))

    def p2g(self, solver, state, dt) -> int:
        m = solver.model
        solver.box, solver.contact_box = self.node_boxes(solver, state)
        outside = 0
        for f, (grid, s, e) in enumerate(self.fields(solver, state)):
            outside += p2g(state.particle_x[s:e], state.particle_v[s:e], state.particle_C[s:e], m.particle_mass[s:e],
                           state.particle_force[s:e], state.particle_crack[s:e], m.pin_mask[s:e], dt, m.origin,
                           1.0 / m.dx, solver.box, state.grid_private, grid)
            if solver.plan.contact:
                surfaces(state.particle_x[s:e], m.particle_mass[s:e], state.particle_crack[s:e], m.origin, 1.0 / m.dx,
                         solver.contact_box, state.grid_surface_private, state.grid_surface[f])
        return outside

    def grid_update(self, solver, state, dt):
        m = solver.model
        for grid, _, _ in self.fields(solver, state):
            grid_update(grid, dt, m.gravity, m.wind_velocity, m.wind_drag, m.origin, m.dx, solver.box,
                        state.time + dt, m.colliders, m.wall_boundary, m.wall_friction)

    def contact(self, solver, state, dt):
        m = solver.model
        contact_update(state.grid_field, state.grid_surface, m.contact_friction, m.contact_stiffness, m.dx, dt,
                       solver.contact_box)

    def g2p(self, solver, state, dt) -> tuple[float, int]:
        m = solver.model
        vmax, bad = 0.0, 0
        for grid, s, e in self.fields(solver, state):
            v, b = g2p(grid, dt, m.origin, 1.0 / m.dx, state.time + dt, m.colliders, m.pin_mask[s:e],
                       m.pin_velocity[s:e], m.pin_stop[s:e], m.flip, state.particle_crack[s:e],
                       state.particle_x[s:e],
                       state.particle_v[s:e], state.particle_C[s:e], particle_chunks())
            vmax, bad = max(vmax, v), bad + b
        return vmax, bad

    def remap(self, solver, state, dt) -> tuple[float, int]:
        """MUSL after a FLIP G2P: the new particle velocities back to the grid (no force; walls, colliders and
        contact again), at the positions G2P read, then every particle moves with them (transfer.advect_at)."""
        m = solver.model
        t_new = state.time + dt
        fields = self.fields(solver, state)
        for grid, s, e in fields:
            p2g(state.particle_x[s:e], state.particle_v[s:e], state.particle_C[s:e], m.particle_mass[s:e],
                state.particle_force[s:e], state.particle_crack[s:e], m.pin_mask[s:e], 0.0, m.origin, 1.0 / m.dx,
                solver.box, state.grid_private, grid)
            grid_update(grid, 0.0, m.gravity, m.wind_velocity, m.wind_drag, m.origin, m.dx, solver.box, t_new,
                        m.colliders, m.wall_boundary, m.wall_friction)
        if solver.plan.contact:
            self.contact(solver, state, 0.0)
        vmax, bad = 0.0, 0
        for grid, s, e in fields:
            v, b = advect(grid, dt, m.origin, 1.0 / m.dx, t_new, m.colliders, m.pin_mask[s:e],
                          state.particle_crack[s:e], state.particle_x[s:e], state.particle_v[s:e], particle_chunks())
            vmax, bad = max(vmax, v), bad + b
        return vmax, bad

    def crack(self, solver, state, dt) -> tuple[float, int]:
        """Crack particles take their kick and meet their own body's material, then (contact: a field per body)
        the other bodies' material with no second kick (dt = 0), as they met all material on one shared grid
        (crack_index is sorted, bodies are particle ranges)."""
        m, idx = solver.model, solver.crack_index
        fields = self.fields(solver, state)
        for own in (True, False):  # with one field the second pass has no particles
            for grid, s, e in fields:
                lo, hi = np.searchsorted(idx, (s, e))
                which = idx[lo:hi] if own else np.concatenate((idx[:lo], idx[hi:]))
                crack_contact(grid, dt if own else 0.0, m.gravity, m.origin, 1.0 / m.dx, which,
                              state.particle_damage, m.particle_mass, m.particle_volume, state.particle_force,
                              state.particle_x, state.particle_v)
        return crack_particle_update(dt, state.time + dt, m.colliders, solver.valid_lo, solver.valid_hi, idx,
                                     state.particle_x, state.particle_v, state.particle_C)

    def inactive_fraction(self, solver, state):
        m = solver.model
        inactive_fraction(state.particle_x, m.origin, 1.0 / m.dx, solver.cells, state.bond_start, state.bond_active,
                          state.cell_bonds, state.cell_broken, state.particle_inactive)

    def crack_particles_changed(self, solver, state):
        """particle_crack changed on the host: nothing to upload here."""
