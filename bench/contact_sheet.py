"""One picture comparing runs: one frame of each run folder, tiled with captions.

Usage: python bench/contact_sheet.py OUT.png RUNDIR[@FRAME]... [--frame N] [--field speed] [--resolution 640x360]
       [--columns 3] [--labels a b ...]
Each run shows frame FRAME when given (the moment its figure is about: a ball in the board, a wall breaking),
else --frame (default the last). Each is rendered with `pdmpm render`'s library (its scene's render settings
apply) into a scratch folder; captions default to the run folders' names. Used for docs/table1.png.
"""

import argparse
import tempfile
from pathlib import Path

from pdmpm_cli.render.options import parse_resolution
from pdmpm_cli.render.run import render_run
from pdmpm_cli.render.sheet import contact_sheet


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="PNG to write")
    ap.add_argument("runs", nargs="+", help="output folders of `pdmpm run`, each optionally @FRAME")
    ap.add_argument("--frame", type=int, default=-1, help="frame index to show (default the last)")
    ap.add_argument("--field", default=None, help="speed, damage, plastic or body (default each scene's)")
    ap.add_argument("--resolution", type=parse_resolution, default=(640, 360), help="tile size WIDTHxHEIGHT")
    ap.add_argument("--columns", type=int, default=3)
    ap.add_argument("--labels", nargs="+", help="captions, one per run (default the folder names)")
    args = ap.parse_args()
    runs = [(Path(folder), int(frame) if frame else args.frame)
            for folder, _, frame in (run.partition("@") for run in args.runs)]
    labels = args.labels or [folder.name for folder, _ in runs]
    if len(labels) != len(runs):
        ap.error(f"{len(labels)} labels for {len(runs)} runs")
    with tempfile.TemporaryDirectory() as scratch:
        images = [render_run(folder, field=args.field, frames=str(frame), resolution=args.resolution,
                             out=Path(scratch) / str(k), video=False).images[0]
                  for k, (folder, frame) in enumerate(runs)]
        contact_sheet(images, labels, args.out, columns=args.columns)
    print(f"{args.out}: {len(images)} runs, frames {[frame for _, frame in runs]}")


if __name__ == "__main__":
    main()
