"""Which mesh reader should pdmpm use? trimesh, meshio and a small reader of our own on the test corpus.

    python bench/mesh_readers.py

Every corpus file (tests/mesh_corpus.py: closed meshes as content tools write them, and damaged files) goes
through each reader, then through pdmpm's own validation (weld, closed, manifold, oriented). The first table says
per closed file whether the reader's triangles validate and how far their volume is from the file's exact volume;
the second says per damaged file whether the reader raised an exception (which pdmpm can turn into a message),
returned nothing, or exited the process / returned wrong data, and then the total read time. The last table is
pdmpm itself (the readers it chose, as a `mode: cloud` body at spacing 0.01 m): the reader, the loaded mesh's
volume error and the volume error of the particles that fill it, and for the damaged files the start of the
message (exit code 2).
"""

from __future__ import annotations

import re
import struct
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pdmpm_cli.errors import InputError  # noqa: E402
from pdmpm_cli.geometry.mesh import mesh_volume, validate_surface, SurfaceMesh  # noqa: E402
from tests.mesh_corpus import write_broken, write_corpus  # noqa: E402


def fan(faces):
    return np.array([(f[0], f[i], f[i + 1]) for f in faces for i in range(1, len(f) - 1)], dtype=np.int64)


# ---------------------------------------------------------------------------- readers under test
def read_trimesh(path):
    import trimesh

    m = trimesh.load(str(path), force="mesh", process=False)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64).reshape(-1, 3)


def read_meshio(path):
    import meshio

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = meshio.read(str(path))
    faces = []
    for block in m.cells:
        if block.type in ("triangle", "quad") or block.type.startswith("polygon"):
            faces += [tuple(f) for f in block.data]
    return np.asarray(m.points, dtype=np.float64), fan(faces)


def read_own(path):
    """A minimal reader of the four text/binary formats, as pdmpm would have to maintain it."""
    ext = Path(path).suffix.lower()
    data = Path(path).read_bytes()
    if ext == ".obj":
        V, faces = [], []
        for line in data.decode("utf-8").splitlines():
            parts = line.split()
            if parts and parts[0] == "v":
                V.append([float(x) for x in parts[1:4]])
            elif parts and parts[0] == "f":
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                faces.append([i - 1 if i > 0 else len(V) + i for i in idx])
        return np.asarray(V, dtype=np.float64).reshape(-1, 3), fan(faces) if faces else np.zeros((0, 3), np.int64)
    if ext == ".off":
        tokens = [t for line in data.decode("utf-8").splitlines() for t in line.split("#")[0].split()]
        if not tokens or tokens[0] != "OFF":
            raise ValueError("not an OFF file")
        nv, nf = int(tokens[1]), int(tokens[2])
        V = np.asarray(tokens[4: 4 + 3 * nv], dtype=np.float64).reshape(nv, 3)
        pos, faces = 4 + 3 * nv, []
        for _ in range(nf):
            k = int(tokens[pos])
            faces.append([int(t) for t in tokens[pos + 1: pos + 1 + k]])
            pos += 1 + k
        return V, fan(faces)
    if ext == ".stl":
        if len(data) >= 84 and 84 + 50 * struct.unpack("<I", data[80:84])[0] == len(data):
            n = struct.unpack("<I", data[80:84])[0]
            rec = np.frombuffer(data, dtype=[("n", "<f4", 3), ("p", "<f4", (3, 3)), ("a", "<u2")], count=n, offset=84)
            return rec["p"].reshape(-1, 3).astype(np.float64), np.arange(3 * n).reshape(-1, 3)
        P = [[float(x) for x in m.groups()] for m in re.finditer(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)", data)]
        return np.asarray(P, dtype=np.float64).reshape(-1, 3), np.arange(len(P)).reshape(-1, 3)
    if ext == ".ply":
        end = data.index(b"end_header\n") + len(b"end_header\n")
        header = data[:end].decode("ascii").splitlines()
        binary = "binary_little_endian" in header[1]
        elements, cur = [], None
        for line in header[2:]:
            p = line.split()
            if p[0] == "element":
                cur = (p[1], int(p[2]), [])
                elements.append(cur)
            elif p[0] == "property":
                cur[2].append(p[1:])
        sizes = {"float": "<f4", "double": "<f8", "uchar": "u1", "int": "<i4", "uint": "<u4", "short": "<i2",
                 "ushort": "<u2", "char": "i1", "float32": "<f4", "uint8": "u1", "int32": "<i4", "uint32": "<u4"}
        V, faces, body = None, [], data[end:]
        tokens = body.decode("ascii").split() if not binary else None
        pos = 0
        for name, count, props in elements:
            if name == "vertex":
                if binary:
                    dt = np.dtype([(p[-1], sizes[p[0]]) for p in props])
                    rec = np.frombuffer(body, dtype=dt, count=count, offset=pos)
                    pos += dt.itemsize * count
                else:
                    rec = np.asarray(tokens[pos: pos + count * len(props)], dtype=np.float64).reshape(count, -1)
                    rec = {p[-1]: rec[:, i] for i, p in enumerate(props)}
                    pos += count * len(props)
                V = np.stack([np.asarray(rec[a], dtype=np.float64) for a in "xyz"], 1)
            elif name == "face":
                _, ct, it, _ = props[0]
                for _ in range(count):
                    if binary:
                        k = int(np.frombuffer(body, dtype=sizes[ct], count=1, offset=pos)[0])
                        pos += np.dtype(sizes[ct]).itemsize
                        faces.append(np.frombuffer(body, dtype=sizes[it], count=k, offset=pos).tolist())
                        pos += np.dtype(sizes[it]).itemsize * k
                    else:
                        k = int(tokens[pos])
                        faces.append([int(t) for t in tokens[pos + 1: pos + 1 + k]])
                        pos += 1 + k
        return V, fan(faces)
    raise ValueError(f"unknown extension {ext}")


READERS = {"trimesh": read_trimesh, "meshio": read_meshio, "own": read_own}


def attempt(reader, path):
    """('ok', (V, T)) | ('error', message) | ('exit', message): SystemExit is what breaks a CLI."""
    try:
        return "ok", reader(path)
    except SystemExit as e:
        return "exit", f"sys.exit({e.code})"
    except Exception as e:  # noqa: BLE001 - measuring what each reader raises
        return "error", f"{type(e).__name__}: {str(e)[:60]}"


def main():
    folder = Path(tempfile.mkdtemp(prefix="pdmpm_corpus_"))
    corpus = write_corpus(folder / "good")
    broken = write_broken(folder / "broken")
    rows, totals = [], {name: 0.0 for name in READERS}
    print("closed meshes: does the reader's output validate, and its volume error against the exact volume")
    print(f"| {'file':22s} | {'format':11s} | " + " | ".join(f"{r:28s}" for r in READERS) + " |")
    print("|" + "---|" * (2 + len(READERS)))
    for m in corpus:
        cells = []
        for name, reader in READERS.items():
            t0 = time.perf_counter()
            status, result = attempt(reader, folder / "good" / m.name)
            totals[name] += time.perf_counter() - t0
            if status != "ok":
                cells.append(f"{status}: {result}"[:28])
                continue
            V, T = result
            try:
                V, T, _ = validate_surface(V * {"m": 1.0, "mm": 1e-3}[m.units], T, m.name)
                err = mesh_volume(SurfaceMesh(V, T)) / m.volume - 1.0
                cells.append(f"ok, volume {100 * err:+.1e} %")
            except InputError as e:
                cells.append(f"invalid: {str(e).split(':')[1][:18]}")
        rows.append(cells)
        print(f"| {m.name:22s} | {m.fmt:11s} | " + " | ".join(f"{c:28s}" for c in cells) + " |")
    print("\ndamaged files: error (an exception pdmpm can word), exit (the process ends), accepted (data returned)")
    print(f"| {'file':22s} | " + " | ".join(f"{r:34s}" for r in READERS) + " |")
    print("|" + "---|" * (1 + len(READERS)))
    for name, _ in broken:
        path = folder / "broken" / name
        cells = []
        for rname, reader in READERS.items():
            status, result = attempt(reader, path)
            if status == "ok":
                V, T = result
                result = f"{len(V)} vertices, {len(T)} triangles"
                status = "accepted"
            cells.append(f"{status}: {result}"[:34])
        print(f"| {name:22s} | " + " | ".join(f"{c:34s}" for c in cells) + " |")
    print("\nread time over the closed corpus: " + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in totals.items()))
    pdmpm_table(folder, corpus, broken)


