"""The exported shell surface follows the particles: a coarse mesh file (a sheet of two triangles) is refined to the
spacing, so that as the cloth folds under its weight the surface stays within half a spacing of its particles."""

import numpy as np
from scipy.spatial import cKDTree

from pdmpm_cli.engine.embedding import mesh_positions

H = 0.015  # particle spacing [m]


def point_triangle_distance(p, a, b, c):
    """Exact distance from points p (n, 3) to triangles (a, b, c) (n, 3 each): the closest point by the Voronoi
    regions of the corners, edges and face (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        q = a + ab * (vb * denom)[:, None] + ac * (vc * denom)[:, None]  # inside the face
        edges = [
            (vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * (d1 / (d1 - d3))[:, None],
            (vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * (d2 / (d2 - d6))[:, None],
            (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None],
        ]
    for mask, point in zip(edges[::2], edges[1::2]):
        q = np.where(mask[:, None], point, q)
    for mask, point in (((d1 <= 0) & (d2 <= 0), a), ((d3 >= 0) & (d4 <= d3), b), ((d6 >= 0) & (d5 <= d6), c)):
        q = np.where(mask[:, None], point, q)
    return np.linalg.norm(p - q, axis=1)


def distance_to_surface(points, V, T, k=24):
    """Distance of each point to the triangle mesh (exact over the k triangles with the nearest centroids)."""
    _, near = cKDTree(V[T].mean(axis=1)).query(points, k=min(k, len(T)))
    near = near.reshape(len(points), -1)
    d = [point_triangle_distance(points, V[T[near[:, j], 0]], V[T[near[:, j], 1]], V[T[near[:, j], 2]])
         for j in range(near.shape[1])]
    return np.min(d, axis=0)


def hanging_sheet(path, edge=None):
    """A 0.3 m square cloth from an OBJ of two triangles, held by two corners: it swings down under its weight
    and hangs in a sagging, folded curtain between them."""
    path.write_text("v 0.25 0.8 0.35\nv 0.55 0.8 0.35\nv 0.55 0.8 0.65\nv 0.25 0.8 0.65\nf 1 4 3 2\n")
    geometry = {"mode": "shell", "spacing": H, "surface": {"type": "mesh", "path": str(path)}}
    if edge:
        geometry["edge"] = edge
    return {
        "simulation": {"duration": 1.0, "fps": 20},
        "grid": {"cell_size": 2 * H, "domain": {"min": [0, 0.2, 0], "max": [0.8, 1.0, 0.8]}},
        "gravity": [0, -9.81, 0],
        "wind": {"velocity": [0, 0, 0], "drag": 4.0},
        "bodies": [{"name": "cloth", "geometry": geometry,
                    "material": {"model": "elastic", "density": 2000.0, "lam": 1e5, "mu": 2e4},
                    "pins": [{"region": {"type": "sphere", "center": [x, 0.8, 0.35], "radius": 0.016}}
                             for x in (0.257, 0.543)]}],
    }


def test_coarse_sheet_surface_follows_the_folding_cloth(sim_factory, tmp_path):
    """Once it hangs, every particle away from the two pins (where the cloth kinks about a point) is within half a
    spacing of the exported surface refined from the file's two triangles, the pinned ones within 0.75 h; the
    file's own triangles (edge: 1 m, no refinement) end up about two spacings away."""
    far = {}
    for edge in (None, 1.0):
        sim = sim_factory(hanging_sheet(tmp_path / "sheet.obj", edge), base={})
        mesh = sim.prep.disc.meshes[0]
        assert len(mesh.triangles) == 2 if edge else len(mesh.triangles) >= 2 * (0.3 / H) ** 2  # edges <= h
        sim.advance(0.5)
        x = sim.state.particle_x
        assert x[:, 1].min() < 0.8 - 0.2  # the free corners swung down
        V = mesh_positions(sim.model, sim.state, [mesh])[0]
        far[edge] = distance_to_surface(x, V, mesh.triangles)
    free = ~sim.model.pin_mask
    print(f"distance particles - surface after 0.5 s [h]: refined: free particles max {far[None][free].max() / H:.2f}, "
          f"mean {far[None].mean() / H:.3f}, pinned max {far[None][~free].max() / H:.2f}; the file's 2 triangles: "
          f"max {far[1.0].max() / H:.2f}, mean {far[1.0].mean() / H:.2f}")
    assert far[None][free].max() < 0.5 * H and far[None].max() < 0.75 * H
    assert far[1.0].max() > 1.5 * H
