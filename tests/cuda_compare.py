"""CPU backend vs CUDA backend, step for step. Needs numba.cuda: a GPU, or the simulator (NUMBA_ENABLE_CUDASIM=1,
set before numba is imported; test_cuda.py runs this in a subprocess for that).

    NUMBA_ENABLE_CUDASIM=1 python -m tests.cuda_compare [--steps N] [--precision float32] [name ...]

The cases are every bundled scene (scenes/*.yaml) at a tiny resolution, and small synthetic scenes that push
walls, colliders, pins, wind, plasticity and contact between bodies. Both solvers take the same time steps (the CPU's), so any difference is
round-off: the GPU's P2G adds with atomics in another order (and a real GPU fuses multiply-adds). Prints one JSON
line per case: the largest differences of positions, velocities and APIC matrices relative to the body size and the
largest speed, of every other State array relative to its largest value, and what the case exercised.
"""

import functools
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from pdmpm_cli.engine.solver import Solver, initial_state
from pdmpm_cli.runner import Prepared, prepare, prepare_scene
from pdmpm_cli.scene.schema import Scene
from tests.mesh_corpus import icosphere, write_off

ROOT = Path(__file__).resolve().parents[1]
BLOCK = {"mode": "cloud", "sampling": "lattice", "spacing": 0.05,
         "shape": {"type": "box", "center": [0.5, 0.27, 0.5], "size": [0.2, 0.2, 0.2]}}
ELASTIC = {"model": "elastic", "density": 1000.0, "lam": 2e5, "mu": 1e5}


def scene(bodies, colliders=(), gravity=(0.0, -9.81, 0.0), wind=None) -> dict:
    return {**({"wind": wind} if wind else {}), "simulation": {"duration": 1.0, "fps": 10}, "gravity": list(gravity),
            "grid": {"cell_size": 0.05, "domain": {"min": [0, 0, 0], "max": [1, 1, 1]}, "friction": 0.3},
            "bodies": bodies, "colliders": list(colliders)}


SYNTHETIC = {
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
    # a viscoelastic slab splatting on the floor: its bonds break and its families are rebuilt within the steps
    "viscous_splat": scene([{"name": "dough", "geometry": {**BLOCK, "shape": {"type": "box", "center": [0.5, 0.2, 0.5],
                                                                               "size": [0.3, 0.1, 0.2]}},
                             "material": {"model": "viscoelastic", "density": 1000.0, "lam": 2e5, "mu": 1e5,
                                          "relaxation_time": 0.002, "relaxing_fraction": 0.8, "break_stretch": 0.005,
                                          "rebuild_distance": 0.05, "bulk_modulus": 3e5},  # rebuilds in 6 steps
                             "velocity": [0.0, -20.0, 0.0]}]),
    # a liquid block (the whole shear relaxing) on a jittered lattice, so that neighbours closer than the spacing
    # are shifted apart from the first step (shift:viscoelastic), falling onto the floor
    "liquid_shift": scene([{"name": "liquid", "geometry": {**BLOCK, "sampling": "jittered",
                                                           "shape": {"type": "box", "center": [0.5, 0.3, 0.5],
                                                                     "size": [0.3, 0.15, 0.2]}},
                            "material": {"model": "viscoelastic", "density": 1000.0, "lam": 0.0, "mu": 1e4,
                                         "relaxation_time": 0.002, "relaxing_fraction": 1.0, "bulk_modulus": 3e5},
                            "velocity": [0.0, -5.0, 0.0]}]),
    # two blocks meeting edge-on, one per grid field: the projection contact with friction 0.4 where they meet, free
    # elsewhere
    "two_bodies": {**scene([{"name": "left",
                             "geometry": {**BLOCK, "shape": {**BLOCK["shape"], "center": [0.37, 0.5, 0.5]}},
                             "material": ELASTIC, "velocity": [3.0, 0.5, 0.0]},
                            {"name": "right",
                             "geometry": {**BLOCK, "shape": {**BLOCK["shape"], "center": [0.6, 0.55, 0.5]}},
                             "material": ELASTIC, "velocity": [-3.0, 0.0, 0.0]}]),
                   "contact": {"model": "projection", "friction": 0.1,
                               "pairs": [{"bodies": ["left", "right"], "friction": 0.4}]}},
    # a block thrown at a moving mesh collider (a closed icosphere file, its signed distance sampled on a lattice)
    "mesh_collider": scene([{"name": "block", "geometry": BLOCK, "material": ELASTIC, "velocity": [0.0, 6.0, 0.0]}],
                           colliders=[{"type": "mesh", "path": "ball.off", "translate": [0.52, 0.5, 0.5],
                                       "velocity": [0.0, -1.0, 0.0], "boundary": "slip", "friction": 0.3}]),
    # a block thrown down and along at a separate plane: the penalty response (response auto with APIC) pushes the
    # particles that touch it, with friction
    "penalty_floor": scene([{"name": "block", "geometry": BLOCK, "material": ELASTIC, "velocity": [1.0, -6.0, 0.0]}],
                           colliders=[{"type": "plane", "point": [0, 0.165, 0], "normal": [0, 1, 0],
                                       "boundary": "separate", "friction": 0.3}]),
}
# The FLIP share with MUSL's position pass (simulation.flip): the pinned bar among colliders in the wind, and the
# two bodies in contact (the remap's contact pass)
SYNTHETIC["flip_pins"] = {**SYNTHETIC["collider_pins"], "simulation": {"duration": 1.0, "fps": 10, "flip": 0.95}}
SYNTHETIC["flip_contact"] = {**SYNTHETIC["two_bodies"], "simulation": {"duration": 1.0, "fps": 10, "flip": 0.95}}
# the two bodies, closer, with the penalty contact (contact.model penalty), which starts nearer the touch
SYNTHETIC["penalty_contact"] = {**SYNTHETIC["two_bodies"],
                                "contact": {**SYNTHETIC["two_bodies"]["contact"], "model": "penalty"}}