SCENE = """simulation: {{duration: 0.1}}
grid: {{cell_size: 0.04, domain: {{min: [0, 0, 0], max: [0.6, 0.6, 0.6]}}}}
bodies:
  - name: part
    geometry: {{mode: cloud, spacing: 0.01, sampling: jittered, shape: {shape}}}
    material: {{model: elastic, density: 1000, lam: 1e4, mu: 1e4}}
"""


def pdmpm_table(folder, corpus, broken):
    from pdmpm_cli.geometry.mesh import TRIMESH_FORMATS
    from pdmpm_cli.runner import prepare

    print("\npdmpm (the chosen readers), closed meshes as cloud bodies at h = 0.01 m")
    print("| file | format | reader | mesh volume error | particle volume error | notes |")
    print("|---|---|---|---|---|---|")
    path = folder / "scene.yaml"
    for m in corpus:
        c = 0.5 * (m.lo + m.hi)
        shift = ", ".join(f"{0.3 - v:.6f}" for v in c)
        path.write_text(SCENE.format(shape=f"{{type: mesh, path: good/{m.name}, units: {m.units}, "
                                           f"translate: [{shift}]}}"))
        prep = prepare(path)
        from pdmpm_cli.discretize import load_mesh_shape

        mesh = load_mesh_shape(prep.scene.bodies[0].geometry.shape, folder)
        reader = "trimesh" if Path(m.name).suffix in TRIMESH_FORMATS else "meshio"
        err_mesh = mesh_volume(mesh) / m.volume - 1.0
        err_fill = prep.disc.volume.sum() / m.volume - 1.0
        notes = "; ".join(n.removeprefix("body 'part': ") for n in prep.plan.notes) or "-"
        print(f"| {m.name} | {m.fmt} | {reader} | {100 * err_mesh:+.1e} % | {100 * err_fill:+.2f} % | {notes} |")
    print("\npdmpm on the damaged files (all exit code 2)")
    print("| file | message (after the scene's file:line:col and key) |")
    print("|---|---|")
    for name, _ in broken:
        path.write_text(SCENE.format(shape=f"{{type: mesh, path: broken/{name}, translate: [0.3, 0.3, 0.3]}}"))
        try:
            prepare(path)
            message = "ACCEPTED"
        except InputError as e:
            message = str(e).split(" bodies.0.geometry.shape.path: ")[-1].replace(str(folder / "broken") + "/", "")
        print(f"| {name} | {message[:110]}{'...' if len(message) > 110 else ''} |")


if __name__ == "__main__":
    main()
