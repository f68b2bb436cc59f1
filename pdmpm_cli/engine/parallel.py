"""How the particle loops are split over threads, and why the bond loops get no floating-point freedom.

Loops over particles run in a fixed number of static chunks, each with its own scratch arrays, so that
nothing is allocated per particle and results do not depend on thread timing (bitwise reproducible for a
given thread count; per-particle results do not depend on the chunk count at all).
"""

from numba import get_num_threads

CHUNKS_PER_THREAD = 4
SCRATCH_CHUNKS = 64  # static chunks of a Kernel's CPU loop (which takes no chunk count) that needs scratch arrays
# No fastmath on the bond loops: with reassociation and FMA contraction a kernel compiled in a process and the same
# kernel loaded from Numba's disk cache gave different last bits (a run and its --resume then differed), for about
# 2 % of the step's time. Kernels with float divisions set error_model="numpy" so that Python's ZeroDivisionError
# checks do not keep their loops scalar.


def particle_chunks() -> int:
    """Static particle chunks for a parallel particle loop: a few per thread, for load balance."""
    return CHUNKS_PER_THREAD * get_num_threads()
