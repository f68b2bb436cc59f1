"""CPU backend vs CUDA backend on tiny scenes, step for step. Needs numba.cuda: a GPU, or the simulator
(NUMBA_ENABLE_CUDASIM=1, set before numba is imported; test_cuda.py runs this in a subprocess for that).

    NUMBA_ENABLE_CUDASIM=1 python -m tests.cuda_compare [scene ...]

Both solvers take the same time steps (the CPU's), so any difference is round-off: the GPU's P2G adds with atomics
in another order (and a real GPU fuses multiply-adds). Prints one JSON line per scene: the largest differences of
positions and velocities relative to the body size and the largest speed, and what the scene exercised.
"""

import json
import sys

import numpy as np

from pdmpm_cli.engine.model import State
from pdmpm_cli.engine.solver import Solver
from pdmpm_cli.runner import make_solver, prepare_scene
from pdmpm_cli.scene.schema import Scene

BLOCK = {"mode": "cloud", "sampling": "lattice", "spacing": 0.05,
         "shape": {"type": "box", "center": [0.5, 0.27, 0.5], "size": [0.2, 0.2, 0.2]}}
ELASTIC = {"model": "elastic", "density": 1000.0, "lam": 2e5, "mu": 1e5}


def scene(bodies, colliders=(), gravity=(0.0, -9.81, 0.0), wind=None) -> dict:
    return {**({"wind": wind} if wind else {}), "simulation": {"duration": 1.0, "fps": 10}, "gravity": list(gravity),
            "grid": {"cell_size": 0.05, "domain": {"min": [0, 0, 0], "max": [1, 1, 1]}, "friction": 0.3},
            "bodies": bodies, "colliders": list(colliders)}


SCENES = {
    # 64 particles thrown down at the floor wall (its nodes are within 3 cells of y = 0) with friction
    "elastic_floor": scene([{"name": "block", "geometry": BLOCK, "material": ELASTIC, "velocity": [0.5, -8.0, 0.0],
                             "angular_velocity": [0.0, 0.0, 2.0]}]),
    # a soft-yielding slab squashed on the floor: most bonds yield (bond_ep, theta, the return map)
    "plastic_slab": scene([{"name": "slab", "geometry": {**BLOCK, "shape": {"type": "box", "center": [0.5, 0.22, 0.5],
                                                                              "size": [0.3, 0.1, 0.2]}},
                            "material": {"model": "plastic", "density": 1000.0, "lam": 2e5, "mu": 1e5,
                                         "yield_stress": 1e3},
                            "velocity": [0.0, -8.0, 0.0]}]),
    # a pinned bar (one end held, moving; the other held by a pin that stops within the third step, ~0.7 ms
    # each) in the wind, hit by a moving sphere collider; mu = 0 leaves out Fbar
    "collider_pins": scene([{"name": "bar", "geometry": {**BLOCK, "shape": {"type": "box", "center": [0.5, 0.5, 0.5],
                                                                             "size": [0.4, 0.1, 0.1]}},
                             "material": {"model": "elastic", "density": 500.0, "lam": 3e5, "mu": 0.0},
                             "pins": [{"region": {"type": "box", "center": [0.33, 0.5, 0.5], "size": [0.1, 0.2, 0.2]},
                                       "velocity": [0.0, 0.2, 0.0]},
                                      {"region": {"type": "box", "center": [0.68, 0.5, 0.5], "size": [0.06, 0.2, 0.2]},
                                       "velocity": [0.0, 0.0, 0.3], "stop": 0.0018}]}],
                           colliders=[{"type": "sphere", "center": [0.6, 0.68, 0.5], "radius": 0.12,
                                       "velocity": [0.0, -1.5, 0.0], "boundary": "slip", "friction": 0.2},
                                      {"type": "plane", "point": [0, 0.42, 0], "normal": [0, 1, 0],
                                       "boundary": "sticky"}],
                           wind={"velocity": [2.0, 0.0, 1.0], "drag": 5.0}),
}


def compare(name: str, steps: int) -> dict:
    """Run `steps` CPU steps and the same steps on the CUDA backend; the largest relative differences."""
    base = SCENES[name]
    prep_cpu = prepare_scene(Scene.model_validate(base), "cpu.yaml")
    prep_gpu = prepare_scene(Scene.model_validate({**base, "simulation": {**base["simulation"], "backend": "cuda"}}),
                             "gpu.yaml")
    states, solvers = [], []
    for prep in (prep_cpu, prep_gpu):
        states.append(State.allocate(prep.model, prep.disc, prep.plan.fields))
        solvers.append(make_solver(prep.model, prep.plan))
        solvers[-1].start(states[-1])
    cpu, gpu = solvers
    assert type(cpu) is Solver and type(gpu) is not Solver
    mass = prep_cpu.model.particle_mass
    p0 = mass @ states[0].particle_v
    for _ in range(steps):
        dt = cpu.step_size()
        for solver, state in zip(solvers, states):
            solver.substep(state, dt)
    gpu.check_energy(states[1])  # syncs the host State, as a frame does
    cpu.check_energy(states[0])
    a, b = states
    size = np.ptp(a.particle_x, axis=0).max()
    speed = np.abs(a.particle_v).max()
    out = {"scene": name, "particles": len(a.particle_x), "bonds": int(a.bond_start[-1]), "steps": steps,
           "phases": list(prep_gpu.plan.phases), "x_rel": float(np.abs(a.particle_x - b.particle_x).max() / size),
           "v_rel": float(np.abs(a.particle_v - b.particle_v).max() / speed),
           "c_rel": float(np.abs(a.particle_C - b.particle_C).max() * prep_cpu.model.dx / speed),
           "displacement": float(np.abs(a.particle_x - prep_cpu.model.rest_x).max() / size),
           # what walls, colliders and pins did: momentum change beyond gravity's, relative to M |v|max
           "external_impulse": float(np.linalg.norm(mass @ a.particle_v - p0 - mass.sum() * a.time
                                                    * prep_cpu.model.gravity) / (mass.sum() * speed)),
           "vmax": [cpu.vmax, gpu.vmax], "energy": [cpu.energy_prev, gpu.energy_prev]}
    if len(a.bond_ep):
        out["yielded"] = float(np.mean(a.bond_ep != 0))
        out["ep_rel"] = float(np.abs(a.bond_ep - b.bond_ep).max() / np.abs(a.bond_ep).max())
        out["yield_residual"] = [cpu.yield_residual, gpu.yield_residual]
    pins = prep_cpu.model.pin_mask.astype(bool)
    if pins.any():
        out["pinned"] = int(pins.sum())
        stopped = prep_cpu.model.pin_stop < a.time
        out["pin_stopped"] = int((pins & stopped).sum())
        held = np.where(stopped[:, None], 0.0, prep_cpu.model.pin_velocity)  # at rest once a pin has stopped
        out["pin_v_err"] = float(np.abs(b.particle_v[pins] - held[pins]).max())
    return out


def main(argv):
    steps = 6
    for name in argv or SCENES:
        print(json.dumps(compare(name, steps)), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
