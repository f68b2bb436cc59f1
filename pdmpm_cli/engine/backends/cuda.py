"""The CUDA backend: the step on one NVIDIA GPU through numba.cuda, on device-resident arrays.

Nothing here is a second implementation of the physics. `device` compiles the Python source of the engine's @njit
per-item formulae (`*_at` functions, Kernel.fn) for the GPU, with their jitted callees compiled the same way, and
`particle_kernel` wraps one in a kernel with one thread per particle. The CPU loops call the very same functions.
Three substitutions make the source valid CUDA: `scatter_node` adds atomically (P2G into one grid), the builtin
max and min become branches (numba's CUDA target cannot compile them), and `np` is `math` (CUDA has no np.floor).

The host State is refreshed (`sync`) when the runner needs it: once per frame, for diagnostics, before an error
message and for the serial parts that run on the host (fracture clustering, family rebuilds: `on_host`). Per step
the host reads one small statistics array after G2P: the max speed (for dt), the non-finite count and the position
bounds, from which it sizes the next P2G's node box and detects particles leaving the domain before any kernel
could index off the grid.
"""

import functools
import inspect
import math
import types
from contextlib import contextmanager

import numpy as np

if not hasattr(np, "row_stack"):
    np.row_stack = np.vstack  # numba-cuda 0.30 still calls np.row_stack, which numpy 2.5 removed

import numba  # noqa: E402
from numba import cuda, float64  # noqa: E402
from numba.core.registry import CPUDispatcher  # noqa: E402

from pdmpm_cli.engine import contact, fracture, transfer  # noqa: E402
from pdmpm_cli.engine.fields import GRID  # noqa: E402
from pdmpm_cli.engine.kernel import Kernel  # noqa: E402

THREADS = 128  # threads per block
# Slots of the per-step statistics array the host reads once per step.
STAT_LO, STAT_HI = 0, 3  # per-axis min and max of the particle positions after G2P [m] (the next P2G's node box)
STAT_VMAX, STAT_BAD = 6, 7  # max particle speed [m/s], number of non-finite particles
N_STATS = 8


def device_name() -> str:
    """The GPU the kernels run on, for benchmark tables."""
    if numba.config.ENABLE_CUDASIM:
        return "numba.cuda simulator"
    name = cuda.get_current_device().name
    return name.decode() if isinstance(name, bytes) else name


@cuda.jit(device=True)
def larger(a, b):
    """max(a, b) as Python defines it (b only if b > a)."""
    return b if b > a else a


@cuda.jit(device=True)
def smaller(a, b):
    """min(a, b) as Python defines it (b only if b < a)."""
    return b if b < a else a


@cuda.jit(device=True)
def scatter_node_atomic(g, i, j, k, m, p0, p1, p2):
    """transfer.scatter_node with atomic adds: every particle's P2G adds into the one grid."""
    cuda.atomic.add(g, (i, j, k, 0), m)
    cuda.atomic.add(g, (i, j, k, 1), p0)
    cuda.atomic.add(g, (i, j, k, 2), p1)
    cuda.atomic.add(g, (i, j, k, 3), p2)


@cuda.jit(device=True)
def scatter_impulse_atomic(g, i, j, k, f0, f1, f2):
    """transfer.scatter_impulse with atomic adds."""
    cuda.atomic.add(g, (i, j, k, 4), f0)
    cuda.atomic.add(g, (i, j, k, 5), f1)
    cuda.atomic.add(g, (i, j, k, 6), f2)


@cuda.jit(device=True)
def scatter_surface_atomic(g, i, j, k, g0, g1, g2, s0, s1, s2):
    """contact.scatter_surface with atomic adds."""
    cuda.atomic.add(g, (i, j, k, 0), g0)
    cuda.atomic.add(g, (i, j, k, 1), g1)
    cuda.atomic.add(g, (i, j, k, 2), g2)
    cuda.atomic.add(g, (i, j, k, 3), s0)
    cuda.atomic.add(g, (i, j, k, 4), s1)
    cuda.atomic.add(g, (i, j, k, 5), s2)


SUBSTITUTES = {"max": larger, "min": smaller, "np": math}
REPLACED = {transfer.scatter_node: scatter_node_atomic, transfer.scatter_impulse: scatter_impulse_atomic,
            contact.scatter_surface: scatter_surface_atomic}