SYNTHETIC["penalty_contact"]["bodies"] = [
    SYNTHETIC["two_bodies"]["bodies"][0],
    {**SYNTHETIC["two_bodies"]["bodies"][1],
     "geometry": {**BLOCK, "shape": {**BLOCK["shape"], "center": [0.56, 0.55, 0.5]}}}]

# Every bundled scene at a tiny resolution: its materials, geometry modes, pins, colliders and fracture as shipped.
SHELL = ("grid.cell_size=0.05", "bodies.0.geometry.spacing=0.05", "bodies.0.geometry.layers=1",
         "bodies.1.geometry.spacing=0.05")
BUNDLED = {
    "elastic_drop": ("grid.cell_size=0.075", "bodies.0.geometry.spacing=0.075"),
    "cloth": ("grid.cell_size=0.025", "bodies.0.geometry.spacing=0.025"),
    "cloth_pegs": ("bodies.0.geometry.spacing=0.025",),
    "board_elastic": SHELL,
    "board_plastic": SHELL,
    "bunnies_elastic": ("grid.cell_size=0.03", "bodies.0.geometry.spacing=0.03", "bodies.1.geometry.spacing=0.03"),
    "bunnies_plastic": ("grid.cell_size=0.03", "bodies.0.geometry.spacing=0.03", "bodies.1.geometry.spacing=0.03"),
    # thrown at 4x its speed so that bonds break within the few steps compared
    "wall_break": ("grid.cell_size=0.04", "bodies.0.geometry.spacing=0.04", "bodies.1.geometry.spacing=0.04",
                   "bodies.1.velocity=[24.0,0.0,0.0]", "bodies.0.fracture.threshold=0.0005",
                   "bodies.1.geometry.shape.center=[0.37,0.4,0.45]",  # touching the wall: contact from the start
                   # a field per body, the projection: crack particles meet the other body's field (the GPU runs
                   # contact.cracks shared: off-grid crack particles)
                   "contact.mode=separate", "contact.model=projection", "contact.cracks=shared"),
    "beams": ("grid.cell_size=0.075", *(f"bodies.{i}.geometry.spacing=0.075" for i in range(3)),
              *(f"bodies.{i}.geometry.layers=1" for i in range(3))),
    # the stream as a falling column: the emitter runs on the CPU only
    "honey": ("grid.cell_size=0.1", "bodies.0.geometry.spacing=0.08", "bodies.0.emitter=null",
              "bodies.0.geometry.shape.height=1.6", "bodies.0.geometry.shape.center=[1.0,1.6,1.0]"),
    "cream_pie": ("grid.cell_size=0.06", "bodies.0.geometry.spacing=0.06"),
}
CASES = [*SYNTHETIC, *BUNDLED]


@functools.cache
def mesh_folder() -> Path:
    """A scratch folder holding the synthetic cases' mesh files (relative paths resolve there)."""
    folder = Path(tempfile.mkdtemp(prefix="pdmpm-cuda-compare-"))
    write_off(folder / "ball.off", *icosphere(2, 0.12))
    return folder


