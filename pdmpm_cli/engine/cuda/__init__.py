"""CUDA backend (numba.cuda). Only `runner.make_solver` imports it, and only for `simulation.backend: cuda`, so a
machine without a GPU or without numba.cuda never loads any of it."""

from pdmpm_cli.errors import InputError


def cuda_solver(model, plan):
    """A CudaSolver for the run, or InputError (exit 2) when numba.cuda has no usable GPU and no simulator."""
    import numpy as np

    if not hasattr(np, "row_stack"):
        np.row_stack = np.vstack  # numba-cuda 0.30 still calls np.row_stack, which numpy 2.5 removed
    try:
        from numba import cuda
    except ImportError as e:
        raise InputError(f"simulation.backend = cuda: numba.cuda cannot be imported ({e}); install numba-cuda, "
                         f"or run with --backend cpu") from e
    if not cuda.is_available():
        raise InputError("simulation.backend = cuda needs an NVIDIA GPU with a working CUDA driver, and numba.cuda "
                         "finds none; run with --backend cpu (or set NUMBA_ENABLE_CUDASIM=1 to run the CUDA kernels "
                         "on numba's simulator, for testing only: it is very slow)")
    from pdmpm_cli.engine.cuda.solver import CudaSolver

    return CudaSolver(model, plan)
