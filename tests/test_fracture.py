"""Fracture (section 6, eq. 21): cell inactive fraction, bond criterion, plane cuts, damage, crack integrator."""

import os
import subprocess
import sys
import types
from pathlib import Path

import numba
import numpy as np
import pytest

from pdmpm_cli.engine.bonds import build_families
from pdmpm_cli.assemble import collider_table
from pdmpm_cli.engine.fracture import (bond_criterion, crack_contact, crack_particle_update, damage, fracture_update,
                                       inactive_fraction, pieces)

H = 0.01  # lattice spacing [m]
DELTA = 2.0 * H  # horizon [m]
DX = 2.0 * H  # grid cell [m]: 2 particles per cell and axis, as in the scenes
ORIGIN = np.full(3, -0.1)
CELLS = np.array([40, 40, 40], dtype=np.int64)
NO_EP = np.zeros(0)


def lattice(nx, ny, nz, corner=(0.0, 0.0, 0.0)):
    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    return np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1) * H + np.asarray(corner)


def owners(bond_start):
    return np.repeat(np.arange(len(bond_start) - 1), np.diff(bond_start))


def reverse(bond_start, bond_nbr):
    """Index of q -> p for every bond p -> q (rows are sorted by neighbour, so keys p n + q ascend)."""
    n = len(bond_start) - 1
    key = owners(bond_start) * n + bond_nbr
    rev = np.searchsorted(key, bond_nbr.astype(np.int64) * n + owners(bond_start))
    assert np.array_equal(key[rev], bond_nbr.astype(np.int64) * n + owners(bond_start))
    return rev


def components(bond_start, bond_nbr, bond_active):
    labels = pieces(bond_start, bond_nbr, bond_active == 1, 0, len(bond_start) - 1)
    return labels.max() + 1, labels


def stretch(x, rest_x, bond_start, bond_nbr):
    src = owners(bond_start)
    return (np.linalg.norm(x[bond_nbr] - x[src], axis=1) / np.linalg.norm(rest_x[bond_nbr] - rest_x[src], axis=1)
            - 1.0)


def cell_counts(cells):
    """inactive_fraction's dense per-cell counts (bonds, broken bonds), stale values in them to show they are reset."""
    return np.full(int(np.prod(cells)), 7, np.int64), np.full(int(np.prod(cells)), 3, np.int64)


def fracture_loop(threshold, start, end, x, rest_x, bond_start, bond_nbr, bond_active, max_updates):
    """Criterion and plane cuts until no candidate is left (or max_updates); returns (bonds cut, updates)."""
    n = len(x)
    inactive, lmax, bmax = np.zeros(n), np.zeros(n), np.zeros(n, np.int64)
    cut = 0
    for update in range(max_updates):
        inactive_fraction(x, ORIGIN, 1.0 / DX, CELLS, bond_start, bond_active, *cell_counts(CELLS), inactive)
        if bond_criterion(start, end, threshold, 1.0, x, rest_x, bond_start, bond_nbr, bond_active, NO_EP, inactive,
                          lmax, bmax) == 0:
            return cut, update
        cut += fracture_update(threshold, DELTA, start, end, x, rest_x, bond_start, bond_nbr, bond_active, lmax,
                               bmax)
    return cut, max_updates


def test_inactive_fraction_counts_broken_bonds_per_cell():
    # Cells 0.2 m wide: particles 0, 1 in cell (0, 0, 0), 2, 3 in cell (1, 0, 0), 4 in (1, 1, 0); 5 lies
    # below the grid and counts in the boundary cell (0, 0, 0).
    x = np.array([[0.05, 0.05, 0.05], [0.15, 0.05, 0.05], [0.25, 0.05, 0.05], [0.35, 0.05, 0.05],
                  [0.25, 0.25, 0.05], [-0.1, 0.05, 0.05]])
    bond_start, bond_nbr = build_families(x, [(0, 6)], [0.16])
    # bonds 0-1, 1-2, 2-3, 0-5 (0-5 is 0.15 long; 2-4 is 0.2 and out of range)
    assert np.diff(bond_start).tolist() == [2, 2, 2, 1, 0, 1]
    active = np.ones(len(bond_nbr), np.uint8)
    rev = reverse(bond_start, bond_nbr)
    src = owners(bond_start)
    broken = ((src == 0) & (bond_nbr == 1)) | ((src == 2) & (bond_nbr == 3))
    active[broken | broken[rev]] = 0
    out = np.full(6, -1.0)
    cells = np.array([4, 4, 4], dtype=np.int64)
    inactive_fraction(x, np.zeros(3), 5.0, cells, bond_start, active, *cell_counts(cells), out)
    # cell (0,0,0): particles 0, 1, 5 own 2 + 2 + 1 bonds, 2 broken (0-1 both ways); cell (1,0,0): 2, 3 own
    # 2 + 1 bonds, 2 broken (2-3 both ways); cell (1,1,0): particle 4 has no bonds
    assert out.tolist() == [2 / 5, 2 / 5, 2 / 3, 2 / 3, 0.0, 2 / 5]


