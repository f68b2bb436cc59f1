"""Explicit MPM step with peridynamic bond forces (paper section 3) and the frame loop around it."""

import time
from collections import defaultdict

import numpy as np

from pdmpm_cli.engine.bonds import averaged_deformation
from pdmpm_cli.engine.parallel import particle_chunks
from pdmpm_cli.engine.fracture import (bond_criterion, crack_contact, crack_particle_update, damage, fracture_update,
                                      inactive_fraction)
from pdmpm_cli.engine.materials import MATERIALS
from pdmpm_cli.engine.model import Model, State
from pdmpm_cli.engine.transfer import WALL, g2p, grid_update, p2g, position_bounds
from pdmpm_cli.errors import SimulationError
from pdmpm_cli.plan import Plan

RUNAWAY_FACTOR = 10.0  # kinetic energy above this multiple of the energy budget is a blow-up


def kinetic_energy(particle_mass: np.ndarray, particle_v: np.ndarray) -> float:
    """1/2 sum_p m_p |v_p|^2 [J]."""
    return 0.5 * float(np.dot(particle_mass, np.einsum("ij,ij->i", particle_v, particle_v)))


def pin_speed(model: Model) -> float:
    """Largest prescribed speed of the pinned particles [m/s] (0 without pins)."""
    held = model.pin_mask.astype(bool) if len(model.pin_mask) else np.zeros(0, dtype=bool)
    return float(np.linalg.norm(model.pin_velocity[held], axis=1).max()) if held.any() else 0.0


