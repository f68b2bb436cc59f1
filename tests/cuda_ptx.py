"""Compile every kernel the CUDA backend launches to PTX for an H100 (sm_90), with the argument types of real runs,
on a machine without a GPU. The simulator runs the kernels as Python and cannot tell what the CUDA target
rejects (np.floor, the builtin max in numba 0.68); this needs only NVVM (the CUDA toolkit), not a driver.

    NUMBA_ENABLE_CUDASIM=0 python -m tests.cuda_ptx [--precision float32]    (exit 3 when NVVM is missing)

The backend runs one step of each tests.cuda_compare synthetic case and of the tiny fracture and viscoelastic
scenes, with host arrays standing in for device arrays and a `launch` that records kernels and argument types
instead of launching; a few particles are made crack particles so that the crack kernels launch too. Then each
recorded kernel is compiled.
"""

import sys
import types

import numpy as np

if not hasattr(np, "row_stack"):
    np.row_stack = np.vstack  # numba-cuda 0.30 still calls np.row_stack, which numpy 2.5 removed

import numba  # noqa: E402
from numba import cuda  # noqa: E402
from numba.cuda import dispatcher  # noqa: E402
from numba.cuda.cudadrv import nvvm  # noqa: E402

from pdmpm_cli.engine.backends import cuda as backend  # noqa: E402
from pdmpm_cli.engine.solver import Solver, initial_state  # noqa: E402
from tests.cuda_compare import SYNTHETIC, prepared  # noqa: E402

CC = (9, 0)
CASES = [*SYNTHETIC, "wall_break", "honey"]


class HostArray(np.ndarray):
    """A numpy array with the device-array methods the backend calls."""

    def copy_to_host(self, out=None):
        if out is None:
            return np.array(self)
        out[...] = self
        return out

    def copy_to_device(self, a):
        self[...] = a


def launched_kernels(precision: str = "float64") -> dict:
    """{(kernel name, argument types): kernel} over one step of every case at that simulation.precision."""
    seen = {}

    def record(kernel, n, *args):
        sig = tuple(numba.typeof(np.asarray(a) if isinstance(a, np.ndarray) else a) for a in args)
        seen.setdefault((kernel.py_func.__name__, sig), kernel)

    cuda.to_device = lambda a: np.array(a).view(HostArray)
    backend.launch = record
    backend.device_name = lambda: "none"
    # device functions are compiled for the current device's compute capability: name one instead
    dispatcher.get_current_device = lambda: types.SimpleNamespace(compute_capability=CC)
    for name in CASES:
        prep = prepared(name, "cuda", precision)
        state = initial_state(prep.model, prep.plan, prep.disc.velocity, prep.disc.velocity_gradient)
        if state.has("particle_crack"):
            state.particle_crack[:3] = 1
            state.particle_damage[:3] = 1.0
        solver = Solver(prep.model, prep.plan, backend=backend.CudaBackend())
        solver.start(state)
        solver.substep(state, prep.plan.dt_max)
    return seen


def main():
    if not nvvm.is_available():
        print("NVVM (the CUDA toolkit's compiler library) is not available", file=sys.stderr)
        sys.exit(3)
    precision = sys.argv[2] if sys.argv[1:2] == ["--precision"] else "float64"
    for (name, sig), kernel in sorted(launched_kernels(precision).items(), key=lambda item: item[0][0]):
        ptx, _ = cuda.compile_ptx(kernel.py_func, sig, cc=CC)
        print(f"{name}: {len(ptx)} characters of PTX")


if __name__ == "__main__":
    main()
