"""Compile every kernel the CudaSolver launches to PTX for an H100 (sm_90), with the argument types of real runs,
on a machine without a GPU. The simulator runs the kernels as Python and cannot tell what the CUDA target
rejects (np.floor, the builtin max in numba 0.68); this needs only NVVM (the CUDA toolkit), not a driver.

    NUMBA_ENABLE_CUDASIM=0 python -m tests.cuda_ptx     (exit 3 when NVVM is missing)

The solver runs one step of each tests.cuda_compare scene with host arrays standing in for device arrays and a
`launch` that records kernels and argument types instead of launching; then each is compiled.
"""

import sys
import types

import numba
import numpy as np
from numba import cuda
from numba.cuda import dispatcher
from numba.cuda.cudadrv import nvvm

from pdmpm_cli.engine.cuda import solver as cuda_solver
from pdmpm_cli.engine.model import State
from pdmpm_cli.runner import prepare_scene
from pdmpm_cli.scene.schema import Scene
from tests.cuda_compare import SCENES

CC = (9, 0)


class HostArray(np.ndarray):
    """A numpy array with the one device-array method the solver calls."""

    def copy_to_host(self, out):
        out[...] = self
        return out


def launched_kernels() -> dict:
    """{(kernel name, argument types): kernel} over one step of every comparison scene."""
    seen = {}

    def record(kernel, n, *args):
        sig = tuple(numba.typeof(np.asarray(a) if isinstance(a, np.ndarray) else a) for a in args)
        seen.setdefault((kernel.py_func.__name__, sig), kernel)

    cuda.to_device = lambda a: np.array(a).view(HostArray)
    cuda.device_array = lambda shape: np.zeros(shape).view(HostArray)
    cuda_solver.launch = record
    cuda_solver.device_name = lambda: "none"
    # device functions are compiled for the current device's compute capability: name one instead
    dispatcher.get_current_device = lambda: types.SimpleNamespace(compute_capability=CC)
    for base in SCENES.values():
        scene = Scene.model_validate({**base, "simulation": {**base["simulation"], "backend": "cuda"}})
        prep = prepare_scene(scene, "ptx.yaml")
        state = State.allocate(prep.model, prep.disc, prep.plan.fields)
        solver = cuda_solver.CudaSolver(prep.model, prep.plan)
        solver.start(state)
        solver.substep(state, prep.plan.dt_max)
    return seen


def main():
    if not nvvm.is_available():
        print("NVVM (the CUDA toolkit's compiler library) is not available", file=sys.stderr)
        sys.exit(3)
    for (name, sig), kernel in sorted(launched_kernels().items(), key=lambda item: item[0][0]):
        ptx, _ = cuda.compile_ptx(kernel.py_func, sig, cc=CC)
        print(f"{name}: {len(ptx)} characters of PTX")


if __name__ == "__main__":
    main()
