"""Time and peak memory of `pdmpm validate` (and `pdmpm run` for the output-folder cases) on hostile inputs.

Usage: python bench/hostile_inputs.py [--markdown]
Each case is written to a scratch folder and run as its own process; the peak resident memory is that process's
own (os.wait4). Prints one row per case: exit code, wall seconds, peak MiB and the message's first 110 characters.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASE = (ROOT / "scenes" / "elastic_drop.yaml").read_text()  # the quick start, as a valid starting point


def laughs(levels: int) -> str:
    lines = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, levels)]
    return BASE + "variants:\n  boom:\n" + "".join(f"    {line}\n" for line in lines)


def cases(folder: Path) -> list[tuple[str, list[str]]]:
    """(name, pdmpm arguments) of every case, with its files written to `folder`."""
    files = {
        "billion laughs, 6 levels": laughs(6),
        "billion laughs, 9 levels": laughs(9),
        "3.7e7 particles (spacing 0.9 mm)": BASE.replace("mode: cloud\n", "mode: cloud\n      spacing: 0.0009\n"),
        "lam: .inf": BASE.replace("lam: 2.0e4", "lam: .inf"),
        "gravity: [0, .nan, 0]": BASE.replace("gravity: [0.0, -9.81, 0.0]", "gravity: [0, .nan, 0]"),
        "velocity: [.inf, 0, 0]": BASE.replace("velocity: [0.0, 0.0, 0.0]", "velocity: [.inf, 0, 0]"),
        "duration: .inf": BASE.replace("duration: 1.5", "duration: .inf"),
        "NaN shape centre": BASE.replace("center: [0.55, 0.75, 0.6]", "center: [.nan, 0.75, 0.6]"),
        "fps: 1e9": BASE.replace("fps: 24", "fps: 1e9"),
        "nested 600 levels (flow)": BASE + "variants:\n  x: " + "[" * 600 + "]" * 600 + "\n",
        "nested 600 levels (block)": BASE + "notes:\n" + "".join(" " * (i + 1) + "-\n" for i in range(600)),
        "40,000 unknown keys": BASE + "".join(f"k{i}: {i}\n" for i in range(40_000)),
        "700,000 unknown keys": BASE + "".join(f"k{i}: {i}\n" for i in range(700_000)),
        "spacing 0.08 m > cell 0.05 m": BASE.replace("mode: cloud\n", "mode: cloud\n      spacing: 0.08\n"),
        "camera position = focus": BASE + "render:\n  camera: {position: [1, 1, 1], focus: [1, 1, 1]}\n",
        "good scene (for comparison)": BASE,
    }
    out = []
    for k, (name, text) in enumerate(files.items()):
        path = folder / f"case{k}.yaml"
        path.write_text(text)
        out.append((name, ["validate", str(path)]))
    good = str(folder / f"case{len(files) - 1}.yaml")
    (folder / "afile").write_text("x")
    out += [("variant 'sofft'", ["validate", str(ROOT / "scenes" / "cloth.yaml"), "--variant", "sofft"]),
            ("run --out an existing file", ["run", good, "--out", str(folder / "afile")]),
            ("run --out under a file", ["run", good, "--out", str(folder / "afile" / "out")])]
    return out


def measure(args: list[str]) -> tuple[int, float, float, str]:
    """(exit code, wall seconds, peak MiB, first line of stderr) of `pdmpm ARGS` in its own process."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), COLUMNS="400")
    with tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "pdmpm_cli", *args], cwd=ROOT, env=env,
                                stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        lines = err.read().decode("utf-8", "replace").splitlines() or [""]
    return proc.returncode, seconds, usage.ru_maxrss / 1024, lines[0][:110]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table (docs/results.md)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        rows = [(name, *measure(argv)) for name, argv in cases(Path(scratch))]
        rows = [(name, code, seconds, mib, message.replace(scratch + "/", "").replace(f"{ROOT}/", ""))
                for name, code, seconds, mib, message in rows]
    if args.markdown:
        print("| case | exit | wall [s] | peak [MiB] | message (first line) |\n|---|---|---|---|---|")
        for name, code, seconds, mib, message in rows:
            print(f"| {name} | {code} | {seconds:.2f} | {mib:.0f} | `{message}` |")
    else:
        for name, code, seconds, mib, message in rows:
            print(f"{name:34s} {code:4d} {seconds:7.2f} s {mib:7.0f} MiB  {message}")


if __name__ == "__main__":
    main()
