"""Crack fields: the two sides of a crack or notch on two grid fields (contact.cracks; not in the paper).

A cubic B-spline node sees material up to two cells on each side, so on one grid field the material on both faces
of a crack or notch narrower than about four cells moves with one velocity there: the grid pulls across the gap
(a slit half a cell wide passed 90 % of one half's motion to the other). Damage-field partitioning (Homel &
Herbold 2017; Wolper et al. 2019, CD-MPM) gives every node near a crack two velocity fields and puts each particle
on the side of the crack it lies on; where the fields meet, the multi-field contact of engine/contact.py acts
(they cannot interpenetrate, they separate freely).

The bonds say where a crack is: each particle's broken bonds (and those a cutout took: through it, or to the
material it removed) point across it, so c_p = sum (X_q - X_p) over them, centred (`crack_normals`), points from p
into its crack, in the reference frame. At each node the particle with the longest c_p among those whose stencils
reach it owns the node; its plane, through X_o with normal n_o = c_o / |c_o|, splits the node: particle p is on the
far side (field 1) when (X_p - X_o) . n_o > h / 2, else on the owner's side (field 0). Once a crack has cut a
body in pieces (connected over intact bonds), a node that cracked particles of two pieces reach is split by piece
instead: the owner's piece, and the rest. A node no cracked particle reaches keeps one field. Everything is in the
reference frame, so the sides do not change as the body deforms. Two fields per node, as in CD-MPM: where cracks
cross or branch within a node's reach, the strongest one's plane splits it.
"""

import numpy as np
from numba import njit, prange

from pdmpm_cli.engine.transfer import stencil, stencil_on_grid

CRACK_MIN = 0.05  # a particle with fewer of its bonds broken or cut does not split nodes (a stray broken bond)
PIECE_MIN = 0.05  # nor does one in a piece with less than this share of its body's particles (debris)


@njit(parallel=True, cache=True)
def crack_normals(start, end, rest_x, bond_start, bond_nbr, bond_active, particle_cut, crack_n, crack_s):
    """c_p = sum over p's broken and cut bonds (particle_cut: their sum and count, rounded) of X_q - X_p, less the
    share d_p (broken and cut over all) of the sum over all of them (at a surface or an edge the family is lopsided,
    and a crack takes a lopsided share of it) -> crack_s[p] = |c_p| [m] where d_p >= CRACK_MIN, crack_n[p, :3] =
    c_p / |c_p| and crack_n[p, 3] = 1 where they are all cut (a cutout's face: no bond of p broken), else 0; zero
    elsewhere."""
    broken = bond_active.shape[0] > 0
    cut = particle_cut.shape[0] > 0
    for p in prange(start, end):
        c0 = c1 = c2 = 0.0
        a0 = a1 = a2 = 0.0  # sum over the whole family, cut bonds included
        nb, nt = 0, bond_start[p + 1] - bond_start[p]
        nc = 0  # of them cut
        if cut:
            c0, c1, c2 = particle_cut[p, 0], particle_cut[p, 1], particle_cut[p, 2]
            a0, a1, a2 = c0, c1, c2
            nc = int(particle_cut[p, 3] + 0.5)
            nb += nc
            nt += nc
        for b in range(bond_start[p], bond_start[p + 1]):
            q = bond_nbr[b]
            e0, e1, e2 = rest_x[q, 0] - rest_x[p, 0], rest_x[q, 1] - rest_x[p, 1], rest_x[q, 2] - rest_x[p, 2]
            a0 += e0
            a1 += e1
            a2 += e2
            if broken and bond_active[b] == 0:
                nb += 1
                c0 += e0
                c1 += e1
                c2 += e2
        crack_s[p] = 0.0
        crack_n[p, 0] = crack_n[p, 1] = crack_n[p, 2] = crack_n[p, 3] = 0.0
        if nb == 0 or nb < CRACK_MIN * nt:
            continue
        d = nb / nt
        c0, c1, c2 = c0 - d * a0, c1 - d * a1, c2 - d * a2
        s = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        if s > 0.0:
            crack_s[p] = s
            crack_n[p, 0], crack_n[p, 1], crack_n[p, 2] = c0 / s, c1 / s, c2 / s
            crack_n[p, 3] = 1.0 if nb == nc else 0.0


@njit(cache=True)
def crack_owners(start, end, particle_x, crack_s, piece, origin, inv_dx, box, owner):
    """owner[node] = the particle of start..end (its index from start) with the largest crack_s (the lower index on
    a tie) whose stencil reaches the node, encoded -index - 2 where such particles of two pieces reach it; -1 where
    none does; over the node box (cleared first). particle_x and crack_s are the whole State's rows, piece the body's.
    Returns the box of the owned nodes [i0, i1) x [j0, j1) x [k0, k1) (all 0 when none). Serial: only the particles
    next to a crack take part."""
    for i in range(box[0], box[1]):
        for j in range(box[2], box[3]):
            for k in range(box[4], box[5]):
                owner[i, j, k] = -1
    wx, wy, wz = np.empty(4), np.empty(4), np.empty(4)
    out = np.zeros(6, dtype=np.int64)
    out[0::2] = np.iinfo(np.int64).max
    for p in range(start, end):
        s = crack_s[p]
        if s <= 0.0:
            continue
        fx, fy, fz, bx, by, bz = stencil(particle_x, p, origin, inv_dx, wx, wy, wz)
        if not stencil_on_grid(fx, fy, fz, owner):
            continue
        out[0], out[1] = min(out[0], bx), max(out[1], bx + 4)
        out[2], out[3] = min(out[2], by), max(out[3], by + 4)
        out[4], out[5] = min(out[4], bz), max(out[5], bz + 4)
        q = p - start
        for i in range(4):
            for j in range(4):
                for k in range(4):
                    o = owner[bx + i, by + j, bz + k]
                    if o == -1:
                        owner[bx + i, by + j, bz + k] = q
                        continue
                    two = o <= -2
                    if two:
                        o = -o - 2
                    two = two or piece[q] != piece[o]
                    if s > crack_s[start + o]:
                        o = q
                    owner[bx + i, by + j, bz + k] = -o - 2 if two else o
    if out[1] == 0:
        out[:] = 0
    return out
