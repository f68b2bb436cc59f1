"""Reference point for bench_cube.py: a plain Taichi MLS-MPM step on the same cube (same particle count, cell
size, cubic B-splines, APIC), with a fixed-corotated stress and no bonds. Optional: needs `pip install taichi`.

Used by bench_cube.py --taichi; runs in its own process because Taichi and Numba each start a thread pool.
Usage: python bench/taichi_cube.py N_PARTICLES STEPS f32|f64 THREADS  (prints particle-steps/s)
"""

import sys
import time

import numpy as np
import taichi as ti


def run(n_target: int, steps: int, precision: str, threads: int) -> float:
    real = ti.f32 if precision == "f32" else ti.f64
    ti.init(arch=ti.cpu, default_fp=real, cpu_max_num_threads=threads, log_level=ti.ERROR)
    h = 0.01  # particle spacing, as bench_cube.cube_scene: 8 particles per cell of 2h
    side_n = round(n_target ** (1 / 3))
    dx = 2 * h
    pad = 6
    cells = side_n // 2 + 2 * pad
    n = side_n**3
    inv_dx = 1.0 / dx
    vol = h**3
    rho, lam, mu = 1000.0, 1e5, 1e5
    mass = rho * vol
    dt = 0.5 * dx / np.sqrt((lam + 2 * mu) / rho)

    x = ti.Vector.field(3, real, n)
    v = ti.Vector.field(3, real, n)
    C = ti.Matrix.field(3, 3, real, n)
    F = ti.Matrix.field(3, 3, real, n)
    grid_v = ti.Vector.field(3, real, (cells, cells, cells))
    grid_m = ti.field(real, (cells, cells, cells))

    @ti.func
    def cubic(fx):
        base = ti.cast(ti.floor(fx), ti.i32) - 1
        w = ti.Matrix.zero(real, 4, 3)
        for i in ti.static(range(4)):
            for a in ti.static(range(3)):
                d = ti.abs(fx[a] - (base[a] + i))
                if d < 1.0:
                    w[i, a] = 0.5 * d**3 - d**2 + 2.0 / 3.0
                elif d < 2.0:
                    w[i, a] = (2.0 - d) ** 3 / 6.0
        return base, w

    @ti.kernel
    def init():
        for p in x:
            i = p // (side_n * side_n)
            j = (p // side_n) % side_n
            k = p % side_n
            x[p] = (ti.Vector([i, j, k]) + 0.5 + 0.3 * (ti.Vector([ti.random(), ti.random(), ti.random()]) - 0.5)) \
                * h + pad * dx
            v[p] = ti.Vector([0.0, 0.0, 0.0])
            F[p] = ti.Matrix.identity(real, 3)
            C[p] = ti.Matrix.zero(real, 3, 3)

    @ti.kernel
    def substep():
        for I in ti.grouped(grid_m):
            grid_v[I] = ti.Vector.zero(real, 3)
            grid_m[I] = 0.0
        for p in x:
            base, w = cubic(x[p] * inv_dx)
            F[p] = (ti.Matrix.identity(real, 3) + dt * C[p]) @ F[p]
            U, sig, V = ti.svd(F[p])
            J = sig[0, 0] * sig[1, 1] * sig[2, 2]
            stress = 2 * mu * (F[p] - U @ V.transpose()) @ F[p].transpose() + ti.Matrix.identity(real, 3) * lam * J * (J - 1)
            stress = (-dt * vol * 3 * inv_dx * inv_dx) * stress
            affine = stress + mass * C[p]
            for i, j, k in ti.static(ti.ndrange(4, 4, 4)):
                offset = ti.Vector([i, j, k])
                dpos = (offset + base - x[p] * inv_dx) * dx
                weight = w[i, 0] * w[j, 1] * w[k, 2]
                grid_v[base + offset] += weight * (mass * v[p] + affine @ dpos)
                grid_m[base + offset] += weight * mass
        for I in ti.grouped(grid_m):
            if grid_m[I] > 0:
                grid_v[I] /= grid_m[I]
                for a in ti.static(range(3)):
                    if I[a] < 3 and grid_v[I][a] < 0 or I[a] > cells - 3 and grid_v[I][a] > 0:
                        grid_v[I][a] = 0
        for p in x:
            base, w = cubic(x[p] * inv_dx)
            new_v = ti.Vector.zero(real, 3)
            new_C = ti.Matrix.zero(real, 3, 3)
            for i, j, k in ti.static(ti.ndrange(4, 4, 4)):
                offset = ti.Vector([i, j, k])
                dpos = (offset + base - x[p] * inv_dx) * dx
                weight = w[i, 0] * w[j, 1] * w[k, 2]
                g_v = grid_v[base + offset]
                new_v += weight * g_v
                new_C += 3 * inv_dx * inv_dx * weight * g_v.outer_product(dpos)
            v[p] = new_v
            C[p] = new_C
            x[p] += dt * v[p]

    init()
    for _ in range(3):  # compile and warm up
        substep()
    ti.sync()
    t0 = time.perf_counter()
    for _ in range(steps):
        substep()
    ti.sync()
    return n * steps / (time.perf_counter() - t0)


if __name__ == "__main__":
    rate = run(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], int(sys.argv[4]))
    print(f"{rate:.6g}")