def inactive_fraction_runs():
    """inactive_fraction on a jittered lattice with 30 % of its bonds broken, with 1 thread and with all of Numba's:
    (x, bond_start, active, [out with 1 thread, out with all])."""
    rest_x = lattice(12, 10, 8)
    bond_start, bond_nbr = build_families(rest_x, [(0, len(rest_x))], [DELTA])
    x = rest_x + np.random.default_rng(3).normal(0.0, 0.3 * H, rest_x.shape)
    active = (np.random.default_rng(4).random(len(bond_nbr)) > 0.3).astype(np.uint8)
    active &= active[reverse(bond_start, bond_nbr)]
    runs, threads_now = [], numba.get_num_threads()
    try:
        for threads in (1, numba.config.NUMBA_NUM_THREADS):
            numba.set_num_threads(threads)
            out = np.zeros(len(x))
            inactive_fraction(x, ORIGIN, 1.0 / DX, CELLS, bond_start, active, *cell_counts(CELLS), out)
            runs.append(out)
    finally:
        numba.set_num_threads(threads_now)
    return x, bond_start, active, runs


def test_inactive_fraction_is_independent_of_thread_count():
    x, bond_start, active, runs = inactive_fraction_runs()
    if numba.config.NUMBA_NUM_THREADS > 1:
        assert np.array_equal(runs[0], runs[1])
    else:  # a test worker's share of the cores is one thread: compare 1 and 2 threads in a process of its own
        code = ("import numpy as np; from tests.test_fracture import inactive_fraction_runs as f; r = f()[3]; "
                "print(len(r), np.array_equal(r[0], r[1]))")
        out = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, NUMBA_NUM_THREADS="2"),
                             cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True, timeout=600)
        assert out.stdout.split() == ["2", "True"], out.stderr
    # direct count: cells as numpy keys
    cell = np.clip(np.floor((x - ORIGIN) / DX).astype(np.int64), 0, CELLS - 1)
    key = np.ravel_multi_index(cell.T, CELLS)
    broken = np.add.reduceat((active == 0).astype(np.int64), bond_start[:-1])
    _, inv = np.unique(key, return_inverse=True)
    frac = np.bincount(inv, broken) / np.bincount(inv, np.diff(bond_start))
    np.testing.assert_array_equal(runs[0], frac[inv])


def test_bond_criterion_uniform_stretch_plastic_strain_and_inactive_fraction():
    rest_x = lattice(8, 6, 5)
    n = len(rest_x)
    bond_start, bond_nbr = build_families(rest_x, [(0, n)], [DELTA])
    s0 = 0.03
    x = rest_x * (1.0 + s0)
    active = np.ones(len(bond_nbr), np.uint8)
    lmax, bmax = np.zeros(n), np.zeros(n, np.int64)

    def criterion(threshold, ep, inactive, resistance=1.0):
        return bond_criterion(0, n, threshold, resistance, x, rest_x, bond_start, bond_nbr, active, ep, inactive,
                              lmax, bmax)

    assert criterion(0.02, NO_EP, np.zeros(n)) == n
    np.testing.assert_allclose(lmax, s0, rtol=0, atol=1e-12)
    assert np.all((bmax >= bond_start[:-1]) & (bmax < bond_start[1:]))
    assert criterion(0.02, np.full(len(bond_nbr), s0 / 2), np.zeros(n)) == 0
    np.testing.assert_allclose(lmax, s0 / 2, rtol=0, atol=1e-12)
    assert criterion(0.02, NO_EP, np.ones(n)) == 0
    np.testing.assert_allclose(lmax, s0 / 2, rtol=0, atol=1e-12)
    assert criterion(0.02, NO_EP, np.ones(n), resistance=0.0) == n  # damage_resistance 0: p_inactive ignored
    np.testing.assert_allclose(lmax, s0, rtol=0, atol=1e-12)
    # a particle whose bonds are all broken has no criterion and is no candidate
    rev = reverse(bond_start, bond_nbr)
    active[bond_start[0]:bond_start[1]] = 0
    active[rev[bond_start[0]:bond_start[1]]] = 0
    assert criterion(0.02, NO_EP, np.zeros(n)) == n - 1
    assert (lmax[0], bmax[0]) == (0.0, -1)


