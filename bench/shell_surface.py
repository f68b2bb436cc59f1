"""How far the exported shell surface strays from the particles under it, for coarse mesh files.

    python bench/shell_surface.py

Two shells from coarse mesh files, each run with the file's mesh refined to the spacing (the default) and with the
file's own triangles (`edge: 1.0`, nothing split):

* a cloth from an OBJ of two triangles, held by two corners, hanging after 0.5 s (tests/test_shell_surface.py);
* a cube from an OBJ of 12 triangles (0.2 m, 2 layers, h = 0.01 m) thrown at 4 m/s onto the floor: its surface
  particles (the layer at h/2 under the surface) are measured against their rest distance over the impact.

The table gives, in spacings h, the largest and the mean distance of the (surface) particles from the exported
surface, over all frames (the cube: the change from the rest distance).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pdmpm_cli.engine.embedding import mesh_positions  # noqa: E402
from pdmpm_cli.study.sim import Sim  # noqa: E402
from tests.test_shell_surface import H, distance_to_surface, hanging_sheet  # noqa: E402

CUBE_H = 0.01


def cube_scene(path: Path, edge=None) -> dict:
    from tests.mesh_corpus import box_quads, write_obj_blender

    V, F = box_quads(size=(0.2, 0.2, 0.2), n=1, center=(0.4, 0.3, 0.4))
    write_obj_blender(path, V, F, mtl=False, name="Cube")
    geometry = {"mode": "shell", "layers": 2, "spacing": CUBE_H, "surface": {"type": "mesh", "path": str(path)}}
    if edge:
        geometry["edge"] = edge
    return {
        "simulation": {"duration": 0.15, "fps": 100},
        "grid": {"cell_size": 2 * CUBE_H, "domain": {"min": [0, 0, 0], "max": [0.8, 0.6, 0.8]}},
        "gravity": [0, -9.81, 0],
        "bodies": [{"name": "cube", "geometry": geometry, "velocity": [0.0, -4.0, 0.0],
                    "material": {"model": "elastic", "density": 1000.0, "lam": 2e5, "mu": 2e5}}],
        "colliders": [{"type": "plane", "point": [0, 0.12, 0], "normal": [0, 1, 0], "friction": 0.3}],
    }


def measure(sim: Sim, t_end: float, h: float, relative: bool) -> tuple[float, float]:
    mesh = sim.prep.disc.meshes[0]
    rest = distance_to_surface(sim.model.rest_x, mesh.vertices, mesh.triangles)
    surface = rest < h if relative else np.ones(len(rest), bool)
    worst, means = 0.0, []
    for t in np.arange(1, int(round(t_end / sim.plan.frame_dt)) + 1) * sim.plan.frame_dt:
        sim.advance(t)
        V = mesh_positions(sim.model, sim.state, [mesh])[0]
        d = distance_to_surface(sim.state.particle_x[surface], V, mesh.triangles)
        dev = np.abs(d - rest[surface]) if relative else d
        worst, means = max(worst, float(dev.max())), means + [float(dev.mean())]
    return worst / h, float(np.mean(means)) / h


def main():
    folder = Path(tempfile.mkdtemp(prefix="pdmpm_shell_surface_"))
    print("| shell | exported surface | triangles | max distance [h] | mean distance [h] |")
    print("|---|---|---|---|---|")
    for label, scene, t_end, h, relative in (
        ("cloth from 2 triangles, hanging 0.5 s", lambda e: hanging_sheet(folder / "sheet.obj", e), 0.5, H, False),
        ("cube from 12 triangles, 4 m/s onto the floor", lambda e: cube_scene(folder / "cube.obj", e), 0.15, CUBE_H,
         True),
    ):
        for edge, what in ((None, "refined to h"), (1.0, "the file's triangles")):
            sim = Sim(scene(edge), folder / "scene.yaml")
            worst, mean = measure(sim, t_end, h, relative)
            print(f"| {label} | {what} | {len(sim.prep.disc.meshes[0].triangles)} | {worst:.2f} | {mean:.3f} |")


if __name__ == "__main__":
    main()
