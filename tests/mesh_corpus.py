"""Mesh files as content tools write them, generated here (nothing is downloaded or committed).

`write_corpus(folder)` writes closed meshes in the forms artists hand over: Blender-style OBJ with texture and
normal indices, groups, materials and quads; OBJ n-gons; OFF with quads; STL ascii and binary (a triangle soup,
the binary one with a header that starts with "solid"); PLY binary with quads and extra vertex properties and PLY
ascii; GLB; and a box modelled in millimetres. Each comes with its exact enclosed volume and bounding box in metres
(after its `units`), computed from the same faces, so a test can check what the loader made of it.

`write_broken(folder)` writes the everyday mistakes and damaged files, each with a fragment its error message must
contain. `bench/mesh_readers.py` runs both through the candidate readers; `tests/test_mesh_input.py` through the CLI.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


@dataclass
class CorpusMesh:
    name: str  # file name inside the folder
    fmt: str  # format as a user would call it
    shows: str  # what the file exercises
    volume: float  # enclosed volume [m^3] after units
    lo: np.ndarray  # bounding box [m] after units
    hi: np.ndarray
    units: str = "m"


# ---------------------------------------------------------------------------- shapes (polygon lists, outward)
def _outward(V, faces):
    """Each face of a convex solid turned so that its normal points away from the centre."""
    V = np.asarray(V, dtype=np.float64)
    c = V.mean(axis=0)
    out = []
    for f in faces:
        P = V[list(f)]
        n = np.cross(P[1] - P[0], P[2] - P[0])
        out.append(tuple(f) if n @ (P.mean(axis=0) - c) > 0 else tuple(f[::-1]))
    return out


def polygon_volume(V, faces) -> float:
    """Enclosed volume of closed planar polygons (fan-triangulated; the fan does not matter for planar faces)."""
    V = np.asarray(V, dtype=np.float64)
    tri = np.array([(f[0], f[i], f[i + 1]) for f in faces for i in range(1, len(f) - 1)])
    a, b, c = V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def uv_sphere(radius=0.1, segments=24, rings=12, center=(0.0, 0.0, 0.0)):
    """Blender's UV sphere: quads between rings (isosceles trapezoids, planar), triangle fans at the poles.

    Returns (V, faces, uv, face_uv): `uv` has segments + 1 entries per ring (the seam is duplicated, as in every
    textured export), `face_uv` the uv index of each face corner."""
    V = [(0.0, radius, 0.0)]
    uv = []
    for j in range(1, rings):
        phi = math.pi * j / rings
        for i in range(segments):
            th = 2 * math.pi * i / segments
            rho = radius * math.sin(phi)
            V.append((rho * math.cos(th), radius * math.cos(phi), rho * math.sin(th)))
    V.append((0.0, -radius, 0.0))
    for j in range(rings + 1):
        for i in range(segments + 1):
            uv.append((i / segments, 1.0 - j / rings))
    ring = lambda j, i: 1 + (j - 1) * segments + i % segments  # noqa: E731
    tuv = lambda j, i: j * (segments + 1) + i  # noqa: E731
    faces, face_uv = [], []
    bottom = len(V) - 1
    for i in range(segments):
        faces.append((0, ring(1, i + 1), ring(1, i)))
        face_uv.append((tuv(0, i), tuv(1, i + 1), tuv(1, i)))
        for j in range(1, rings - 1):
            faces.append((ring(j, i), ring(j, i + 1), ring(j + 1, i + 1), ring(j + 1, i)))
            face_uv.append((tuv(j, i), tuv(j, i + 1), tuv(j + 1, i + 1), tuv(j + 1, i)))
        faces.append((ring(rings - 1, i), ring(rings - 1, i + 1), bottom))
        face_uv.append((tuv(rings - 1, i), tuv(rings - 1, i + 1), tuv(rings, i)))
    V = np.asarray(V) + center
    if polygon_volume(V, faces) < 0:
        faces, face_uv = [f[::-1] for f in faces], [f[::-1] for f in face_uv]
    return V, faces, np.asarray(uv), face_uv


def box_quads(size=(0.2, 0.12, 0.08), n=2, center=(0.0, 0.0, 0.0)):
    """A box whose faces are n x n quads, vertices shared."""
    size = np.asarray(size, dtype=np.float64)
    index, V, faces = {}, [], []

    def vid(p):
        key = tuple(np.round(p, 12))
        if key not in index:
            index[key] = len(V)
            V.append(p)
        return index[key]

    for axis in range(3):
        u, w = (axis + 1) % 3, (axis + 2) % 3
        for side in (-0.5, 0.5):
            for a in range(n):
                for b in range(n):
                    quad = []
                    for da, db in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = np.zeros(3)
                        p[axis] = side * size[axis]
                        p[u] = ((a + da) / n - 0.5) * size[u]
                        p[w] = ((b + db) / n - 0.5) * size[w]
                        quad.append(vid(p))
                    faces.append(tuple(quad) if side > 0 else tuple(quad[::-1]))
    V = np.asarray(V) + center
    return V, _outward(V, faces)


def prism(sides=6, radius=0.1, height=0.15):
    """A prism with two n-gon caps and quad sides."""
    ang = 2 * math.pi * np.arange(sides) / sides
    ring = np.stack([radius * np.cos(ang), radius * np.sin(ang)], 1)
    V = np.array([(x, z, y) for z in (-0.5 * height, 0.5 * height) for x, y in ring])
    faces = [tuple(range(sides)), tuple(range(sides, 2 * sides))]
    faces += [(i, (i + 1) % sides, (i + 1) % sides + sides, i + sides) for i in range(sides)]
    return V, _outward(V, faces)


def icosphere(subdivisions: int, radius: float = 1.0):
    """Icosahedron subdivided and projected on the sphere: 20 * 4**s outward (counter-clockwise) triangles."""
    t = (1.0 + 5.0**0.5) / 2.0
    base = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
            (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    V = [np.array(v, float) / np.linalg.norm(v) for v in base]
    for _ in range(subdivisions):
        cache, new = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = V[a] + V[b]
                V.append(m / np.linalg.norm(m))
                cache[key] = len(V) - 1
            return cache[key]

        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return radius * np.array(V), np.array(faces, dtype=np.int64)


def bowl(outer=0.2, inner=0.16, edge=0.02):
    """A hemispherical bowl as a closed solid, rim at y = 0, opening upwards (geometry.primitive_surfaces)."""
    from pdmpm_cli.geometry.primitive_surfaces import bowl_surface

    mesh = bowl_surface(outer, inner, edge)
    return mesh.vertices, mesh.triangles


def torus(R=1.0, r=0.35, nu=48, nv=24):
    """A torus about the z axis, of outward triangles (each grid quad split in two: the quads are not planar)."""
    u, v = np.meshgrid(np.arange(nu) * 2 * np.pi / nu, np.arange(nv) * 2 * np.pi / nv, indexing="ij")
    V = np.stack([(R + r * np.cos(v)) * np.cos(u), (R + r * np.cos(v)) * np.sin(u), r * np.sin(v)], -1).reshape(-1, 3)
    idx = lambda i, j: (i % nu) * nv + (j % nv)  # noqa: E731
    faces = []
    for i in range(nu):
        for j in range(nv):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            faces += [(a, b, c), (a, c, d)]
    T = np.array(faces, dtype=np.int64)
    return V, T if polygon_volume(V, T) > 0 else T[:, ::-1].copy()


# ---------------------------------------------------------------------------- writers
def _f(x) -> str:
    return f"{x:.6f}"


def write_obj_blender(path: Path, V, faces, uv=None, face_uv=None, groups=None, mtl=True, name="Sphere"):
    """OBJ as Blender 4 writes it: header, mtllib, o, v, vn, vt, s, usemtl, `f v/vt/vn`; optional `g` groups
    (a list of (group name, material, face indices))."""
    V = np.asarray(V)
    normals = V - V.mean(axis=0)
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    lines = ["# Blender 4.1.1", "# www.blender.org", f"mtllib {path.stem}.mtl", f"o {name}"]
    lines += [f"v {_f(x)} {_f(y)} {_f(z)}" for x, y, z in V]
    lines += [f"vn {_f(x)} {_f(y)} {_f(z)}" for x, y, z in normals]
    if uv is not None:
        lines += [f"vt {_f(s)} {_f(t)}" for s, t in uv]
    lines.append("s 1")
    groups = groups or [(None, "Material", list(range(len(faces))))]
    for group, material, members in groups:
        if group:
            lines.append(f"g {group}")
        lines.append(f"usemtl {material}")
        for k in members:
            f = faces[k]
            if uv is not None:
                corners = [f"{v + 1}/{t + 1}/{v + 1}" for v, t in zip(f, face_uv[k])]
            else:
                corners = [f"{v + 1}//{v + 1}" for v in f]
            lines.append("f " + " ".join(corners))
    path.write_text("\n".join(lines) + "\n")
    if mtl:
        mats = sorted({m for _, m, _ in groups})
        path.with_suffix(".mtl").write_text("".join(f"newmtl {m}\nKd 0.8 0.8 0.8\n\n" for m in mats))
    return path


def write_off(path: Path, V, faces):
    lines = ["OFF", "# written by the pdmpm test corpus", f"{len(V)} {len(faces)} 0"]
    lines += [f"{_f(x)} {_f(y)} {_f(z)}" for x, y, z in V]
    lines += [f"{len(f)} " + " ".join(map(str, f)) for f in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def _soup(V, faces):
    tri = np.array([(f[0], f[i], f[i + 1]) for f in faces for i in range(1, len(f) - 1)])
    P = np.asarray(V)[tri]
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    return P, n / np.linalg.norm(n, axis=1)[:, None]


def write_stl_ascii(path: Path, V, faces, name="icosphere"):
    P, N = _soup(V, faces)
    lines = [f"solid {name}"]
    for p, n in zip(P, N):
        lines += [f"  facet normal {n[0]:e} {n[1]:e} {n[2]:e}", "    outer loop"]
        lines += [f"      vertex {x:e} {y:e} {z:e}" for x, y, z in p]
        lines += ["    endloop", "  endfacet"]
    lines.append(f"endsolid {name}")
    path.write_text("\n".join(lines) + "\n")
    return path


def write_stl_binary(path: Path, V, faces, header=b"solid exported by a CAD tool (binary!)"):
    P, N = _soup(V, faces)
    rec = np.zeros(len(P), dtype=[("n", "<f4", 3), ("p", "<f4", (3, 3)), ("attr", "<u2")])
    rec["n"], rec["p"] = N, P
    with open(path, "wb") as f:
        f.write(header.ljust(80, b" ")[:80] + struct.pack("<I", len(P)) + rec.tobytes())
    return path


def write_ply(path: Path, V, faces, binary=True):
    """PLY as Blender writes it: x y z nx ny nz s t and rgb per vertex, `list uchar uint vertex_indices`."""
    V = np.asarray(V, dtype=np.float64)
    n = V - V.mean(axis=0)
    n /= np.linalg.norm(n, axis=1)[:, None]
    fmt = "binary_little_endian" if binary else "ascii"
    header = ["ply", f"format {fmt} 1.0", "comment Created in Blender version 4.1.1", f"element vertex {len(V)}",
              "property float x", "property float y", "property float z", "property float nx", "property float ny",
              "property float nz", "property float s", "property float t", "property uchar red",
              "property uchar green", "property uchar blue", f"element face {len(faces)}",
              "property list uchar uint vertex_indices", "end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        if binary:
            rec = np.zeros(len(V), dtype=[("x", "<f4", 3), ("n", "<f4", 3), ("st", "<f4", 2), ("rgb", "u1", 3)])
            rec["x"], rec["n"], rec["rgb"] = V, n, 200
            f.write(rec.tobytes())
            for face in faces:
                f.write(struct.pack("<B", len(face)) + np.asarray(face, dtype="<u4").tobytes())
        else:
            rows = [f"{_f(x)} {_f(y)} {_f(z)} {_f(a)} {_f(b)} {_f(c)} 0 0 200 200 200"
                    for (x, y, z), (a, b, c) in zip(V, n)]
            rows += [f"{len(face)} " + " ".join(map(str, face)) for face in faces]
            f.write(("\n".join(rows) + "\n").encode("ascii"))
    return path


def write_glb(path: Path, V, faces):
    """Binary glTF with one triangle mesh (through trimesh's exporter)."""
    import trimesh

    tri = np.array([(f[0], f[i], f[i + 1]) for f in faces for i in range(1, len(f) - 1)])
    trimesh.Trimesh(np.asarray(V), tri, process=False).export(path)
    return path


def _entry(name, fmt, shows, V, faces, units="m"):
    s = UNITS[units]
    V = np.asarray(V, dtype=np.float64)
    return CorpusMesh(name, fmt, shows, polygon_volume(V, faces) * s**3, V.min(axis=0) * s, V.max(axis=0) * s, units)


def write_corpus(folder: Path) -> list[CorpusMesh]:
    """Write every closed corpus mesh into `folder`; returns their descriptions."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    V, F, uv, fuv = uv_sphere()
    half = len(F) // 2
    groups = [("upper", "Red", list(range(half))), ("lower", "Blue", list(range(half, len(F))))]
    write_obj_blender(folder / "uv_sphere.obj", V, F, uv, fuv, groups=groups)
    out.append(_entry("uv_sphere.obj", "OBJ", "Blender header, v/vt/vn, quads + pole triangles, groups, 2 materials",
                      V, F))
    V, F = prism()
    write_obj_blender(folder / "hex_prism.obj", V, F, mtl=False, name="Prism")
    out.append(_entry("hex_prism.obj", "OBJ", "hexagon n-gons, v//vn, mtllib naming a missing file", V, F))
    V, F = box_quads(n=3)
    write_off(folder / "box_quads.off", V, F)
    out.append(_entry("box_quads.off", "OFF", "quads, a comment line", V, F))
    V, F = icosphere(2, 0.1)
    write_stl_ascii(folder / "icosphere_ascii.stl", V, F)
    out.append(_entry("icosphere_ascii.stl", "STL ascii", "triangle soup (every vertex repeated)", V, F))
    V, F = torus(0.1, 0.04, 32, 16)
    write_stl_binary(folder / "torus_binary.stl", V, F)
    out.append(_entry("torus_binary.stl", "STL binary", "triangle soup, float32, header starting with 'solid'",
                      V, F))
    V, F, _, _ = uv_sphere(segments=16, rings=8)
    write_ply(folder / "uv_sphere_binary.ply", V, F)
    out.append(_entry("uv_sphere_binary.ply", "PLY binary", "quads + triangles, normals, uv and colour properties",
                      V, F))
    V, F = icosphere(1, 0.1)
    write_ply(folder / "icosphere_ascii.ply", V, F, binary=False)
    out.append(_entry("icosphere_ascii.ply", "PLY ascii", "triangles, extra vertex properties", V, F))
    V, F = box_quads(size=(0.15, 0.1, 0.12), n=1)
    write_glb(folder / "box.glb", V, F)
    out.append(_entry("box.glb", "glTF binary", "one triangle mesh", V, F))
    V, F = box_quads(size=(100.0, 60.0, 40.0), n=2, center=(50.0, 30.0, 20.0))
    write_obj_blender(folder / "box_mm.obj", V, F, name="Part")
    out.append(_entry("box_mm.obj", "OBJ", "modelled in millimetres (100 x 60 x 40 mm), corner at the origin", V, F,
                      units="mm"))
    return out


# ---------------------------------------------------------------------------- broken files
def write_broken(folder: Path, rng=None) -> list[tuple[str, str]]:
    """Write damaged meshes and everyday mistakes; returns (file name, fragment the error message must contain)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = rng or np.random.default_rng(0)
    cases = []

    def add(name, expect):
        cases.append((name, expect))

    for ext in ("obj", "stl", "ply", "off", "glb"):
        (folder / f"garbage.{ext}").write_bytes(bytes(rng.integers(0, 256, 3000, dtype=np.uint8)))
        add(f"garbage.{ext}", "export it again")
    (folder / "empty.obj").write_text("")
    add("empty.obj", "empty")
    (folder / "folder.obj").mkdir(exist_ok=True)
    add("folder.obj", "is a folder")
    add("missing.obj", "not found")
    (folder / "nan.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n")
    add("nan.obj", "NaN")
    V, F = box_quads()
    text = write_obj_blender(folder / "huge_index.obj", V, F, mtl=False).read_text()
    (folder / "huge_index.obj").write_text(text + "f 1//1 2//2 99999999999//1\n")
    add("huge_index.obj", "could not be read as an OBJ")
    head = (b"ply\nformat binary_little_endian 1.0\nelement vertex 100000000000\nproperty float x\nproperty float y\n"
            b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n")
    (folder / "huge_count.ply").write_bytes(head + b"\0" * 64)
    add("huge_count.ply", "could not be read as a PLY")
    good = write_stl_binary(folder / "truncated.stl", *icosphere(2, 0.1)).read_bytes()
    (folder / "truncated.stl").write_bytes(good[: len(good) // 2])
    add("truncated.stl", "truncated")
    V, F = box_quads(n=2)
    write_obj_blender(folder / "holes.obj", V, F[:-2], mtl=False)
    add("holes.obj", "Fill Holes")
    write_obj_blender(folder / "flipped_face.obj", V, F[:3] + [F[3][::-1]] + F[4:], mtl=False)
    add("flipped_face.obj", "Recalculate Outside")
    write_obj_blender(folder / "non_manifold.obj", V, F + [F[0][::-1], F[0]], mtl=False)  # a face doubled
    add("non_manifold.obj", "non-manifold")
    P, _ = _soup(*box_quads(n=2))
    jitter = rng.uniform(-1e-5, 1e-5, P.shape)  # every corner stored separately, 1e-5 m apart
    write_stl_binary(folder / "unmerged.stl", *_soup_faces(P.reshape(-1, 3) + jitter.reshape(-1, 3)))
    add("unmerged.stl", "Merge by Distance")
    (folder / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 3 2\n")
    add("flat.obj", "zero volume")
    (folder / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    add("points.obj", "no faces")
    (folder / "shape.xyz").write_text("0 0 0\n1 0 0\n")
    add("shape.xyz", "file extension")
    (folder / "latin1.obj").write_bytes("# modèle\nv 0 0 0\n".encode("latin-1") + b"\xff\xfe\x00garbage\n")
    add("latin1.obj", "latin1.obj")
    return cases


def _soup_faces(points):
    """(V, faces) of a triangle soup whose consecutive triples of points are the triangles."""
    return points, [(3 * i, 3 * i + 1, 3 * i + 2) for i in range(len(points) // 3)]