@functools.cache
def device(fn):
    """A CUDA device function compiled from the Python source of the @njit function `fn`: the jitted functions it
    calls by name become their device versions (recursively; so call them by name, not as module attributes), and
    SUBSTITUTES replace what CUDA lacks."""
    if fn in REPLACED:
        return REPLACED[fn]
    py = fn.py_func
    scope = dict(py.__globals__)
    for name in py.__code__.co_names:
        value = scope.get(name)
        if isinstance(value, CPUDispatcher):
            scope[name] = device(value)
    scope.update({k: v for k, v in SUBSTITUTES.items() if k in py.__code__.co_names})
    return cuda.jit(device=True)(types.FunctionType(py.__code__, scope, py.__name__, py.__defaults__,
                                                    py.__closure__))


def _generated(name: str, params: list[str], body: str, scope: dict):
    """A CUDA kernel from source text: def name(params): body."""
    src = f"def {name}({', '.join(params)}):\n" + "\n".join("    " + line for line in body.splitlines())
    exec(compile(src, f"<pdmpm cuda kernel {name}>", "exec"), scope)
    return cuda.jit(scope[name])


@functools.cache
def particle_kernel(kernel: Kernel):
    """A kernel running kernel.fn(i, *args, *scratch) for i in start..end-1, one thread each; its reduction, if any,
    goes to out[0] with an atomic max or add."""
    names = list(inspect.signature(kernel.fn.py_func).parameters)
    item, args = names[0], names[1:len(names) - len(kernel.scratch)]
    scratch = [f"{s} = cuda.local.array({n}, float64)" for s, n in kernel.scratch]
    call = f"fn({item}, {', '.join(args + [s for s, _ in kernel.scratch])})"
    reduce = {None: call, "max": f"cuda.atomic.max(out, 0, float64({call}))",
              "sum": f"cuda.atomic.add(out, 0, float64({call}))"}[kernel.reduce]
    body = "\n".join([f"{item} = start + cuda.grid(1)", f"if {item} < end:"] + ["    " + s for s in scratch]
                     + ["    " + reduce])
    return _generated(kernel.fn.py_func.__name__, ["start", "end", "out"] + args, body,
                      {"cuda": cuda, "float64": float64, "fn": device(kernel.fn)})


def rows(array, s: int, e: int):
    """array[s:e] on the device; the whole array when that is all of it, or when it is an empty stand-in (no view
    to make, per step and array, on the one-field path)."""
    return array if array.shape[0] == 0 or (s == 0 and e == array.shape[0]) else array[s:e]


