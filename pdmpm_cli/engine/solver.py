"""Explicit MPM step with peridynamic bond forces (paper section 3) and the frame loop around it.

The step reads top to bottom as the paper's loop: bond forces (eq. 4, then each body's material), P2G, the grid
update, contact between bodies (ours: engine/contact.py), the crack particles' own integrator and G2P, with a FLIP
share MUSL's position pass (ours: engine/transfer.py, advect_at), a material's pass on the moved particles (ours: a
liquid's particle shift), then fracture. A part a scene does not need is
skipped by a switch the Plan set once (`plan.fbar`, `plan.fracture`, `plan.contact`, `plan.remap`); materials are
called through their registry entries, never by type. The backend (engine/backends) runs each part on the CPU or
the GPU."""

import time
from collections import defaultdict
from contextlib import contextmanager

import numpy as np

from pdmpm_cli.engine.bonds import AVERAGED_DEFORMATION, averaged_deformation, bond_reference_terms
from pdmpm_cli.engine.colliders import PENALTY, header_rows
from pdmpm_cli.engine.crack import PIECE_MIN, crack_normals
from pdmpm_cli.engine.emitter import emit
from pdmpm_cli.engine.fracture import CRITERION, damage, fracture_update, pieces
from pdmpm_cli.engine.materials import MATERIALS, declared_fields
from pdmpm_cli.engine.model import Model
from pdmpm_cli.engine.parallel import particle_chunks
from pdmpm_cli.engine.plan import Plan
from pdmpm_cli.engine.state import State
from pdmpm_cli.engine.transfer import WALL
from pdmpm_cli.errors import InputError, SimulationError

RUNAWAY_FACTOR = 10.0  # kinetic energy above this multiple of the energy budget is a blow-up


def initial_state(model: Model, plan: Plan, velocity: np.ndarray, velocity_gradient: np.ndarray) -> State:
    """The State at t = 0: the Plan's arrays, particles at rest positions with their initial velocity and APIC
    matrix, the reference families, and the reference bond factors (w V_q, 1 / |xi|) where they exist."""
    declared = declared_fields()
    specs = {name: spec for name, spec in plan.fields.items() if name in declared}
    state = State.allocate(declared, specs, {
        "particle_x": model.rest_x, "particle_v": velocity, "particle_C": velocity_gradient,
        "bond_start": model.bond_start, "bond_nbr": model.bond_nbr})
    if state.has("bond_wv"):
        bond_reference_terms(model.rest_x, model.particle_volume, model.bond_start, model.bond_nbr,
                             model.particle_body, model.body_horizon, state.bond_wv, state.bond_inv_len)
    return state


def kinetic_energy(particle_mass: np.ndarray, particle_v: np.ndarray) -> float:
    """1/2 sum_p m_p |v_p|^2 [J]."""
    return 0.5 * float(np.dot(particle_mass, np.einsum("ij,ij->i", particle_v, particle_v)))


def pin_speed(model: Model) -> float:
    """Largest prescribed speed of the pinned particles [m/s] (0 without pins)."""
    held = model.pin_mask.astype(bool) if len(model.pin_mask) else np.zeros(0, dtype=bool)
    return float(np.linalg.norm(model.pin_velocity[held], axis=1).max()) if held.any() else 0.0


def make_backend(name: str):
    """The backend of that name; numba.cuda is imported only for 'cuda', and a machine without a usable GPU (or
    numba's simulator) is refused as bad input."""
    if name == "cuda":
        if not hasattr(np, "row_stack"):
            np.row_stack = np.vstack  # numba-cuda 0.30 still calls np.row_stack, which numpy 2.5 removed
        try:
            from numba import cuda
        except ImportError as e:
            raise InputError(f"simulation.backend = cuda: numba.cuda cannot be imported ({e}); install numba-cuda, "
                             f"or run with --backend cpu") from e
        if not cuda.is_available():
            raise InputError("simulation.backend = cuda needs an NVIDIA GPU with a working CUDA driver, and numba.cuda "
                             "finds none; run with --backend cpu (or set NUMBA_ENABLE_CUDASIM=1 to run the CUDA "
                             "kernels on numba's simulator, for testing only: it is very slow)")
        from pdmpm_cli.engine.backends.cuda import CudaBackend

        return CudaBackend()
    from pdmpm_cli.engine.backends.cpu import CpuBackend

    return CpuBackend()


