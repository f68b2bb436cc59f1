"""Every plane cut of the notched plate that damages a particle along the notch (more than a horizon behind its tip,
bench/notched_plate.py's definition): when (against the tip's first cut), the cluster, its most deformed bond's
criterion over the threshold, its plane, the bonds it cut there, and the grid fields of the bond's ends at the last
P2G with their nodes' owners (engine/crack.py; issue 19).

Usage: NUMBA_NUM_THREADS=1 python bench/notch_cuts.py [--cell 0.04] [--energy 2.0] [--until 0.3]
The solver's fracture_update is wrapped to cut one cluster at a time, which cuts the same bonds (clusters run in
order and see the cuts of the ones before). Fields per end: (unsplit, owner's side, far side) node counts.
"""

import argparse

import numpy as np

import pdmpm_cli.engine.solver as solver_module
from pdmpm_cli.engine.transfer import node_side, stencil
from pdmpm_cli.study.fracture import GRIP, large_pieces, plate_scene
from pdmpm_cli.study.sim import Sim

from notch_faces import one_cluster_at_a_time  # bench/, the script's own folder

NOTCH = 0.12


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cell", type=float, default=0.04)
    ap.add_argument("--until", type=float, default=0.3)
    ap.add_argument("--energy", type=float, default=2.0)
    args = ap.parse_args()
    scene = plate_scene(args.cell, args.energy, notch=NOTCH, duration=args.until)
    sim = Sim(scene)
    state, model = sim.state, sim.model
    b = model.bodies[0]
    h, delta = b.spacing, b.horizon
    x = model.rest_x
    edge = x[:, 0].min()
    lo, hi = x[:, 1].min(), x[:, 1].max()
    mid = 0.5 * (lo + hi)
    inner = np.abs(x[:, 1] - mid) < 0.5 * (hi - lo) - GRIP * (hi - lo) - delta
    along = inner & (x[:, 0] < edge + NOTCH - delta)
    own = np.repeat(np.arange(len(model.bond_start) - 1), np.diff(model.bond_start))
    nbr = model.bond_nbr
    first = {"t": None}
    wx, wy, wz = np.empty(4), np.empty(4), np.empty(4)

    def fields_of(p):
        """Field (0/1) of particle p at each of its 64 nodes, as the last P2G split them; counts of (unsplit, 0, 1)."""
        if not state.has("grid_owner"):
            return None
        owner = state.grid_owner[0]
        fx, fy, fz, bx, by, bz = stencil(state.particle_x, p, model.origin, 1.0 / model.dx, wx, wy, wz)
        out = [0, 0, 0]
        owners = set()
        for i in range(4):
            for j in range(4):
                for k in range(4):
                    o = owner[bx + i, by + j, bz + k]
                    if o == -1:
                        out[0] += 1
                        continue
                    owners.add(int(o))
                    out[1 + node_side(p, o, x, state.particle_crack_n, state.particle_piece, 0.5 * h)] += 1
        return out, owners

    def on_cut(mem, before, cut):
        if first["t"] is None:
            first["t"] = state.time
        particle_x, lmax, bond_active, rest_x = state.particle_x, state.particle_lmax, state.bond_active, x
        threshold = b.fracture.threshold
        top = mem[np.argmax(lmax[mem])]
        q = state.bond_nbr[state.particle_bmax[top]]
        new = (before == 1) & (bond_active == 0)
        hit = np.unique(np.concatenate([own[new], nbr[new]]))
        bad = hit[along[hit]]
        if len(bad):
            c = rest_x[mem].mean(axis=0)
            n_ = particle_x[q] - particle_x[top]
            n_ /= np.linalg.norm(n_)
            r = np.sqrt(((particle_x[mem] - particle_x[mem].mean(axis=0)) ** 2).sum(axis=1).max())
            print(f"t={state.time:.4f} (tip's first cut {first['t']:.4f}) cluster of {len(mem)} at "
                  f"x={c[0]-edge:.3f} y={(c[1]-mid)/h:+.2f}h radius {r/h:.2f}h "
                  f"normal {np.round(n_, 2).tolist()} top bond "
                  f"{top}->{q} rest ({x[top,0]-edge:.3f},{(x[top,1]-mid)/h:+.2f}h)->({x[q,0]-edge:.3f},"
                  f"{(x[q,1]-mid)/h:+.2f}h) l/thr={lmax[top]/threshold:.3f} cut {cut}, damaging along the "
                  f"notch {len(bad)}: x {np.round(x[bad,0]-edge, 3).tolist()} "
                  f"y/h {np.round((x[bad,1]-mid)/h, 2).tolist()}")
            for e in np.flatnonzero(new & (along[own] | along[nbr]) & (own < nbr)):
                u, v = own[e], nbr[e]
                cu = model.particle_cut[u, :3] / max(np.linalg.norm(model.particle_cut[u, :3]), 1e-30)
                cv = model.particle_cut[v, :3] / max(np.linalg.norm(model.particle_cut[v, :3]), 1e-30)
                bd = (x[v] - x[u]) / np.linalg.norm(x[v] - x[u])
                print(f"   bond ({x[u,0]-edge:.3f},{(x[u,1]-mid)/h:+.2f}h,{(x[u,2]-x[:,2].min())/h:.2f}h)->"
                      f"({x[v,0]-edge:.3f},{(x[v,1]-mid)/h:+.2f}h,{(x[v,2]-x[:,2].min())/h:.2f}h) cut dirs "
                      f"{np.round(cu, 2).tolist()} {np.round(cv, 2).tolist()} bond dir {np.round(bd, 2).tolist()}")
            for p in (top, q):
                print(f"   particle {p}: fields (unsplit, near, far) / owners {fields_of(p)} crack_s "
                      f"{state.particle_crack_s[p]:.4g} damage {state.particle_damage[p]:.3f}")
            for o in sorted(fields_of(top)[1] | fields_of(q)[1])[:6] if fields_of(top) else []:
                oo = o if o >= 0 else -o - 2
                print(f"   owner {oo}: rest ({x[oo,0]-edge:.3f},{(x[oo,1]-mid)/h:+.2f}h) crack_s "
                      f"{state.particle_crack_s[oo]/h:.3f}h n {np.round(state.particle_crack_n[oo], 2).tolist()}"
                      f" cut-count {model.particle_cut[oo,3] if len(model.particle_cut) else 0:.2f}")

    solver_module.fracture_update = one_cluster_at_a_time(model, on_cut)
    while state.time < args.until - 1e-12:
        sim.solver.advance(state, min(state.time + sim.plan.frame_dt, args.until))
        if state.bonds_cut and large_pieces(state, model) >= 2:
            break
    dmg = state.particle_damage > 0
    print(f"end t={state.time:.3f}: damaged along the notch {int((dmg & along).sum())}")


if __name__ == "__main__":
    main()