class Solver:
    """Runs the Plan's phases on a State; one method per phase, each one jitted kernel."""

    def __init__(self, model: Model, plan: Plan):
        self.model = model
        self.plan = plan
        self.vmax = 0.0
        self.crack_vmax = 0.0  # max speed of the crack particles, set before g2p each step
        self.energy_budget = 0.0
        self.energy_prev = 0.0  # kinetic + strain energy at the previous frame [J]
        self.phase_time = defaultdict(float)  # seconds spent in each phase, for benchmarks
        self.clock = time.perf_counter  # the phase timer (benchmarks on a busy machine use process time)
        self.yield_residual = -1.0  # largest f / psi_p after any return map so far (0: exactly on the surface)
        self.bonds_cut = 0  # bonds removed by fracture planes so far
        kinds = [b.model for b in plan.bodies]
        self.bodies_of = {k: [i for i, kk in enumerate(kinds) if kk == k] for k in kinds}
        self.fbar_bodies = [i for i, (k, mat) in enumerate(zip(kinds, model.materials))
                            if MATERIALS[k].needs_fbar(mat)]
        self.fracture_bodies = [i for i, f in enumerate(model.fracture) if f is not None]
        if self.fracture_bodies:
            nodes = np.asarray(model.grid_shape)
            self.cells = (nodes - 1).astype(np.int64)
            self.valid_lo = model.origin + WALL * model.dx
            self.valid_hi = model.origin + (nodes - 1 - WALL) * model.dx

    # ---- phases
    def fbar(self, state: State, dt: float = 0.0):
        """Eq. 4 for the bodies whose material uses Fbar."""
        m = self.model
        for body in self.fbar_bodies:
            start, end = m.body_ranges[body]
            averaged_deformation(start, end, state.particle_x, m.rest_x, state.bond_start, state.bond_nbr,
                                 state.bond_wv, m.particle_Kinv, state.particle_Fbar, particle_chunks())

    def material_phase(self, state: State, stage: str, kind: str, dt: float):
        """Run a material's phase (e.g. return_map:plastic, bonds:elastic) on every body of that kind."""
        fn = MATERIALS[kind].phases[stage]
        for body in self.bodies_of[kind]:
            result = fn(self.model, state, body, dt)
            if stage == "return_map":
                self.yield_residual = max(self.yield_residual, result)

    def node_box(self, state: State) -> np.ndarray:
        """Node index box [i0, i1) x [j0, j1) x [k0, k1) touched by the particles' B-spline stencils."""
        m = self.model
        x_lo, x_hi = position_bounds(state.particle_x, particle_chunks())
        lo = np.floor((x_lo - m.origin) / m.dx).astype(np.int64) - 2
        hi = np.floor((x_hi - m.origin) / m.dx).astype(np.int64) + 4
        shape = np.asarray(m.grid_shape)
        lo = np.clip(lo, 0, shape)
        hi = np.clip(hi, 0, shape)
        return np.array([lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]], dtype=np.int64)

    def step_size(self) -> float:
        """dt = min(dt_max, cfl dx / (c + |v|max)) (METHOD.md section 6)."""
        p = self.plan
        return min(p.dt_max, p.dt_cfl * p.wave_speed / (p.wave_speed + self.vmax))

    def p2g(self, state: State, dt: float):
        m = self.model
        self.box = self.node_box(state)
        outside = p2g(state.particle_x, state.particle_v, state.particle_C, m.particle_mass, state.particle_force,
                      state.particle_crack, m.pin_mask, dt, m.origin, 1.0 / m.dx, self.box, state.grid_private, state.grid)
        if outside:
            self.fail_outside(state)

    def grid_update(self, state: State, dt: float):
        m = self.model
        grid_update(state.grid, dt, m.gravity, m.wind_velocity, m.wind_drag, m.origin, m.dx, self.box,
                    state.time + dt, m.colliders, m.wall_boundary, m.wall_friction)

    def g2p(self, state: State, dt: float):
        m = self.model
        vmax, bad = g2p(state.grid, dt, m.origin, 1.0 / m.dx, state.time + dt, m.colliders, m.pin_mask,
                        m.pin_velocity, m.pin_stop, state.particle_crack, state.particle_x, state.particle_v,
                        state.particle_C, particle_chunks())
        self.vmax = max(vmax, self.crack_vmax)
        if bad:
            self.fail_nonfinite(state)

    def crack(self, state: State, dt: float):
        """Crack-surface particles advance by their own bond forces, gravity and collisions (section 6), and
        meet the material on the grid in an inelastic contact."""
        m = self.model
        crack_contact(state.grid, dt, m.gravity, m.origin, 1.0 / m.dx, state.particle_crack, state.particle_damage,
                      m.particle_mass, m.particle_volume, state.particle_force, state.particle_x, state.particle_v)
        self.crack_vmax, bad = crack_particle_update(dt, state.time + dt, m.colliders, self.valid_lo, self.valid_hi,
                                                     state.particle_crack, state.particle_x, state.particle_v,
                                                     state.particle_C)
        if bad:
            self.fail_nonfinite(state)

    def fracture(self, state: State, dt: float):
        """Eq. 21 criterion, clustering and fracture planes (section 6), then damage and crack-particle flags.

        Particles with a broken bond stop using Fbar (elastic.py), so K^-1 never needs recomputing."""
        m = self.model
        inactive_fraction(state.particle_x, m.origin, 1.0 / m.dx, self.cells, state.bond_start, state.bond_active,
                          state.particle_inactive)
        cut = 0
        for body in self.fracture_bodies:
            start, end = m.body_ranges[body]
            threshold = m.fracture[body].threshold
            if bond_criterion(start, end, threshold, m.fracture[body].damage_resistance, state.particle_x, m.rest_x,
                              state.bond_start, state.bond_nbr, state.bond_active, state.bond_ep,
                              state.particle_inactive, state.particle_lmax, state.particle_bmax):
                cut += fracture_update(threshold, m.body_horizon[body], start, end, state.particle_x, m.rest_x,
                                       state.bond_start, state.bond_nbr, state.bond_active, state.particle_lmax,
                                       state.particle_bmax)
        if cut:
            self.bonds_cut += cut
            damage(state.bond_start, state.bond_active, state.particle_damage, state.particle_crack)

    def substep(self, state: State, dt: float):
        """One explicit step: the Plan's phases in order, each timed."""
        for phase in self.plan.phases:
            t0 = self.clock()
            stage, _, kind = phase.partition(":")
            if kind:
                self.material_phase(state, stage, kind, dt)
            else:
                getattr(self, phase)(state, dt)
            self.phase_time[phase] += self.clock() - t0
        state.step += 1
        state.time += dt
        state.dt_prev = dt

    def advance(self, state: State, t_end: float, on_substep=None):
        """Substep until state.time reaches t_end exactly; the last step is shortened to land on it."""
        while state.time < t_end - 1e-12 * max(1.0, t_end):
            dt = min(self.step_size(), t_end - state.time)
            self.substep(state, dt)
            if on_substep is not None:
                on_substep(state, dt)
        self.check_energy(state)

    # ---- diagnostics
    def kinetic_energy(self, state: State) -> float:
        return kinetic_energy(self.model.particle_mass, state.particle_v)

    def angular_momentum(self, state: State, about) -> np.ndarray:
        """Total angular momentum [kg m^2/s]: particles plus the APIC affine part m_p (dx^2/3) eps_ijk C_kj,
        which APIC transfers conserve together (Jiang et al. 2015)."""
        m = self.model.particle_mass
        r = state.particle_x - np.asarray(about)
        lin = (m[:, None] * np.cross(r, state.particle_v)).sum(axis=0)
        c = np.einsum("p,pkj->kj", m, state.particle_C) * (self.model.dx**2 / 3.0)
        return lin + np.array([c[2, 1] - c[1, 2], c[0, 2] - c[2, 0], c[1, 0] - c[0, 1]])

    def strain_energy(self, state: State) -> float:
        """Total strain energy of all bodies [J] (eq. 5 with the calibration)."""
        self.fbar(state)
        return sum(MATERIALS[b.model].energy(self.model, state, i) for i, b in enumerate(self.plan.bodies))

    def start(self, state: State):
        """Set the energy budget the runaway check measures against [J]: what gravity (over the domain's
        largest extent), the colliders' motion (and the wind's and the pins') and the initial motion can
        legitimately supply; and the speed the first step's CFL bound uses."""
        for i, b in enumerate(self.plan.bodies):
            if MATERIALS[b.model].init is not None:
                MATERIALS[b.model].init(self.model, state, i)
        m = self.model
        extent = float(np.max(np.asarray(self.plan.grid_nodes) - 1) * m.dx)
        v_coll = float(np.abs(m.colliders[:, 10:13]).max()) if len(m.colliders) else 0.0
        v_coll = max(v_coll, float(np.linalg.norm(m.wind_velocity)))  # the wind can bring material to its speed
        v_coll = max(v_coll, pin_speed(m))  # so can a moving pin that drags its body along
        mass = float(m.particle_mass.sum())
        self.energy_budget = self.kinetic_energy(state) + mass * (np.linalg.norm(m.gravity) * extent + v_coll**2)
        self.energy_budget += self.strain_energy(state) + 1e-12 * mass
        self.energy_prev = self.energy_budget
        # The first step's CFL bound sees the initial speeds: a body thrown at 10 dx / dt otherwise moved 10 cells in
        # its first step (stability case impact_floor_10).
        v2 = np.einsum("ij,ij->i", state.particle_v, state.particle_v)
        self.vmax = float(np.sqrt(v2.max())) if len(v2) else 0.0

    def check_energy(self, state: State):
        """Blow-up test, once per frame: kinetic energy may not exceed 10x the larger of the budget and the
        total (kinetic + strain) energy at the previous check. Pins and breaking bonds may legitimately turn
        stored energy into motion; they cannot multiply the total tenfold within one frame."""
        ke = self.kinetic_energy(state)
        limit = RUNAWAY_FACTOR * max(self.energy_budget, self.energy_prev)
        self.energy_prev = ke + self.strain_energy(state)
        if ke > limit:
            fastest = np.argsort(np.einsum("ij,ij->i", state.particle_v, state.particle_v))[-5:][::-1]
            raise SimulationError(
                f"runaway energy after step {state.step} (t = {state.time:.6g} s): kinetic energy {ke:.4g} J exceeds "
                f"{RUNAWAY_FACTOR:g}x the energy of the previous frame or what gravity, colliders and the initial motion "
                f"can supply ({limit:.4g} J); "
                f"fastest particles {fastest.tolist()} at speed "
                f"{np.linalg.norm(state.particle_v[fastest[0]]):.4g} m/s. "
                f"Lower simulation.cfl or simulation.bond_safety (now {self.plan.dt_max:.3g} s max step)"
            )

    def fail_nonfinite(self, state: State):
        bad = np.flatnonzero(~np.isfinite(state.particle_x).all(axis=1) | ~np.isfinite(state.particle_v).all(axis=1))
        raise SimulationError(
            f"NaN or infinite values at step {state.step + 1} (t = {state.time:.6g} s) in {len(bad)} particles "
            f"(first: {bad[:8].tolist()}). The step became unstable: lower simulation.cfl or "
            f"simulation.bond_safety, or set a smaller simulation.dt (max step now {self.plan.dt_max:.3g} s)"
        )

    def fail_outside(self, state: State):
        m = self.model
        nodes = np.asarray(m.grid_shape)
        f = (state.particle_x - m.origin) / m.dx
        bad = np.flatnonzero(~((f >= 1.0) & (f < nodes - 3)).all(axis=1))
        cells_per_step = np.linalg.norm(state.particle_v[bad], axis=1).max() * self.plan.dt_max / m.dx
        hint = (f"they move {cells_per_step:.2g} cells per step, so the step is unstable: lower simulation.cfl or "
                f"simulation.bond_safety, or set a smaller simulation.dt" if cells_per_step > 1.0 else
                "enlarge grid.domain, or check initial velocities and collider motion")
        raise SimulationError(
            f"{len(bad)} particles left the simulation domain at step {state.step + 1} (t = {state.time:.6g} s), "
            f"first {bad[:8].tolist()} at {np.round(state.particle_x[bad[0]], 4).tolist()}; {hint}"
        )
