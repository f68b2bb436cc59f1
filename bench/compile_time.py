"""Numba compile time of one pdmpm command, per jitted function, from numba's compile events.

Usage: python bench/compile_time.py run scenes/elastic_drop.yaml --out outputs/compile --overwrite --quiet
Runs the pdmpm CLI in this process and prints the wall and process CPU time, then the functions that took longest
to compile (wall seconds; a function compiled inside another's compile counts in both). Run it in a fresh clone
(or after deleting the __pycache__ folders) for a cold start, and again for the warm one: the difference of the
CPU times is what the first run pays to compile.
"""

import sys
import time
from collections import defaultdict

from numba.core import event


class CompileTimes(event.Listener):
    """Sums the duration of every numba:compile event per function."""

    def __init__(self):
        self.started = {}
        self.totals = defaultdict(float)

    def on_start(self, ev):
        self.started[id(ev.data["dispatcher"]), str(ev.data["args"])] = time.perf_counter()

    def on_end(self, ev):
        key = (id(ev.data["dispatcher"]), str(ev.data["args"]))
        if key in self.started:
            fn = ev.data["dispatcher"].py_func
            self.totals[f"{fn.__module__}.{fn.__name__}"] += time.perf_counter() - self.started.pop(key)


def main():
    listener = CompileTimes()
    event.register("numba:compile", listener)
    wall, cpu = time.perf_counter(), time.process_time()
    sys.argv = ["pdmpm", *sys.argv[1:]]
    try:
        from pdmpm_cli.cli.app import main as pdmpm

        pdmpm()
    except SystemExit:
        pass
    print(f"wall {time.perf_counter() - wall:.1f} s, process CPU {time.process_time() - cpu:.1f} s")
    for name, seconds in sorted(listener.totals.items(), key=lambda kv: -kv[1])[:30]:
        print(f"{seconds:8.2f} s  {name}")


if __name__ == "__main__":
    main()