@pytest.mark.parametrize("hinge", [0.0, 0.02])
def test_notched_bar_splits_at_the_notch_plane(hinge):
    # Body 0: a small block off to the side that must stay untouched. Body 1: a 40 x 10 x 6 bar along x
    # with a 3h wide notch from the top down to 45 % of the height, halfway along. The halves separate
    # rigidly by half a spacing (and, with hinge > 0, also rotate apart about the ligament's bottom edge).
    block = lattice(3, 3, 3, corner=(0.6, 0.0, 0.0))
    bar = lattice(40, 10, 6)
    notch_x = 19.5 * H
    bar = bar[~((np.abs(bar[:, 0] - notch_x) < H) & (bar[:, 1] > 4.5 * H))]
    rest_x = np.vstack([block, bar])
    start, end = len(block), len(rest_x)
    bond_start, bond_nbr = build_families(rest_x, [(0, start), (start, end)], [DELTA, DELTA])
    left = rest_x[:, 0] < notch_x
    sign = np.where(left, -1.0, 1.0)
    x = rest_x.copy()
    x[start:, 0] += 0.25 * H * sign[start:]
    c, s = np.cos(-hinge * sign[start:]), np.sin(-hinge * sign[start:])
    rel = x[start:, :2] - [notch_x, 0.0]
    x[start:, 0] = notch_x + c * rel[:, 0] - s * rel[:, 1]
    x[start:, 1] = s * rel[:, 0] + c * rel[:, 1]
    x += np.random.default_rng(0).uniform(-0.02 * H, 0.02 * H, x.shape)
    active = np.ones(len(bond_nbr), np.uint8)
    src = owners(bond_start)
    crossing = int(np.sum(left[src] != left[bond_nbr])) // 2

    cut, updates = fracture_loop(0.1, start, end, x, rest_x, bond_start, bond_nbr, active, 20)

    print(f"hinge {hinge}: {cut} bonds cut in {updates} updates, {crossing} cross the notch plane")
    assert updates <= 3
    assert cut == crossing
    assert np.all(active[bond_start[start]:] == (left[src] == left[bond_nbr])[bond_start[start]:])
    assert np.all(active[:bond_start[start]] == 1)
    n_comp, label = components(bond_start, bond_nbr, active)
    assert n_comp == 3  # block, left half, right half
    bar_left, bar_right = label[start:][left[start:]], label[start:][~left[start:]]
    assert len(np.unique(bar_left)) == 1 and len(np.unique(bar_right)) == 1 and bar_left[0] != bar_right[0]
    dmg, crack = np.zeros(end), np.zeros(end, np.uint8)
    damage(bond_start, active, dmg, crack)
    assert dmg.max() < 0.5
    # crack-surface particles: the two ligament columns next to the plane (bonds are shorter than 2h)
    assert crack.sum() == np.sum(np.abs(bar[:, 0] - notch_x) < H) == 2 * 5 * 6


