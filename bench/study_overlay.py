"""One log-log plot of error against wall time from several `pdmpm study` CSVs (their space ladders).

Usage: python bench/study_overlay.py OUT.png STUDY.csv... [--labels a b ...] [--title T]
Each study's space-ladder runs with an error become one line, labelled with its fitted slope. Used for
docs/study_classes.png (the four Table 1 material classes).
"""

import argparse
import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="PNG to write")
    ap.add_argument("studies", type=Path, nargs="+", help="study.csv files of `pdmpm study`")
    ap.add_argument("--labels", nargs="+", help="one per study (default the parent folder names)")
    ap.add_argument("--title", default="error against the finest run")
    args = ap.parse_args()
    labels = args.labels or [p.parent.name for p in args.studies]
    if len(labels) != len(args.studies):
        ap.error(f"{len(labels)} labels for {len(args.studies)} studies")
    fig, ax = plt.subplots(figsize=(8.4, 3.6), dpi=80)
    for path, label in zip(args.studies, labels):
        rows = [r for r in csv.DictReader(path.open()) if r["ladder"] == "space" and r["error"] != "nan"]
        wall, err = (np.array([float(r[k]) for r in rows]) for k in ("wall_s", "error"))
        slope = np.polyfit(np.log(wall), np.log(err), 1)[0]
        ax.loglog(wall, err, "o-", label=f"{label}: slope {slope:.2f}")
    ax.set(xlabel="wall time [s]", ylabel="error [-]", title=args.title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.02, 0.5))
    fig.tight_layout()
    fig.savefig(args.out)


if __name__ == "__main__":
    main()
