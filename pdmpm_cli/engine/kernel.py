"""A per-item formula paired with its CPU loop: how every phase is written once for both backends."""

from dataclasses import dataclass
from typing import Callable

from numba import njit, prange


@dataclass(frozen=True)
class Kernel:
    """A per-item formula and its CPU loop, so both backends run the same per-particle (or per-node) math.

    `fn(i, *args, *scratch)` handles item i; `cpu(start, end, *args)` is its CPU loop (a parallel @njit loop, or
    a Python function calling several). The CUDA backend compiles `fn` for the GPU and runs one thread per item,
    with `scratch` ((name, length) pairs) as per-thread local arrays. `reduce` ('max' or 'sum') combines fn's
    return values; `cpu` returns the same reduction."""

    fn: Callable
    cpu: Callable
    scratch: tuple[tuple[str, int], ...] = ()
    reduce: str | None = None


@njit(cache=True)
def copy_row_at(p, src, dst):
    """dst[p] = src[p] for a (n, 3) array."""
    for a in range(3):
        dst[p, a] = src[p, a]


@njit(parallel=True, cache=True)
def copy_rows(start, end, src, dst):
    """`copy_row_at` for rows start..end-1."""
    for p in prange(start, end):
        copy_row_at(p, src, dst)


COPY_ROWS = Kernel(copy_row_at, copy_rows)