def test_plane_cuts_make_few_fragments_where_deleting_over_threshold_bonds_makes_dust():
    # Uniform 7.5 % stretch with 1 % noise: 99 % of the bonds exceed the 5 % threshold at once.
    rest_x = lattice(20, 20, 20)
    n = len(rest_x)
    bond_start, bond_nbr = build_families(rest_x, [(0, n)], [DELTA])
    threshold = 0.05
    x = rest_x * (1.0 + 1.5 * threshold) + np.random.default_rng(1).normal(0.0, 0.01 * H, rest_x.shape)
    s = stretch(x, rest_x, bond_start, bond_nbr)
    naive = (s <= threshold).astype(np.uint8)
    n_naive = components(bond_start, bond_nbr, naive)[0]
    counts = []
    for updates in (1, 3):
        active = np.ones(len(bond_nbr), np.uint8)
        fracture_loop(threshold, 0, n, x, rest_x, bond_start, bond_nbr, active, updates)
        counts.append(components(bond_start, bond_nbr, active)[0])
        assert np.array_equal(active, active[reverse(bond_start, bond_nbr)])  # no half-broken pair
    print(f"over threshold {np.mean(s > threshold):.3f}; components: delete over threshold {n_naive}, "
          f"plane cuts {counts[0]} after one update, {counts[1]} after three")
    assert np.mean(s > threshold) > 0.95
    assert n_naive > 0.5 * n
    assert counts[0] <= 4 and counts[1] <= 30


def test_damage_counts_broken_bonds():
    # chain 0-1-2-3 (horizon 1.5 h): cutting 0-1 and 2-3
    x = lattice(4, 1, 1)
    bond_start, bond_nbr = build_families(x, [(0, 4)], [1.5 * H])
    active = np.ones(len(bond_nbr), np.uint8)
    src = owners(bond_start)
    active[(src + bond_nbr == 1) | (src + bond_nbr == 5)] = 0
    dmg, crack = np.full(4, -1.0), np.full(4, 7, np.uint8)
    damage(bond_start, active, dmg, crack)
    assert dmg.tolist() == [1.0, 0.5, 0.5, 1.0]
    assert crack.tolist() == [1, 1, 1, 1]
    active[:] = 1
    active[(src + bond_nbr == 1)] = 0
    damage(bond_start, active, dmg, crack)
    assert dmg.tolist() == [1.0, 0.5, 0.0, 0.0]
    assert crack.tolist() == [1, 1, 0, 0]
    # a lattice particle with 26 bonds, 3 of them broken
    x = lattice(5, 5, 5)
    bond_start, bond_nbr = build_families(x, [(0, 125)], [DELTA])
    centre = 62
    assert bond_start[centre + 1] - bond_start[centre] == 26
    active = np.ones(len(bond_nbr), np.uint8)
    rev = reverse(bond_start, bond_nbr)
    active[bond_start[centre]:bond_start[centre] + 3] = 0
    active[rev[bond_start[centre]:bond_start[centre] + 3]] = 0
    dmg, crack = np.zeros(125), np.zeros(125, np.uint8)
    damage(bond_start, active, dmg, crack)
    assert dmg[centre] == 3 / 26
    assert crack.sum() == 4 and np.count_nonzero(dmg) == 4


