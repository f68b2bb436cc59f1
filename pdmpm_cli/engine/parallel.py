"""How the particle loops are split over threads, and the floating-point freedom the bond loops get.

Loops over particles run in a fixed number of static chunks, each with its own scratch arrays, so that
nothing is allocated per particle and results do not depend on thread timing (bitwise reproducible for a
given thread count; per-particle results do not depend on the chunk count at all).
"""

from numba import get_num_threads

CHUNKS_PER_THREAD = 4
# Bond loops may reassociate their per-particle sums (and contract them to FMAs) so that they run as SIMD;
# results stay deterministic for a given build. Kernels that use it also set error_model="numpy": Python's
# ZeroDivisionError checks would otherwise keep those loops scalar.
VECTOR_MATH = {"reassoc", "contract", "nsz", "arcp"}


def particle_chunks() -> int:
    """Static particle chunks for a parallel particle loop: a few per thread, for load balance."""
    return CHUNKS_PER_THREAD * get_num_threads()
