"""Why the notched plate's notch faces take damage: each cut bond with the cluster that cut it, and the faces'
most stretched bond frame by frame (pdmpm_cli/study/fracture.py: plate_scene; issue 19).

Usage: NUMBA_NUM_THREADS=1 python bench/notch_faces.py [--cell 0.02] [--cracks auto|shared] [--until 0.3]
Per frame until the first separation: the largest stretch over the threshold among the intact bonds along the
notch's faces (both ends more than a horizon behind its tip, within 3 spacings of its plane) and that bond's ends
(rest x from the plate's edge, y from the notch's plane in spacings), the bonds cut so far and those along the faces.
Then each cluster (section 6's plane cuts) that cut bonds along the faces: when, its size, where, its plane's normal
and how many bonds it cut. The solver's fracture_update is wrapped to cut one cluster at a time, which cuts the
same bonds (clusters run in order and see the cuts of the ones before).
"""

import argparse

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

import pdmpm_cli.engine.solver as solver_module
from pdmpm_cli.engine.fracture import candidate_edges, cut_clusters
from pdmpm_cli.study.fracture import large_pieces, plate_scene
from pdmpm_cli.study.sim import Sim

NOTCH = 0.12  # plate_scene's notch length [m]


def one_cluster_at_a_time(model, on_cut):
    """A stand-in for the solver's fracture_update that cuts one cluster at a time, which cuts the same bonds
    (clusters run in order and see the cuts of the ones before), and calls on_cut(members, bond_active before the
    cut, bonds cut) after each (bench/notch_cuts.py uses it too)."""

    def update(threshold, delta, start, end, particle_x, rest_x, bond_start, bond_nbr, bond_active, lmax, bmax,
               particle_cut=None):
        cand = start + np.flatnonzero((lmax[start:end] > threshold) & (bmax[start:end] >= 0))
        if len(cand) == 0:
            return 0
        src, dst = candidate_edges(start, end, cand, particle_x, bond_start, bond_nbr, bond_active, bmax)
        n, labels = connected_components(coo_matrix((np.ones(len(src)), (src, dst)), shape=(len(cand),) * 2),
                                         directed=False)
        total = 0
        for k in range(n):
            mem = cand[labels == k]
            before = bond_active.copy()
            cut = cut_clusters(delta, mem, np.array([0, len(mem)], dtype=np.int64), particle_x, bond_start,
                               bond_nbr, lmax, bmax, bond_active, rest_x, model.particle_cut)
            total += cut
            on_cut(mem, before, cut)
        return total

    return update


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cell", type=float, default=0.02)
    ap.add_argument("--cracks", choices=("auto", "shared"), default="auto", help="contact.cracks")
    ap.add_argument("--until", type=float, default=0.3, help="stop here if it has not separated [s]")
    args = ap.parse_args()
    scene = plate_scene(args.cell, 2.0, notch=NOTCH, duration=args.until)
    scene["contact"] = {"cracks": args.cracks}
    sim = Sim(scene)
    state, model = sim.state, sim.model
    b = model.bodies[0]
    x = model.rest_x
    own = np.repeat(np.arange(len(model.bond_start) - 1), np.diff(model.bond_start))
    nbr = model.bond_nbr
    edge, mid = x[:, 0].min(), 0.5 * (x[:, 1].min() + x[:, 1].max())
    behind = x[:, 0] < edge + NOTCH - b.horizon
    faces = behind[own] & behind[nbr] & (np.abs(x[own, 1] - mid) < 3 * b.spacing) & (own < nbr)
    rest = np.linalg.norm(x[nbr] - x[own], axis=1)
    clusters = []

    def on_cut(mem, before, cut):
        on_faces = int(np.count_nonzero(faces & (before == 1) & (state.bond_active == 0)))
        if on_faces:
            top = mem[np.argmax(state.particle_lmax[mem])]
            n_ = state.particle_x[state.bond_nbr[state.particle_bmax[top]]] - state.particle_x[top]
            c = x[mem].mean(axis=0)
            clusters.append((state.time, len(mem), c[0] - edge, (c[1] - mid) / b.spacing,
                             n_ / np.linalg.norm(n_), cut, on_faces))

    solver_module.fracture_update = one_cluster_at_a_time(model, on_cut)
    print("| t [s] | faces' largest stretch / threshold | at x [m] | y [h] -> y [h] | bonds cut | along the faces |")
    print("|---|---|---|---|---|---|")
    while state.time < args.until - 1e-12:
        sim.solver.advance(state, min(state.time + sim.plan.frame_dt, args.until))
        xs = state.particle_x
        s = np.linalg.norm(xs[nbr] - xs[own], axis=1) / rest - 1.0
        intact = faces & ((state.bond_active == 1) if state.has("bond_active") else True)
        i = np.flatnonzero(intact)[np.argmax(s[intact])]
        broken = int(np.count_nonzero(faces & (state.bond_active == 0))) if state.has("bond_active") else 0
        print(f"| {state.time:.3f} | {s[i] / b.fracture.threshold:.2f} | {x[own[i], 0] - edge:.3f} | "
              f"{(x[own[i], 1] - mid) / b.spacing:+.2f} -> {(x[nbr[i], 1] - mid) / b.spacing:+.2f} | "
              f"{state.bonds_cut} | {broken} |", flush=True)
        if state.bonds_cut and large_pieces(state, model) >= 2:
            break
    print("\n| t [s] | cluster size | centroid x [m] | centroid y [h] | plane normal | bonds cut | along the faces |")
    print("|---|---|---|---|---|---|---|")
    for t, size, cx, cy, n, cut, on_faces in clusters:
        print(f"| {t:.3f} | {size} | {cx:.3f} | {cy:+.2f} | {np.round(n, 2).tolist()} | {cut} | {on_faces} |")


if __name__ == "__main__":
    main()