def launch(kern, n: int, *args):
    """Run `kern` on n threads (none when n = 0)."""
    if n > 0:
        kern[(n + THREADS - 1) // THREADS, THREADS](*args)


# ---- the kernels of the transfers and of fracture: thin wrappers of the shared per-item formulae

d_p2g_at = device(transfer.p2g_at)
d_grid_node_update = device(transfer.grid_node_update)
d_g2p_at = device(transfer.g2p_at)
d_advect_at = device(transfer.advect_at)
d_crack_contact_at = device(fracture.crack_contact_at)
d_crack_update_at = device(fracture.crack_update_at)
d_cell_key = device(fracture.cell_key)
d_broken_bonds = device(fracture.broken_bonds)
d_surface_at = device(contact.surface_at)
d_contact_node_at = device(contact.contact_node_at)
d_stencil_off_box = device(contact.stencil_off_box)


@cuda.jit(device=True)
def box_node(t, box):
    """Node (i, j, k) of thread t over the node box (i0, i1, j0, j1, k0, k1), or i = -1 past its end."""
    ny = box[3] - box[2]
    nz = box[5] - box[4]
    if t >= (box[1] - box[0]) * ny * nz:
        return -1, 0, 0
    return box[0] + t // (ny * nz), box[2] + (t // nz) % ny, box[4] + t % nz


@cuda.jit
def zero_box(box, grid):
    """grid = 0 on the node box: the only nodes P2G can touch this step."""
    i, j, k = box_node(cuda.grid(1), box)
    if i >= 0:
        for q in range(grid.shape[3]):
            grid[i, j, k, q] = 0.0


@cuda.jit
def p2g_kernel(particle_x, particle_v, particle_C, particle_mass, particle_force, particle_crack, pin_mask, dt, origin,
               inv_dx, grid, no_owner, no_rows, no_piece, no_box):
    p = cuda.grid(1)
    if p < particle_x.shape[0]:
        wx = cuda.local.array(4, float64)
        wy = cuda.local.array(4, float64)
        wz = cuda.local.array(4, float64)
        d_p2g_at(p, particle_x, particle_v, particle_C, particle_mass, particle_force, particle_crack, pin_mask, dt,
                 origin, inv_dx, grid, wx, wy, wz, no_owner, no_rows, no_rows, no_piece, 0.0, no_box, 0)


@cuda.jit
def grid_update_kernel(grid, dt, gravity, wind, drag, origin, dx, box, t_new, colliders, wall_boundary, wall_friction):
    i, j, k = box_node(cuda.grid(1), box)
    if i >= 0:
        v = cuda.local.array(3, float64)
        nrm = cuda.local.array(3, float64)
        d_grid_node_update(i, j, k, grid, dt, gravity, wind, drag, origin, dx, t_new, colliders, wall_boundary,
                           wall_friction, v, nrm)


@cuda.jit
def field_bounds(particle_x, bounds):
    """Per-axis min (0..2) and max (3..5) of one field's particle positions -> bounds: its node box."""
    p = cuda.grid(1)
    if p < particle_x.shape[0]:
        for a in range(3):
            cuda.atomic.min(bounds, a, particle_x[p, a])
            cuda.atomic.max(bounds, 3 + a, particle_x[p, a])


@cuda.jit
def surface_kernel(particle_x, particle_mass, particle_crack, origin, inv_dx, box, grid_surface, no_owner, no_rows,
                   no_piece, no_box):
    """contact.surfaces on the GPU: the particles whose stencils meet the box (contact.overlap_box) scatter."""
    p = cuda.grid(1)
    if p < particle_x.shape[0] and not d_stencil_off_box(particle_x, p, origin, inv_dx, box):
        wx = cuda.local.array(4, float64)
        wy = cuda.local.array(4, float64)
        wz = cuda.local.array(4, float64)
        gx = cuda.local.array(4, float64)
        gy = cuda.local.array(4, float64)
        gz = cuda.local.array(4, float64)
        d_surface_at(p, particle_x, particle_mass, particle_crack, origin, inv_dx, grid_surface, box, wx, wy, wz, gx,
                     gy, gz, no_owner, no_rows, no_rows, no_piece, 0.0, no_box, 0)


@cuda.jit
def contact_kernel(grid_field, grid_surface, friction, stiffness, dx, dt, box):
    i, j, k = box_node(cuda.grid(1), box)
    if i >= 0:
        d_contact_node_at(i, j, k, grid_field, grid_surface, friction, stiffness, dx, dt)


@cuda.jit
def reset_stats(stats):
    """Clear the per-step slots (bounds, max speed, non-finite count) before G2P fills them."""
    if cuda.grid(1) == 0:
        for a in range(3):
            stats[STAT_LO + a] = math.inf
            stats[STAT_HI + a] = -math.inf
        stats[STAT_VMAX] = 0.0
        stats[STAT_BAD] = 0.0


@cuda.jit(device=True)
def add_stats(p, s, particle_x, stats):
    """Fold particle p's speed s (-1: not finite) and position into the step's statistics."""
    if s < 0.0:
        cuda.atomic.add(stats, STAT_BAD, 1.0)
        return
    cuda.atomic.max(stats, STAT_VMAX, s)
    for a in range(3):
        cuda.atomic.min(stats, STAT_LO + a, particle_x[p, a])
        cuda.atomic.max(stats, STAT_HI + a, particle_x[p, a])


@cuda.jit
def g2p_kernel(grid, dt, origin, inv_dx, t_new, colliders, pin_mask, pin_velocity, pin_stop, flip, particle_crack,
               particle_x, particle_v, particle_C, particle_rho, stats, no_owner, no_rows, no_piece, no_box):
    p = cuda.grid(1)
    if p < particle_x.shape[0]:
        wx = cuda.local.array(4, float64)
        wy = cuda.local.array(4, float64)
        wz = cuda.local.array(4, float64)
        v = cuda.local.array(3, float64)
        nrm = cuda.local.array(3, float64)
        s = d_g2p_at(p, grid, dt, origin, inv_dx, t_new, colliders, pin_mask, pin_velocity, pin_stop, flip,
                     particle_crack, particle_x, particle_v, particle_C, particle_rho, wx, wy, wz, v, nrm, grid,
                     no_owner, no_rows, no_rows, no_piece, 0.0, no_box)
        add_stats(p, s, particle_x, stats)


@cuda.jit
def advect_kernel(grid, dt, origin, inv_dx, t_new, colliders, pin_mask, particle_crack, particle_x, particle_v,
                  stats, no_owner, no_rows, no_piece, no_box):
    p = cuda.grid(1)
    if p < particle_x.shape[0]:
        wx = cuda.local.array(4, float64)
        wy = cuda.local.array(4, float64)
        wz = cuda.local.array(4, float64)
        nrm = cuda.local.array(3, float64)
        s = d_advect_at(p, grid, dt, origin, inv_dx, t_new, colliders, pin_mask, particle_crack, particle_x,
                        particle_v, wx, wy, wz, nrm, grid, no_owner, no_rows, no_rows, no_piece, 0.0, no_box)
        add_stats(p, s, particle_x, stats)


@cuda.jit
def crack_contact_kernel(grid, dt, gravity, origin, inv_dx, crack_index, particle_damage, particle_mass,
                         particle_volume, particle_force, particle_x, particle_v):
    """fracture.crack_contact on one thread: each contact reads the grid the previous ones changed, so they run in
    the CPU's order (crack particles are few)."""
    if cuda.grid(1) == 0:
        wx = cuda.local.array(4, float64)
        wy = cuda.local.array(4, float64)
        wz = cuda.local.array(4, float64)
        gx = cuda.local.array(4, float64)
        gy = cuda.local.array(4, float64)
        gz = cuda.local.array(4, float64)
        for i in range(crack_index.shape[0]):
            d_crack_contact_at(crack_index[i], grid, dt, gravity, origin, inv_dx, particle_damage, particle_mass,
                               particle_volume, particle_force, particle_x, particle_v, wx, wy, wz, gx, gy, gz)


@cuda.jit
def crack_update_kernel(dt, t_new, colliders, lo, hi, crack_index, particle_x, particle_v, particle_C, stats):
    i = cuda.grid(1)
    if i < crack_index.shape[0]:
        v = cuda.local.array(3, float64)
        nrm = cuda.local.array(3, float64)
        p = crack_index[i]
        add_stats(p, d_crack_update_at(p, dt, t_new, colliders, lo, hi, particle_x, particle_v, particle_C, v, nrm),
                  particle_x, stats)


@cuda.jit
def zero_cells(cell_bonds, cell_broken):
    """Clear the cell counts (flat arrays over the grid's cells)."""
    c = cuda.grid(1)
    if c < cell_bonds.shape[0]:
        cell_bonds[c] = 0
        cell_broken[c] = 0


@cuda.jit
def count_cells(particle_x, origin, inv_dx, cells, bond_start, bond_active, cell_bonds, cell_broken):
    """Each particle's bonds and broken bonds into its cell's counts (eq. 21's p_inactive; integers, so the atomic
    order does not matter)."""
    p = cuda.grid(1)
    if p < particle_x.shape[0]:
        c = d_cell_key(particle_x, p, origin, inv_dx, cells)
        cuda.atomic.add(cell_bonds, c, bond_start[p + 1] - bond_start[p])
        cuda.atomic.add(cell_broken, c, d_broken_bonds(p, bond_start, bond_active))


@cuda.jit
def cell_fraction(particle_x, origin, inv_dx, cells, cell_bonds, cell_broken, particle_inactive):
    p = cuda.grid(1)
    if p < particle_x.shape[0]:
        c = d_cell_key(particle_x, p, origin, inv_dx, cells)
        nt = cell_bonds[c]
        particle_inactive[p] = cell_broken[c] / nt if nt > 0 else 0.0


class DeviceArrays:
    """Device copies of a host object's arrays by attribute name, uploaded on first use (or replaced by name)."""

    def __init__(self, host):
        self.__dict__["_host"] = host
        self.__dict__["_dev"] = {}

    def __getattr__(self, name):
        dev = self.__dict__["_dev"]
        if name not in dev:
            dev[name] = cuda.to_device(np.ascontiguousarray(getattr(self.__dict__["_host"], name)))
        return dev[name]

    def __setattr__(self, name, value):
        self.__dict__["_dev"][name] = value

    def allocated(self):
        return self.__dict__["_dev"]


class CudaBackend:
    """The State's arrays live on the GPU between frames; see the module docstring."""

    name = "cuda"

    def __init__(self):
        self.device_name = device_name()
        self.stats = np.zeros(N_STATS)
        self.dirty = False  # the device holds steps the host State has not seen
        self.dev_contact_box = None  # solver.contact_box on the device (plan.contact)

    # ---- host <-> device
    def start(self, solver, state):
        """Upload the State: the host State is the truth here, whatever the device still holds."""
        self.dirty = False
        solver.a = DeviceArrays(state)
        for name in state.arrays:
            getattr(solver.a, name)
        solver.m = DeviceArrays(solver.model)
        self.extra = DeviceArrays(solver)  # the solver's own arrays: cells, valid box, crack particles
        self.stats[STAT_LO:STAT_LO + 3] = state.particle_x.min(axis=0) if len(state.particle_x) else 0.0
        self.stats[STAT_HI:STAT_HI + 3] = state.particle_x.max(axis=0) if len(state.particle_x) else 0.0
        self.dev_stats = cuda.to_device(self.stats)
        # stand-ins for the crack fields' arrays (contact.cracks: separate runs on the CPU only)
        self.unsplit = (cuda.to_device(np.zeros((0, 0, 0), np.int64)), cuda.to_device(np.zeros((0, 3))),
                        cuda.to_device(np.zeros(0, np.int64)), cuda.to_device(np.zeros(6, np.int64)))
        self.solver = solver

    def sync(self, state):
        """Copy the device's State arrays (all but the grids) into the host State."""
        if self.dirty:
            dev = self.solver.a.allocated()
            for name, array in state.arrays.items():
                if name in dev and state.declared[name].where != GRID:
                    dev[name].copy_to_host(array)
            self.dirty = False

    def synchronize(self):
        cuda.synchronize()

    @contextmanager
    def on_host(self, state, names, changed=None):
        """Work on the host State's arrays `names` within the block; then upload `changed` (default: all of them),
        which the block may have replaced by arrays of another size."""
        dev = self.solver.a.allocated()
        for name in names:
            if name in dev and self.dirty:
                dev[name].copy_to_host(state.arrays[name])
        yield
        for name in names if changed is None else changed:
            host = state.arrays[name]
            if name in dev and dev[name].shape == host.shape:
                dev[name].copy_to_device(host)
            else:
                dev[name] = cuda.to_device(host)

    def run(self, kernel, start, end, *args):
        self.dirty = True
        out = None
        if kernel.reduce is not None:
            out = cuda.to_device(np.array([-math.inf if kernel.reduce == "max" else 0.0]))
        launch(particle_kernel(kernel), end - start, start, end, out if out is not None else self.dev_stats, *args)
        if out is None:
            return None
        value = float(out.copy_to_host()[0])
        return value if kernel.reduce == "max" else int(round(value))

    # ---- the transfers
    @staticmethod
    def fields(solver):
        """(grid, start, end) per grid field on the device: the one grid and every particle, or each body's field
        and its particles (plan.contact)."""
        if not solver.plan.contact:
            return ((solver.a.grid, 0, solver.model.n_particles),)
        return tuple((solver.a.grid_field[f], b.start, b.end) for f, b in enumerate(solver.model.bodies))

    def p2g(self, solver, state, dt) -> int:
        """Node box and domain test from the bounds of the last G2P (transfer.stencil_on_grid on the extreme
        particles is the test on all of them), then P2G. Returns 1 when particles are off the grid (no launch)."""
        self.dirty = True
        m, a, d = solver.model, solver.a, solver.m
        nodes = np.asarray(m.grid_shape)
        lo, hi = self.stats[STAT_LO:STAT_LO + 3], self.stats[STAT_HI:STAT_HI + 3]
        if ((lo - m.origin) / m.dx < 1.0).any() or ((hi - m.origin) / m.dx >= nodes - 3).any():
            return 1
        solver.box = solver.box_of(lo, hi)
        self.box = cuda.to_device(solver.box)
        b = solver.box
        nodes_in_box = int((b[1] - b[0]) * (b[3] - b[2]) * (b[5] - b[4]))
        if solver.plan.contact:
            self.contact_box(solver)
        c = solver.contact_box
        nodes_in_contact = 0 if c is None else int((c[1] - c[0]) * (c[3] - c[2]) * (c[5] - c[4]))
        for f, (grid, s, e) in enumerate(self.fields(solver)):
            x, mass, crack = rows(a.particle_x, s, e), rows(d.particle_mass, s, e), rows(a.particle_crack, s, e)
            launch(zero_box, nodes_in_box, self.box, grid)
            launch(p2g_kernel, e - s, x, rows(a.particle_v, s, e), rows(a.particle_C, s, e), mass,
                   rows(a.particle_force, s, e), crack, rows(d.pin_mask, s, e), dt, d.origin, 1.0 / m.dx, grid,
                   *self.unsplit)
            if solver.plan.contact:  # no overlap: nothing to launch
                launch(zero_box, nodes_in_contact, self.dev_contact_box, a.grid_surface[f])
                launch(surface_kernel, (e - s) if nodes_in_contact else 0, x, mass, crack, d.origin, 1.0 / m.dx,
                       self.dev_contact_box, a.grid_surface[f], *self.unsplit)
        return 0

    def contact_box(self, solver):
        """contact.overlap_box of the fields' node boxes (from their particles' bounds: one more small read-back
        per step) -> solver.contact_box and its device copy."""
        fields = self.fields(solver)
        bounds = np.empty((len(fields), 6))
        bounds[:, :3], bounds[:, 3:] = math.inf, -math.inf
        dev = cuda.to_device(bounds)
        for f, (_, s, e) in enumerate(fields):
            launch(field_bounds, e - s, rows(solver.a.particle_x, s, e), dev[f])
        dev.copy_to_host(bounds)
        boxes = [solver.box_of(lo_hi[:3], lo_hi[3:]) if e > s else None
                 for lo_hi, (_, s, e) in zip(bounds, fields)]
        solver.contact_box = contact.overlap_box(boxes)
        self.dev_contact_box = cuda.to_device(solver.contact_box)

    def grid_update(self, solver, state, kick, t_new):
        m, b = solver.model, solver.box
        for grid, _, _ in self.fields(solver):
            launch(grid_update_kernel, int((b[1] - b[0]) * (b[3] - b[2]) * (b[5] - b[4])), grid, kick,
                   solver.m.gravity, solver.m.wind_velocity, m.wind_drag, solver.m.origin, m.dx, self.box,
                   t_new, solver.m.colliders, m.wall_boundary, m.wall_friction)

    def contact(self, solver, state, dt):
        c = solver.contact_box
        launch(contact_kernel, int((c[1] - c[0]) * (c[3] - c[2]) * (c[5] - c[4])), solver.a.grid_field,
               solver.a.grid_surface, solver.m.contact_friction, solver.m.contact_stiffness, solver.model.dx, dt,
               self.dev_contact_box)

    def g2p(self, solver, state, dt) -> tuple[float, int]:
        """G2P, then the one read-back of the step: speed, non-finite count and bounds (crack particles included:
        their update ran before and left their figures in the statistics)."""
        m, a, d = solver.model, solver.a, solver.m
        if not (solver.plan.fracture and len(solver.crack_index)):
            launch(reset_stats, 1, self.dev_stats)
        for grid, s, e in self.fields(solver):
            pins = (rows(d.pin_mask, s, e), rows(d.pin_velocity, s, e), rows(d.pin_stop, s, e))
            launch(g2p_kernel, e - s, grid, dt, d.origin, 1.0 / m.dx, state.time + dt, d.colliders, *pins, m.flip,
                   rows(a.particle_crack, s, e), rows(a.particle_x, s, e), rows(a.particle_v, s, e),
                   rows(a.particle_C, s, e), rows(a.particle_rho, s, e), self.dev_stats, *self.unsplit)
        if solver.plan.remap:
            return 0.0, 0  # read back after the remap's position pass
        self.dev_stats.copy_to_host(self.stats)
        return float(self.stats[STAT_VMAX]), int(self.stats[STAT_BAD])

    def remap(self, solver, state, dt) -> tuple[float, int]:
        """MUSL after a FLIP G2P (as CpuBackend.remap): P2G of the new velocities with no force at the positions G2P
        read (the same node box), the grid update with dt = 0 and contact, then the position pass; its positions
        join the statistics G2P opened (bounds of both positions: a box at most one step larger)."""
        m, a, d, b = solver.model, solver.a, solver.m, solver.box
        nodes_in_box = int((b[1] - b[0]) * (b[3] - b[2]) * (b[5] - b[4]))
        t_new = state.time + dt
        fields = self.fields(solver)
        for grid, s, e in fields:
            launch(zero_box, nodes_in_box, self.box, grid)
            launch(p2g_kernel, e - s, rows(a.particle_x, s, e), rows(a.particle_v, s, e), rows(a.particle_C, s, e),
                   rows(d.particle_mass, s, e), rows(a.particle_force, s, e), rows(a.particle_crack, s, e),
                   rows(d.pin_mask, s, e), 0.0, d.origin, 1.0 / m.dx, grid, *self.unsplit)
            launch(grid_update_kernel, nodes_in_box, grid, 0.0, d.gravity, d.wind_velocity, m.wind_drag, d.origin,
                   m.dx, self.box, t_new, d.colliders, m.wall_boundary, m.wall_friction)
        if solver.plan.contact:
            self.contact(solver, state, 0.0)
        for grid, s, e in fields:
            launch(advect_kernel, e - s, grid, dt, d.origin, 1.0 / m.dx, t_new, d.colliders, rows(d.pin_mask, s, e),
                   rows(a.particle_crack, s, e), rows(a.particle_x, s, e), rows(a.particle_v, s, e), self.dev_stats,
                   *self.unsplit)
        self.dev_stats.copy_to_host(self.stats)
        return float(self.stats[STAT_VMAX]), int(self.stats[STAT_BAD])

    def crack(self, solver, state, kick, dt) -> tuple[float, int]:
        """Crack particles: their kick and contact with their own body's material, then with the other bodies'
        (dt = 0: no second kick), in the CPU's order (serial, on one thread), and update; their speeds and positions
        open this step's statistics, which G2P completes and reads back."""
        m, a, d, e = solver.model, solver.a, solver.m, self.extra
        fields = self.fields(solver)
        for own in (True, False):  # with one field the second pass has no particles
            for grid, s, end in fields:
                lo, hi = np.searchsorted(solver.crack_index, (s, end))
                parts = ((lo, hi, kick),) if own else ((0, lo, 0.0), (hi, len(solver.crack_index), 0.0))
                for i0, i1, step in parts:
                    if i1 > i0:
                        launch(crack_contact_kernel, 1, grid, step, d.gravity, d.origin, 1.0 / m.dx,
                               e.crack_index[i0:i1], a.particle_damage, d.particle_mass, d.particle_volume,
                               a.particle_force, a.particle_x, a.particle_v)
        launch(reset_stats, 1, self.dev_stats)
        launch(crack_update_kernel, len(solver.crack_index), dt, state.time + dt, d.colliders, e.valid_lo,
               e.valid_hi, e.crack_index, a.particle_x, a.particle_v, a.particle_C, self.dev_stats)
        return 0.0, 0  # read back with G2P's

    def inactive_fraction(self, solver, state):
        m, a, e = solver.model, solver.a, self.extra
        launch(zero_cells, a.cell_bonds.shape[0], a.cell_bonds, a.cell_broken)
        launch(count_cells, m.n_particles, a.particle_x, solver.m.origin, 1.0 / m.dx, e.cells, a.bond_start,
               a.bond_active, a.cell_bonds, a.cell_broken)
        launch(cell_fraction, m.n_particles, a.particle_x, solver.m.origin, 1.0 / m.dx, e.cells, a.cell_bonds,
               a.cell_broken, a.particle_inactive)

    def crack_particles_changed(self, solver, state):
        setattr(self.extra, "crack_index", cuda.to_device(solver.crack_index))