class Solver:
    """Steps one State with the Plan's parts on a backend. Everything that evolves lives in the State."""

    def __init__(self, model: Model, plan: Plan, backend=None, profile: bool = False):
        self.model = model
        self.plan = plan
        self.backend = backend if backend is not None else make_backend(plan.backend)
        self.kick = 0.0  # the step's kick [s], (dt_prev + dt) / 2 (substep)
        self.kinds = [MATERIALS[b.kind] for b in model.bodies]
        self.fbar_bodies = [i for i, (k, b) in enumerate(zip(self.kinds, model.bodies)) if k.uses_fbar(b.params)]
        self.step_fbar_bodies = [i for i in self.fbar_bodies if not self.kinds[i].computes_fbar]  # the fbar phase's
        self.fracture_bodies = [i for i, b in enumerate(model.bodies) if b.fracture is not None]
        self.movers = [i for i, (k, b) in enumerate(zip(self.kinds, model.bodies))
                       if k.after_move is not None and k.moves(b.params)]  # bodies whose material acts after G2P
        self.phase_time = defaultdict(float)  # seconds spent in each part of the step, for benchmarks
        self.clock = time.perf_counter  # the phase timer (benchmarks on a busy machine use process time)
        self.profile = profile  # the CUDA backend synchronises after every part, so the times are the GPU's
        self.state = None  # the State this solver steps, bound by start()
        self.a = None  # the backend's arrays of the state (host or device), by name
        self.m = None  # the backend's arrays of the model
        self.box = None  # the node box P2G touched this step
        self.contact_box = None  # within it, where two bodies' fields can meet (plan.contact)
        self.crack_index = np.zeros(0, np.int64)  # the crack-surface particles, in order
        nodes = np.asarray(model.grid_shape)
        self.cells = (nodes - 1).astype(np.int64)
        self.valid_lo = model.origin + WALL * model.dx
        self.valid_hi = model.origin + (nodes - 1 - WALL) * model.dx

    # ---- the step
    def substep(self, state: State, dt: float):
        """One explicit step (paper section 3) as a leapfrog: the velocities live at the half steps, so the kick
        (forces, gravity, drag, contact and collider pushes) spans (dt_prev + dt) / 2, half a step on the first, and
        the drift (G2P's x += dt v) spans dt. With a kick of dt from the first step on (symplectic Euler from the
        initial velocity) every trajectory under gravity ran g t dt / 2 ahead of g t^2 / 2 (docs/method.md)."""
        self.kick = 0.5 * (state.dt_prev + dt)
        self.forces(state, dt)
        with self.timed("p2g"):
            if self.backend.p2g(self, state, self.kick):
                self.fail_outside(state)
        with self.timed("grid_update"):
            self.backend.grid_update(self, state, self.kick, state.time + dt)
        if self.plan.contact:
            with self.timed("contact"):
                self.backend.contact(self, state, self.kick)
        crack_vmax = 0.0
        if self.plan.fracture:
            with self.timed("crack"):
                crack_vmax = self.crack(state, dt)
        with self.timed("g2p"):
            vmax, bad = self.backend.g2p(self, state, dt)
            if bad:
                self.fail_nonfinite(state)
        if self.plan.remap:
            with self.timed("remap"):
                vmax, bad = self.backend.remap(self, state, dt)
                if bad:
                    self.fail_nonfinite(state)
        for i in self.movers:
            kind = self.kinds[i]
            with self.timed(f"{kind.after_move.__name__}:{kind.name}"):
                kind.after_move(self, i, dt)
        state.vmax = max(vmax, crack_vmax)
        if self.plan.fracture:
            with self.timed("fracture"):
                self.fracture(state)
        state.step += 1
        state.time += dt
        state.dt_prev = dt

    def forces(self, state: State, dt: float):
        """particle_force of every body: Fbar (eq. 4) where a material reads it, then each body's material."""
        if self.plan.fbar:
            with self.timed("fbar"):
                self.fbar(self.step_fbar_bodies)
        for hook in ("before_forces", "forces", "after_forces"):
            for i, kind in enumerate(self.kinds):
                fn = getattr(kind, hook)
                if fn is not None:
                    with self.timed(f"{fn.__name__}:{kind.name}"):
                        fn(self, i, dt)
        if self.model.collider_penalty.size:
            with self.timed("collider_penalty"):
                m, a = self.m, self.a
                for i, b in enumerate(self.model.bodies):
                    self.backend.run(PENALTY, b.start, b.end, m.colliders, state.time, self.kick,
                                     self.model.collider_penalty[i], 0.5 * b.spacing, m.pin_mask, a.particle_x,
                                     a.particle_v, m.particle_mass, a.particle_force)
        if self.model.emitter is not None:  # births after the families' rebuild point, where x_prev = x
            with self.timed("emit"):
                emit(self, state)

    def bond_forces(self, dt: float):
        """particle_force of every body from the current positions alone, without the materials' other hooks (no
        return map, no family rebuild): what the stiffness probes of engine.spectrum and the studies need."""
        if self.plan.fbar:
            self.fbar()
        for i, kind in enumerate(self.kinds):
            (kind.bond_forces or kind.forces)(self, i, dt)

    def fbar(self, bodies=None):
        """Eq. 4 for the bodies whose material uses Fbar (or those of `bodies`)."""
        a, m = self.a, self.m
        for i in self.fbar_bodies if bodies is None else bodies:
            b = self.model.bodies[i]
            self.backend.run(AVERAGED_DEFORMATION, b.start, b.end, a.particle_x, m.rest_x, a.bond_start, a.bond_nbr,
                             a.bond_wv, m.particle_Kinv, a.particle_Fbar, particle_chunks())

    def crack(self, state: State, dt: float) -> float:
        """Crack-surface particles advance by their own bond forces, gravity and collisions (section 6), and meet
        the material on the grid in an inelastic contact. Returns their largest speed."""
        if not len(self.crack_index):
            return 0.0
        vmax, bad = self.backend.crack(self, state, self.kick, dt)
        if bad:
            self.fail_nonfinite(state)
        return vmax

    def fracture(self, state: State):
        """Eq. 21 criterion, clustering and fracture planes (section 6), then damage and the crack particles.

        Particles with a broken bond stop using Fbar (elastic.py), so K^-1 never needs recomputing. The clustering
        is serial and runs on the host."""
        be, a, m = self.backend, self.a, self.m
        be.inactive_fraction(self, state)
        candidates = []
        for i in self.fracture_bodies:
            b = self.model.bodies[i]
            if be.run(CRITERION, b.start, b.end, b.fracture.threshold, b.fracture.damage_resistance, a.particle_x,
                      m.rest_x, a.bond_start, a.bond_nbr, a.bond_active, a.bond_ep, a.particle_inactive,
                      a.particle_lmax, a.particle_bmax):
                candidates.append(b)
        if not candidates:
            return
        cut = 0
        with be.on_host(state, ("particle_x", "bond_active", "particle_lmax", "particle_bmax", "particle_damage",
                                "particle_crack"), changed=("bond_active", "particle_damage", "particle_crack")):
            for b in candidates:
                cut += fracture_update(b.fracture.threshold, b.horizon, b.start, b.end, state.particle_x,
                                       self.model.rest_x, state.bond_start, state.bond_nbr, state.bond_active,
                                       state.particle_lmax, state.particle_bmax, self.model.particle_cut)
            if cut:
                damage(state.bond_start, state.bond_active, state.particle_damage, state.particle_crack)
                self.crack_sides(state)
                self.crack_index = self.off_grid(state)
        if cut:
            state.bonds_cut += cut
            be.crack_particles_changed(self, state)

    def off_grid(self, state: State) -> np.ndarray:
        """The crack particles that leave the grid for their own integrator (section 6), in order: all of them but
        those of crack-field bodies that belong to a large piece, which stay on the grid on their side's field
        (engine/crack.py); `crack_sides` marks the others (dust and chips) in particle_dust."""
        crack = state.particle_crack.astype(bool)
        for i in self.model.crack_bodies:
            b = self.model.bodies[i]
            crack[b.start:b.end] = state.particle_dust[b.start:b.end] != 0
        return np.flatnonzero(crack).astype(np.int64)

    def crack_sides(self, state: State):
        """Each crack body's pieces and crack directions from its broken and cut bonds (engine/crack.py), on the host
        State. Particles of pieces under PIECE_MIN of the body split no node (debris would put both large pieces on
        one side), and their crack particles, dust and chips, fly off the grid on the crack particles' own
        integrator, kept inside the domain as the paper's are (particle_dust)."""
        m = self.model
        if not m.crack_bodies:
            return
        fractured = state.has("bond_active")  # else a body with cutouts alone: every bond intact
        active = state.bond_active if fractured else np.zeros(0, dtype=np.uint8)
        intact = active == 1 if fractured else np.ones(len(state.bond_nbr), dtype=bool)
        for i in m.crack_bodies:
            b = m.bodies[i]
            crack_normals(b.start, b.end, m.rest_x, state.bond_start, state.bond_nbr, active, m.particle_cut,
                          state.particle_crack_n, state.particle_crack_s)
            label = pieces(state.bond_start, state.bond_nbr, intact, b.start, b.end)
            state.particle_piece[b.start:b.end] = label
            small = np.bincount(label)[label] < PIECE_MIN * (b.end - b.start)
            state.particle_crack_s[b.start:b.end][small] = 0.0
            if state.has("particle_crack"):
                state.particle_dust[b.start:b.end] = small & (state.particle_crack[b.start:b.end] != 0)

    @contextmanager
    def timed(self, name: str):
        t0 = self.clock()
        yield
        if self.profile:
            self.backend.synchronize()
        self.phase_time[name] += self.clock() - t0

    def box_of(self, lo, hi) -> np.ndarray:
        """Node index box [i0, i1) x [j0, j1) x [k0, k1) of the B-spline stencils of particles within [lo, hi]."""
        m = self.model
        shape = np.asarray(m.grid_shape)
        lo = np.clip(np.floor((lo - m.origin) / m.dx).astype(np.int64) - 2, 0, shape)
        hi = np.clip(np.floor((hi - m.origin) / m.dx).astype(np.int64) + 4, 0, shape)
        return np.array([lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]], dtype=np.int64)

    def step_size(self) -> float:
        """dt = min(dt_max, cfl dx / (c + |v|max)) (section 6 of the method)."""
        p = self.plan
        return min(p.dt_max, p.dt_cfl * p.wave_speed / (p.wave_speed + self.state.vmax))

    def advance(self, state: State, t_end: float, on_substep=None):
        """Substep until state.time reaches t_end exactly; the last step is shortened to land on it. Then the
        host State is made current and the blow-up check runs."""
        while state.time < t_end - 1e-12 * max(1.0, t_end):
            dt = min(self.step_size(), t_end - state.time)
            self.substep(state, dt)
            if on_substep is not None:
                on_substep(state, dt)
        self.check_energy(state)

    # ---- start, and the host State
    def start(self, state: State):
        """Bind the solver to a fresh State: the materials' initial values, then the energy budget the runaway
        check measures against [J] (what gravity over the domain's largest extent, the colliders' motion, the wind,
        the pins and the initial motion can legitimately supply) and the speed of the first step's CFL bound."""
        for i, kind in enumerate(self.kinds):
            if kind.start is not None:
                kind.start(self, state, i)
        m = self.model
        extent = float(np.max(np.asarray(m.grid_shape) - 1) * m.dx)
        heads = header_rows(m.colliders)
        v_coll = float(np.abs(m.colliders[heads, 10:13]).max()) if heads else 0.0
        v_coll = max(v_coll, float(np.linalg.norm(m.wind_velocity)))  # the wind can bring material to its speed
        v_coll = max(v_coll, pin_speed(m))  # so can a moving pin that drags its body along
        mass = float(m.particle_mass.sum())
        state.energy_budget = kinetic_energy(m.particle_mass, state.particle_v) + mass * (
            np.linalg.norm(m.gravity) * extent + v_coll**2)
        state.energy_budget += self.host_strain_energy(state) + 1e-12 * mass
        state.energy_prev = state.energy_budget
        # The first step's CFL bound sees the initial speeds: a body thrown at 10 dx / dt otherwise moved 10 cells in
        # its first step.
        v2 = np.einsum("ij,ij->i", state.particle_v, state.particle_v)
        state.vmax = float(np.sqrt(v2.max())) if len(v2) else 0.0
        self.bind(state)

    def bind(self, state: State):
        """Step this State from now on (after start, or after a checkpoint was restored into it): the backend
        takes its arrays (the CUDA backend uploads them)."""
        self.state = state
        self.crack_sides(state)
        self.crack_index = self.off_grid(state) if state.has("particle_crack") else np.zeros(0, np.int64)
        self.backend.start(self, state)

    def sync(self, state: State) -> State:
        """The host State, current (the CUDA backend copies its arrays back)."""
        self.backend.sync(state)
        return state

    # ---- diagnostics, on the host State
    def kinetic_energy(self, state: State) -> float:
        self.sync(state)
        return kinetic_energy(self.model.particle_mass, state.particle_v)

    def angular_momentum(self, state: State, about) -> np.ndarray:
        """Total angular momentum [kg m^2/s]: particles plus the APIC affine part m_p (dx^2/3) eps_ijk C_kj,
        which APIC transfers conserve together (Jiang et al. 2015)."""
        self.sync(state)
        m = self.model.particle_mass
        r = state.particle_x - np.asarray(about)
        lin = (m[:, None] * np.cross(r, state.particle_v)).sum(axis=0)
        c = np.einsum("p,pkj->kj", m, state.particle_C) * (self.model.dx**2 / 3.0)
        return lin + np.array([c[2, 1] - c[1, 2], c[0, 2] - c[2, 0], c[1, 0] - c[0, 1]])

    def strain_energy(self, state: State) -> float:
        """Total strain energy of all bodies [J] (eq. 5 with the calibration)."""
        self.sync(state)
        return self.host_strain_energy(state)

    def host_strain_energy(self, state: State) -> float:
        """Strain energy from the host State's arrays, with Fbar recomputed there by the CPU kernel."""
        m = self.model
        for i in self.fbar_bodies:
            b = m.bodies[i]
            averaged_deformation(b.start, b.end, state.particle_x, m.rest_x, state.bond_start, state.bond_nbr,
                                 state.bond_wv, m.particle_Kinv, state.particle_Fbar, particle_chunks())
        return sum(k.energy(self, state, i) for i, k in enumerate(self.kinds) if k.energy is not None)

    def check_energy(self, state: State):
        """Blow-up test, once per frame: kinetic energy may not exceed 10x the larger of the budget and the
        total (kinetic + strain) energy at the previous check. Pins and breaking bonds may legitimately turn
        stored energy into motion; they cannot multiply the total tenfold within one frame."""
        ke = self.kinetic_energy(state)
        limit = RUNAWAY_FACTOR * max(state.energy_budget, state.energy_prev)
        state.energy_prev = ke + self.host_strain_energy(state)
        if ke > limit:
            fastest = np.argsort(np.einsum("ij,ij->i", state.particle_v, state.particle_v))[-5:][::-1]
            raise SimulationError(
                f"runaway energy after step {state.step} (t = {state.time:.6g} s): kinetic energy {ke:.4g} J exceeds "
                f"{RUNAWAY_FACTOR:g}x the energy of the previous frame or what gravity, colliders and the initial motion "
                f"can supply ({limit:.4g} J); "
                f"fastest particles {fastest.tolist()} at speed "
                f"{np.linalg.norm(state.particle_v[fastest[0]]):.4g} m/s. "
                f"Lower {self.knobs()} (now {self.plan.dt_max:.3g} s max step)"
            )

    def knobs(self) -> str:
        """The factors that set the step: bond_safety only where the rule applies a bond bound."""
        return "simulation.cfl" + (" or simulation.bond_safety" if self.plan.dt_bond < np.inf else "")

    def fail_nonfinite(self, state: State):
        self.sync(state)
        bad = np.flatnonzero(~np.isfinite(state.particle_x).all(axis=1) | ~np.isfinite(state.particle_v).all(axis=1))
        raise SimulationError(
            f"NaN or infinite values at step {state.step + 1} (t = {state.time:.6g} s) in {len(bad)} particles "
            f"(first: {bad[:8].tolist()}). The step became unstable: lower {self.knobs()}, or set a "
            f"smaller simulation.dt (max step now {self.plan.dt_max:.3g} s)"
        )

    def fail_outside(self, state: State):
        self.sync(state)
        m = self.model
        nodes = np.asarray(m.grid_shape)
        f = (state.particle_x - m.origin) / m.dx
        bad = np.flatnonzero(~((f >= 1.0) & (f < nodes - 3)).all(axis=1))
        cells_per_step = np.linalg.norm(state.particle_v[bad], axis=1).max() * self.plan.dt_max / m.dx
        hint = (f"they move {cells_per_step:.2g} cells per step, so the step is unstable: lower {self.knobs()}, or "
                f"set a smaller simulation.dt" if cells_per_step > 1.0 else
                "enlarge grid.domain, or check initial velocities and collider motion")
        raise SimulationError(
            f"{len(bad)} particles left the simulation domain at step {state.step + 1} (t = {state.time:.6g} s), "
            f"first {bad[:8].tolist()} at {np.round(state.particle_x[bad[0]], 4).tolist()}; {hint}"
        )