def test_crack_particle_update_symplectic_euler_colliders_and_box():
    floor = types.SimpleNamespace(type="plane", point=(0.0, 0.1, 0.0), normal=(0.0, 1.0, 0.0),
                                  velocity=(0.0, 0.0, 0.0), boundary="separate", friction=0.0)
    colliders = collider_table([floor])
    dt, t_new = 0.01, 0.01
    gravity = np.array([0.0, -9.81, 0.0])
    lo, hi = np.full(3, 0.02), np.full(3, 0.98)
    # 0: free flight; 1: falls through the floor within the step; 2: already below it, moving down;
    # 3: not a crack particle; 4: leaves the box through x = hi
    x0 = np.array([[0.5, 0.5, 0.5], [0.3, 0.1005, 0.5], [0.6, 0.099, 0.5], [0.2, 0.05, 0.5], [0.97, 0.5, 0.5]])
    v0 = np.array([[1.0, 2.0, -0.5], [0.5, -1.0, 0.0], [0.2, -3.0, 0.0], [0.0, -5.0, 0.0], [5.0, 0.0, 0.0]])
    mass = np.array([2.0, 1.0, 1.0, 1.0, 1.0])
    force = np.array([[4.0, -2.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [9.0, 9.0, 9.0], [0.0, 0.0, 0.0]])
    crack = np.array([1, 1, 1, 0, 1], np.uint8)
    x, v = x0.copy(), v0.copy()
    c = np.ones((5, 3, 3))
    grid = np.zeros((12, 12, 12, 4))  # no material on the grid: no contact, only the own-force update
    index = np.flatnonzero(crack)
    crack_contact(grid, dt, gravity, np.zeros(3), 10.0, index, np.ones(5), mass, np.full(5, 1e-3), force, x, v)
    vmax, bad = crack_particle_update(dt, t_new, colliders, lo, hi, index, x, v, c)

    v_free = v0[0] + dt * (force[0] / mass[0] + gravity)
    np.testing.assert_allclose(v[0], v_free, rtol=0, atol=1e-15)
    np.testing.assert_allclose(x[0], x0[0] + dt * v_free, rtol=0, atol=1e-15)
    assert x[1, 1] == pytest.approx(0.1, abs=1e-15)  # pushed back onto the floor
    np.testing.assert_allclose(v[1], v0[1] + dt * gravity, atol=1e-15)  # above the floor: free velocity
    assert x[2, 1] == pytest.approx(0.1, abs=1e-15) and v[2, 1] == 0.0  # inside: normal velocity removed
    np.testing.assert_allclose(x[2, [0, 2]], x0[2, [0, 2]] + dt * v0[2, [0, 2]], atol=1e-15)
    np.testing.assert_array_equal(x[3], x0[3])
    np.testing.assert_array_equal(v[3], v0[3])
    assert np.all(c[3] == 1.0) and np.all(c[crack == 1] == 0.0)
    assert x[4, 0] == hi[0] and v[4, 0] == 0.0
    assert bad == 0
    assert vmax == pytest.approx(np.linalg.norm(v[crack == 1], axis=1).max())


def test_crack_contact_with_grid_material_is_inelastic_and_conserves_momentum():
    """A crack particle flying into a slab of material on the grid (x < 0.5) loses its approach velocity along
    the slab's normal; the slab takes the impulse. One flying away, or outside the material, is untouched."""
    n, dx = 20, 0.05
    grid = np.zeros((n, n, n, 4))
    rho = 1000.0
    grid[:10, :, :, 0] = rho * dx**3  # material filling x < 0.5 m (node mass of a full cell)
    grid[:10, :, :, 1:] = [0.1, 0.0, 0.0]  # moving slowly in +x
    x = np.array([[0.47, 0.5, 0.5], [0.47, 0.5, 0.5], [0.8, 0.5, 0.5]])
    v0 = np.array([[-2.0, 0.3, 0.0], [1.0, 0.0, 0.0], [-2.0, 0.0, 0.0]])
    v = v0.copy()
    mass = np.full(3, rho * (dx / 2) ** 3)
    crack = np.ones(3, np.uint8)
    before = grid.copy()
    momentum = lambda g, vv: (g[..., :1] * g[..., 1:]).sum(axis=(0, 1, 2)) + mass @ vv  # noqa: E731
    energy = lambda g, vv: 0.5 * (g[..., 0] * (g[..., 1:] ** 2).sum(-1)).sum() + 0.5 * mass @ (vv**2).sum(1)  # noqa: E731
    crack_contact(grid, 0.0, np.zeros(3), np.zeros(3), 1.0 / dx, np.flatnonzero(crack), np.ones(3), mass, mass / rho,
                  np.zeros((3, 3)), x, v)
    np.testing.assert_allclose(momentum(grid, v), momentum(before, v0), rtol=1e-13)
    assert energy(grid, v) < energy(before, v0)
    # the particle and the lump of slab around it move on together along the normal (x); sliding is kept
    assert -2.0 < v[0, 0] < 0.1 and v[0, 1] == pytest.approx(0.3) and v[0, 2] == 0.0
    assert grid[:10, :, :, 1].min() < 0.1  # the slab was pushed back where the particle hit
    np.testing.assert_array_equal(v[1:], v0[1:])  # separating, and outside the material


def test_cuts_never_leave_half_broken_pairs():
    rest_x = lattice(14, 12, 10)
    n = len(rest_x)
    bond_start, bond_nbr = build_families(rest_x, [(0, n)], [DELTA])
    rev = reverse(bond_start, bond_nbr)
    x = rest_x + np.random.default_rng(5).normal(0.0, 0.15 * H, rest_x.shape)
    active = np.ones(len(bond_nbr), np.uint8)
    cut, updates = fracture_loop(0.1, 0, n, x, rest_x, bond_start, bond_nbr, active, 6)
    broken = int(np.sum(active == 0))
    print(f"random field: {cut} pairs cut in {updates} updates")
    assert cut > 100 and broken == 2 * cut
    assert np.array_equal(active, active[rev])
