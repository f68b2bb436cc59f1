"""The CPU backend: kernels run on the host State's arrays with Numba's parallel loops."""

from contextlib import contextmanager

import numpy as np

from pdmpm_cli.engine.contact import contact_update, meeting_box, overlap_box, surfaces
from pdmpm_cli.engine.crack import crack_owners
from pdmpm_cli.engine.fracture import crack_contact, crack_particle_update, inactive_fraction
from pdmpm_cli.engine.parallel import particle_chunks
from pdmpm_cli.engine.transfer import advect, g2p, grid_update, has_clamped, mirror_clamped, p2g, position_bounds


# the crack-field arguments of the transfers for a body with one field (engine/crack.py)
UNSPLIT = (np.zeros((0, 0, 0), dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0, dtype=np.int64), 0.0,
           np.zeros(6, dtype=np.int64))
EMPTY = np.zeros(6, dtype=np.int64)  # the node box of a body without particles


class CpuBackend:
    """Arrays are the host State's and the Model's own; a kernel runs as its CPU loop (Kernel.cpu)."""

    name = "cpu"

    def __init__(self):
        self.crack_boxes = []  # per crack body: the node box its cracks split this step (engine/crack.py)
        self.body_boxes = None  # with a field per body: each body's node box this step (EMPTY: no particles)
        self.written = {}  # per body field: the node box its last P2G wrote (none yet: the whole grid may hold mass)

    def start(self, solver, state):
        solver.a, solver.m = state, solver.model
        self.written = {}

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

    def node_boxes(self, solver, state) -> tuple[np.ndarray, list | None]:
        """Node index box [i0, i1) x [j0, j1) x [k0, k1) touched by the particles' B-spline stencils and, with a
        field per body (plan.contact), each body's own box (None for a body without particles). The node box is then
        the union of the bodies' boxes, so every position is read once."""
        if not solver.plan.contact:
            return solver.box_of(*position_bounds(state.particle_x)), None
        boxes = [solver.box_of(*position_bounds(state.particle_x[b.start:b.end])) if b.end > b.start else None
                 for b in solver.model.bodies]
        live = np.array([b for b in boxes if b is not None])
        if not len(live):
            return solver.box_of(*position_bounds(state.particle_x)), boxes
        union = np.empty(6, dtype=np.int64)
        union[0::2], union[1::2] = live[:, 0::2].min(axis=0), live[:, 1::2].max(axis=0)
        return union, boxes

    @staticmethod
    def cracked(solver, state, body: int, s: int, e: int) -> np.ndarray:
        """The rows of the particles the transfers skip for a body: a crack body's dust and chips (its other crack
        particles stay on the grid, on their side's field: engine/crack.py), any other body's crack particles."""
        return state.particle_dust[s:e] if body in solver.model.crack_bodies else state.particle_crack[s:e]

    def sides(self, solver, state, body: int) -> tuple:
        """(owner, rest_x, crack_n, piece, half_h, box of the split nodes) of a body's crack fields as the transfers
        take them (engine/crack.py), or stand-ins for a body with one field."""
        m = solver.model
        if body not in m.crack_bodies:
            return UNSPLIT
        b, c = m.bodies[body], m.crack_bodies.index(body)
        return (state.grid_owner[c], m.rest_x[b.start:b.end], state.particle_crack_n[b.start:b.end],
                state.particle_piece[b.start:b.end], 0.5 * b.spacing, self.crack_boxes[c])

    def fields(self, solver, state):
        """(grid, start, end, sides, side, cracked) per grid field: the one grid and every particle, or each body's
        field and its particles (plan.contact), then the far side of each crack body's field (engine/crack.py)."""
        m = solver.model
        if not solver.plan.contact:
            return ((state.grid, 0, m.n_particles, UNSPLIT, 0, state.particle_crack),)
        out = [(state.grid_field[f], b.start, b.end, self.sides(solver, state, f), 0,
                self.cracked(solver, state, f, b.start, b.end)) for f, b in enumerate(m.bodies)]
        for c, i in enumerate(m.crack_bodies):
            b = m.bodies[i]
            out.append((state.grid_field[len(m.bodies) + c], b.start, b.end, self.sides(solver, state, i), 1,
                        state.particle_dust[b.start:b.end]))
        return tuple(out)

    def readers(self, solver, state):
        """(grid, far side's grid, start, end, sides, cracked) per body: the fields its particles read back from."""
        m = solver.model
        if not solver.plan.contact:
            return ((state.grid, state.grid, 0, m.n_particles, UNSPLIT, state.particle_crack),)
        out = []
        for f, b in enumerate(m.bodies):
            far = (state.grid_field[len(m.bodies) + m.crack_bodies.index(f)] if f in m.crack_bodies
                   else state.grid_field[f])
            out.append((state.grid_field[f], far, b.start, b.end, self.sides(solver, state, f),
                        self.cracked(solver, state, f, b.start, b.end)))
        return tuple(out)

    def field_box(self, solver, f: int) -> np.ndarray:
        """The node box P2G and the grid update cover in field f: with a field per body its body's own box (the
        field has no mass anywhere else: `clear_outside`), else, and for a crack's far side, solver.box."""
        if self.body_boxes is None or f >= len(self.body_boxes):
            return solver.box
        return self.body_boxes[f]

    def clear_outside(self, grid, f: int, box: np.ndarray):
        """Zero body field f on the nodes its last P2G wrote outside `box` (all of it the first time), so that every
        node outside its box holds no mass, as P2G over the union of the bodies' boxes left it: what reads a field
        outside its body's box (contact, another body's crack particles) finds the same zeros."""
        old = self.written.get(f)
        self.written[f] = box
        if old is None:
            grid[...] = 0.0
            return
        if (old == box).all():
            return
        for a in range(3):
            for lo, hi in ((old[2 * a], min(old[2 * a + 1], box[2 * a])), (max(old[2 * a], box[2 * a + 1]),
                                                                          old[2 * a + 1])):
                if lo < hi:
                    span = [slice(old[0], old[1]), slice(old[2], old[3]), slice(old[4], old[5])]
                    span[a] = slice(lo, hi)
                    grid[tuple(span)] = 0.0

    def scatter(self, solver, state, dt, with_surfaces: bool):
        """P2G of every field on its box (`field_box`), then (with_surfaces) the fields' surfaces for contact on the
        nodes where two fields have mass (`contact.meeting_box` of solver.contact_box, which becomes the contact box);
        returns the particles off the grid."""
        m = solver.model
        outside = 0
        fields = self.fields(solver, state)
        for f, (grid, s, e, sides, want, cracked) in enumerate(fields):
            box = self.field_box(solver, f)
            if want:  # a crack's far side has mass only on the nodes its cracks split
                grid[box[0]:box[1], box[2]:box[3], box[4]:box[5]] = 0.0
                box = sides[-1]
            elif self.body_boxes is not None:
                self.clear_outside(grid, f, box)
            n = p2g(state.particle_x[s:e], state.particle_v[s:e], state.particle_C[s:e], m.particle_mass[s:e],
                    state.particle_force[s:e], cracked, m.pin_mask[s:e], dt, m.origin, 1.0 / m.dx, box,
                    state.grid_private, grid, *sides, want)
            outside += 0 if want else n  # a crack side's particles were counted with their body
        if with_surfaces:
            solver.contact_box = meeting_box(state.grid_field, solver.contact_box)
            for f, (_, s, e, sides, want, cracked) in enumerate(fields):
                surfaces(state.particle_x[s:e], m.particle_mass[s:e], cracked, m.origin, 1.0 / m.dx,
                         solver.contact_box, state.grid_surface_private, state.grid_surface[f], *sides, want)
        return outside

    def p2g(self, solver, state, dt) -> int:
        """The nodes' owners of each crack body (engine/crack.py), then P2G; with a field per body, the contact box
        is `contact.overlap_box` of the fields' boxes (a crack side's: the nodes its cracks split), the only nodes
        where two fields can have mass, narrowed after P2G to those where they do (`scatter`)."""
        m = solver.model
        solver.box, boxes = self.node_boxes(solver, state)
        self.body_boxes = None if boxes is None else [EMPTY if b is None else b for b in boxes]
        self.crack_boxes = [crack_owners(m.bodies[i].start, m.bodies[i].end, state.particle_x, state.particle_crack_s,
                                         state.particle_piece[m.bodies[i].start:m.bodies[i].end], m.origin,
                                         1.0 / m.dx, solver.box, state.grid_owner[c])
                            for c, i in enumerate(m.crack_bodies)]
        solver.contact_box = None if boxes is None else overlap_box(
            boxes + [b if b[1] > b[0] else None for b in self.crack_boxes])
        return self.scatter(solver, state, dt, solver.plan.contact)

    def grid_update(self, solver, state, kick, t_new):
        self.update_fields(solver, state, kick, t_new)

    def update_fields(self, solver, state, dt, t_new):
        """Every grid field's update (forces over dt, walls, colliders), then a clamped plane's mirror pass."""
        m = solver.model
        clamped = has_clamped(m.colliders)
        for f, (grid, *_) in enumerate(self.fields(solver, state)):
            box = self.field_box(solver, f)
            grid_update(grid, dt, m.gravity, m.wind_velocity, m.wind_drag, m.origin, m.dx, box, t_new, m.colliders,
                        m.wall_boundary, m.wall_friction)
            if clamped:
                mirror_clamped(grid, m.origin, m.dx, box, t_new, m.colliders)

    def contact(self, solver, state, dt):
        m = solver.model
        contact_update(state.grid_field, state.grid_surface, m.contact_friction, m.contact_stiffness, m.dx, dt,
                       solver.contact_box)

    def g2p(self, solver, state, dt) -> tuple[float, int]:
        m = solver.model
        vmax, bad = 0.0, 0
        for grid, far, s, e, sides, cracked in self.readers(solver, state):
            v, b = g2p(grid, dt, m.origin, 1.0 / m.dx, state.time + dt, m.colliders, m.pin_mask[s:e],
                       m.pin_velocity[s:e], m.pin_stop[s:e], m.flip, cracked,
                       state.particle_x[s:e], state.particle_v[s:e], state.particle_C[s:e], state.particle_rho[s:e],
                       particle_chunks(), far,
                       *sides)
            vmax, bad = max(vmax, v), bad + b
        return vmax, bad

    def remap(self, solver, state, dt) -> tuple[float, int]:
        """MUSL after a FLIP G2P: the new particle velocities back to the grid (no force; walls, colliders and
        contact again), at the positions G2P read, then every particle moves with them (transfer.advect_at)."""
        m = solver.model
        t_new = state.time + dt
        self.scatter(solver, state, 0.0, False)
        self.update_fields(solver, state, 0.0, t_new)
        if solver.plan.contact:
            self.contact(solver, state, 0.0)
        vmax, bad = 0.0, 0
        for grid, far, s, e, sides, cracked in self.readers(solver, state):
            v, b = advect(grid, dt, m.origin, 1.0 / m.dx, t_new, m.colliders, m.pin_mask[s:e], cracked,
                          state.particle_x[s:e], state.particle_v[s:e], particle_chunks(),
                          far, *sides)
            vmax, bad = max(vmax, v), bad + b
        return vmax, bad

    def crack(self, solver, state, kick, dt) -> tuple[float, int]:
        """Crack particles take their kick and meet their own body's material, then (contact: a field per body)
        the other bodies' material and the far side of their own body's cracks with no second kick (dt = 0), as
        they met all material on one shared grid (crack_index is sorted, bodies are particle ranges)."""
        m, idx = solver.model, solver.crack_index
        fields = self.fields(solver, state)
        for own in (True, False):  # with one field the second pass has no particles
            for grid, s, e, _, want, _ in fields:
                lo, hi = np.searchsorted(idx, (s, e))
                if own:
                    which = idx[lo:hi] if not want else idx[:0]
                else:
                    which = idx if want else np.concatenate((idx[:lo], idx[hi:]))
                crack_contact(grid, kick if own else 0.0, m.gravity, m.origin, 1.0 / m.dx, which,
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