def prepared(name: str, backend: str, precision: str = "float64") -> Prepared:
    """A case by name, or a scene file given by its path, at that simulation.precision."""
    sets = [f"simulation.backend={backend}", f"simulation.precision={precision}"]
    if name.endswith(".yaml"):
        return prepare(name, sets)
    if name in SYNTHETIC:
        base = SYNTHETIC[name]
        simulation = {**base["simulation"], "backend": backend, "precision": precision}
        return prepare_scene(Scene.model_validate({**base, "simulation": simulation}),
                             mesh_folder() / f"{backend}.yaml")
    return prepare(ROOT / "scenes" / f"{name}.yaml", [*BUNDLED[name], *sets])


def compare(name: str, steps: int, precision: str = "float64") -> dict:
    """Run `steps` CPU steps and the same steps on the CUDA backend; the largest relative differences."""
    preps = [prepared(name, b, precision) for b in ("cpu", "cuda")]
    states, solvers = [], []
    for prep in preps:
        states.append(initial_state(prep.model, prep.plan, prep.disc.velocity, prep.disc.velocity_gradient))
        solvers.append(Solver(prep.model, prep.plan))
        solvers[-1].start(states[-1])
    cpu, gpu = solvers
    assert cpu.backend.name == "cpu" and gpu.backend.name == "cuda"
    model = preps[0].model
    mass = model.particle_mass
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
    others = {}
    for key, array in a.lasting().items():
        if key in ("particle_x", "particle_v", "particle_C") or array.dtype.kind not in "fiu":
            continue
        other = b.arrays[key]
        if other.shape != array.shape:
            others[key] = float("inf")
            continue
        scale = float(np.abs(array).max()) or 1.0
        others[key] = float(np.abs(array.astype(float) - other.astype(float)).max() / scale)
    out = {"case": name, "particles": len(a.particle_x), "bonds": int(a.bond_start[-1]), "steps": steps,
           "phases": list(preps[1].plan.phases), "x_rel": float(np.abs(a.particle_x - b.particle_x).max() / size),
           "v_rel": float(np.abs(a.particle_v - b.particle_v).max() / speed),
           "c_rel": float(np.abs(a.particle_C - b.particle_C).max() * model.dx / speed),
           "arrays_rel": others,
           "displacement": float(np.abs(a.particle_x - model.rest_x).max() / size),
           # what walls, colliders and pins did: momentum change beyond gravity's, relative to M |v|max
           "external_impulse": float(np.linalg.norm(mass @ a.particle_v - p0 - mass.sum() * a.time
                                                    * model.gravity) / (mass.sum() * speed)),
           "vmax": [a.vmax, b.vmax], "energy": [a.energy_prev, b.energy_prev],
           "scalars": [{k: v for k, v in s.scalars.items() if k != "energy_budget"} for s in states]}
    if a.has("bond_ep"):
        out["yielded"] = float(np.mean(a.bond_ep != 0))
        out["yield_residual"] = [a.yield_residual, b.yield_residual]
    if a.has("bond_active"):
        out["broken"] = int((a.bond_active == 0).sum())
        out["crack_particles"] = int(a.particle_crack.sum())
    if a.has("particle_shift"):  # the last step's particle shift, in cells
        out["shifted"] = float(np.abs(a.particle_shift).max() / model.dx)
    if a.has("bond_len0"):
        out["rebuilt"] = bool(np.any(a.particle_x_rebuild != model.rest_x))
        out["broken"] = int((a.bond_len0 < 0).sum())
    if preps[0].plan.contact:  # x momentum the first body gave the others (gravity acts along y only)
        b0 = model.bodies[0]
        m0 = mass[b0.start:b0.end]
        mv = m0 @ (states[0].particle_v[b0.start:b0.end] - preps[0].disc.velocity[b0.start:b0.end])
        out["exchanged"] = float(abs(mv[0]) / (m0.sum() * speed))
    pins = model.pin_mask.astype(bool)
    if pins.any():
        out["pinned"] = int(pins.sum())
        stopped = model.pin_stop < a.time
        out["pin_stopped"] = int((pins & stopped).sum())
        held = np.where(stopped[:, None], 0.0, model.pin_velocity)  # at rest once a pin has stopped
        out["pin_v_err"] = float(np.abs(b.particle_v[pins] - held[pins]).max())
    return out


def main(argv):
    steps, precision = 6, "float64"
    while argv[:1] in (["--steps"], ["--precision"]):
        if argv[0] == "--steps":
            steps = int(argv[1])
        else:
            precision = argv[1]
        argv = argv[2:]
    for name in argv or CASES:
        print(json.dumps(compare(name, steps, precision)), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
