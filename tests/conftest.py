"""Shared helpers: build scenes in code and run them without touching the disk."""

import os

# Under pytest-xdist (`-n auto --dist loadfile`) the workers share the cores: each gets its share of Numba's
# threads, set before Numba is imported so that its thread pool, its private grids and the pdmpm processes a test
# starts (which inherit the variable) all agree: a run compared bitwise with an in-process reference takes the
# reference's thread count, hence its sums.
WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
if WORKERS > 1 and "NUMBA_NUM_THREADS" not in os.environ:
    os.environ["NUMBA_NUM_THREADS"] = str(max(1, (os.cpu_count() or 1) // WORKERS))

import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402

import pytest  # noqa: E402

from pdmpm_cli.scene.loader import merge  # noqa: E402
from pdmpm_cli.study.sim import Sim  # noqa: E402

BASE = {
    "simulation": {"duration": 1.0, "fps": 10},
    "grid": {"cell_size": 0.05, "domain": {"min": [0, 0, 0], "max": [1, 1, 1]}},
    "gravity": [0, 0, 0],
    "bodies": [{
        "name": "cube",
        "geometry": {"mode": "cloud", "shape": {"type": "box", "center": [0.5, 0.5, 0.5], "size": [0.3, 0.3, 0.3]},
                     "sampling": "lattice"},
        "material": {"model": "elastic", "density": 1000.0, "lam": 1e5, "mu": 1e5},
    }],
}


@pytest.fixture
def sim_factory(tmp_path):
    return lambda changes=None, base=BASE: Sim(merge(base, changes or {}), tmp_path / "scene.yaml")


def cuda_compare_commands():
    """The two `tests.cuda_compare` runs test_cuda.py checks: the synthetic cases over 6 steps (so that the block
    meets the floor and the slab yields), the bundled scenes over 2."""
    from tests.cuda_compare import BUNDLED, SYNTHETIC

    return [[sys.executable, "-m", "tests.cuda_compare", "--steps", str(steps), *cases]
            for steps, cases in ((6, SYNTHETIC), (2, BUNDLED))]


class CudaCompare:
    """The CUDA simulator comparisons running in the background; `rows()` waits for them. They run at a lower
    priority (nice 10), so that they take the cores the rest of the suite leaves idle rather than slowing it.
    Output goes to temporary files, not pipes: a full pipe would stall a process nobody reads until the end."""

    def __init__(self):
        env = dict(os.environ, COLUMNS="200", NUMBA_ENABLE_CUDASIM="1")
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        self.runs = []
        for cmd in cuda_compare_commands():
            out, err = tempfile.TemporaryFile("w+"), tempfile.TemporaryFile("w+")
            self.runs.append((subprocess.Popen(cmd, stdout=out, stderr=err, text=True, cwd=root, env=env,
                                               preexec_fn=(lambda: os.nice(10)) if os.name == "posix" else None),
                              out, err))

    def rows(self, timeout: float = 1800) -> list[str]:
        """The JSON lines the runs printed; raises AssertionError with the end of stderr if one failed."""
        lines = []
        for proc, out, err in self.runs:
            proc.wait(timeout)
            out.seek(0)
            err.seek(0)
            assert proc.returncode == 0, err.read()[-3000:]
            lines += out.read().splitlines()
        return lines

    def stop(self):
        for proc, out, err in self.runs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            out.close()
            err.close()


def pytest_collection_modifyitems(session, config, items):
    """The CUDA simulator runs kernels as Python threads: its comparisons take minutes of one core each, while
    most of the suite is single-threaded Python and Numba compilation. In a plain (not xdist) run they start in
    the background as soon as the tests are collected, and test_cuda.py's tests move to the end of the run, so
    that the wait overlaps the rest of the suite."""
    if WORKERS > 1 or not any(item.nodeid.startswith("tests/test_cuda.py") and "compared" in item.fixturenames
                              for item in items):
        return
    items.sort(key=lambda item: item.nodeid.startswith("tests/test_cuda.py"))  # stable: the order otherwise kept
    config.stash[CUDA_COMPARE] = CudaCompare()


CUDA_COMPARE = pytest.StashKey[CudaCompare]()


def pytest_unconfigure(config):
    """A run that ends early (-x, Ctrl-C) leaves no simulator process behind."""
    if CUDA_COMPARE in config.stash:
        config.stash[CUDA_COMPARE].stop()
