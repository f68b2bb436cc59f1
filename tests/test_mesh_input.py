"""Mesh files as artists have them: every corpus mesh validates and fills, every damaged one is refused with exit
code 2 and a message naming the scene's line, the key, the mesh file and the fix; placement by units and fit;
bodies too large for the domain refused before sampling; warnings where the particles are not what was drawn."""

import io
import sys
import textwrap
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
import pytest

from pdmpm_cli.cli.app import main
from pdmpm_cli.errors import InputError
from pdmpm_cli import runner
from pdmpm_cli.runner import prepare
from tests.mesh_corpus import write_broken, write_corpus
from tests.test_cli import pdmpm

H = 0.01  # particle spacing [m]; corpus shapes are about 0.2 m across


def scene(shape: str, mode: str = "cloud", extra: str = "", domain: float = 0.6) -> str:
    key = "surface" if mode == "shell" else "shape"
    return textwrap.dedent(f"""\
        simulation: {{duration: 0.1}}
        grid: {{cell_size: 0.04, domain: {{min: [0, 0, 0], max: [{domain}, {domain}, {domain}]}}}}
        bodies:
          - name: part
            geometry:
              mode: {mode}
              spacing: {H}
              {key}: {shape}
              {extra}
            material: {{model: elastic, density: 1000, lam: 1e4, mu: 1e4}}
        """)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("corpus")
    return folder, write_corpus(folder / "good"), write_broken(folder / "broken")


def cli(*args) -> tuple[int, str, str]:
    """`pdmpm ARGS` through the console entry point, in this process (a process each would cost a minute):
    (exit code, stdout, stderr)."""
    out, err, argv = io.StringIO(), io.StringIO(), sys.argv
    sys.argv = ["pdmpm", *map(str, args)]
    try:
        with redirect_stderr(err), redirect_stdout(out):
            main()
        code = 0
    except SystemExit as e:
        code = e.code
    finally:
        sys.argv = argv
    return code, out.getvalue(), err.getvalue()


def test_corpus_meshes_validate_and_fill(corpus):
    """OBJ (Blender header, v/vt/vn, groups, materials, quads, n-gons), OFF quads, STL ascii/binary, PLY, GLB and
    a millimetre mesh: the particles' volume is the mesh's exact volume within 3 %, inside the drawn box."""
    folder, meshes, _ = corpus
    for m in meshes:
        c = 0.5 * (m.lo + m.hi)
        shift = ", ".join(f"{0.3 - v:.6f}" for v in c)
        path = folder / "s.yaml"
        path.write_text(scene(f"{{type: mesh, path: good/{m.name}, units: {m.units}, translate: [{shift}]}}",
                              extra="sampling: jittered"))
        prep = prepare(path)
        volume = prep.disc.volume.sum()
        assert volume == pytest.approx(m.volume, rel=0.03), m.name
        x = prep.disc.rest_x - 0.3 + c
        assert np.all(x >= m.lo - 1e-9) and np.all(x <= m.hi + 1e-9), m.name


def test_broken_meshes_exit_2_with_position_key_file_and_fix(corpus):
    """Garbage bytes, empty files, a folder, a missing file, NaN coordinates, huge indices, truncated files, holes,
    flipped and non-manifold faces, unmerged duplicates, flat and point-only files, unknown extensions: exit code 2,
    one `error:` line naming scene file:line:col, the dotted key, the mesh file and a fix; never a traceback."""
    folder, _, broken = corpus
    path = folder / "broken.yaml"
    path.write_text(scene("{type: mesh, path: PLACEHOLDER, translate: [0.3, 0.3, 0.3]}"))
    line = next(i for i, text in enumerate(path.read_text().splitlines(), 1) if "PLACEHOLDER" in text)
    col = path.read_text().splitlines()[line - 1].index("PLACEHOLDER") + 1
    for name, expect in broken:
        path.write_text(scene(f"{{type: mesh, path: broken/{name}, translate: [0.3, 0.3, 0.3]}}"))
        code, _, err = cli("validate", path)
        assert code == 2, (name, err)
        assert err.startswith(f"error: {path}:{line}:{col} bodies.0.geometry.shape.path: "), (name, err)
        assert str(folder / "broken" / name) in err and "Fix:" in err and expect in err, (name, err)
        assert "Traceback" not in err


def test_broken_mesh_through_a_process(corpus):
    """The same as a user runs it: a separate process, no traceback, the error on stderr, exit code 2; a path set
    with --set is pointed at the --set."""
    folder, _, _ = corpus
    path = folder / "garbage.yaml"
    path.write_text(scene("{type: mesh, path: broken/garbage.stl, translate: [0.3, 0.3, 0.3]}"))
    r = pdmpm("validate", path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"{path}:8:" in r.stderr and "bodies.0.geometry.shape.path" in r.stderr and "garbage.stl" in r.stderr
    r = pdmpm("validate", path, "--set", "bodies.0.geometry.shape.path=broken/box_quads.off")
    assert r.returncode == 2 and "error: --set bodies.0.geometry.shape.path: mesh file not found" in r.stderr


def test_millimetre_mesh_by_units_and_fit(corpus):
    """A 100 x 60 x 40 mm part: with units: mm it is 0.1 m long where it was drawn (corner at the translation);
    with fit it is scaled to the given size and centred; per-axis scale stretches it."""
    folder, meshes, _ = corpus
    path = folder / "mm.yaml"
    cases = {
        "units: mm, translate: [0.2, 0.2, 0.2]": ([0.2, 0.2, 0.2], [0.3, 0.26, 0.24]),
        "fit: {size: 0.25, center: [0.3, 0.3, 0.3]}": ([0.175, 0.225, 0.25], [0.425, 0.375, 0.35]),
        "units: mm, scale: [1, 2, 1], fit: {size: 0.06, axis: z, center: [0.3, 0.3, 0.3]}":
            ([0.225, 0.21, 0.27], [0.375, 0.39, 0.33]),
    }
    for placement, (lo, hi) in cases.items():
        path.write_text(scene(f"{{type: mesh, path: good/box_mm.obj, {placement}}}", extra="sampling: lattice"))
        x = prepare(path).disc.rest_x
        assert np.allclose(x.min(axis=0), lo, atol=0.51 * H) and np.allclose(x.max(axis=0), hi, atol=0.51 * H), \
            placement


def test_body_larger_than_the_domain_is_refused_before_sampling(corpus, monkeypatch):
    """The millimetre part read as metres is 100 m wide: refused before anything is sampled (wall time:
    bench/hostile_inputs.py), with both sizes and the units fix, pointing at the shape."""
    folder, _, _ = corpus
    monkeypatch.setattr(runner, "discretize", lambda *a: pytest.fail("sampled"))
    path = folder / "big.yaml"
    path.write_text(scene("{type: mesh, path: good/box_mm.obj}").replace(f"spacing: {H}", "spacing: 0.002"))
    with pytest.raises(InputError) as e:
        prepare(path)
    msg = str(e.value)
    assert f"{path}:8:7 bodies.0.geometry.shape: body 'part' is 100 m wide (along x), but the domain is 0.6 m" in msg
    assert "set units: mm" in msg
    path.write_text(scene("{type: box, center: [0.3, 0.3, 0.3], size: [0.2, 3.0, 0.2]}"))
    with pytest.raises(InputError, match=r"body 'part' is 3 m tall \(along y\), but the domain is 0.6 m"):
        prepare(path)


def test_cloud_mode_reports_repairs_and_thin_features(tmp_path):
    """An inside-out OBJ is flipped and said so in cloud mode too; a plate thinner than the spacing is reported
    with the body's name and how many particles are loose or one particle thick; `validate` prints them."""
    from tests.mesh_corpus import box_quads, write_obj_blender

    V, F = box_quads(size=(0.2, 0.2, 0.2), n=1, center=(0.3, 0.3, 0.3))
    write_obj_blender(tmp_path / "inside_out.obj", V, [f[::-1] for f in F], mtl=False)
    path = tmp_path / "s.yaml"
    path.write_text(scene("{type: mesh, path: inside_out.obj}", extra="sampling: jittered"))
    notes = prepare(path).plan.notes
    assert any("body 'part': flipped all faces" in n for n in notes), notes
    V, F = box_quads(size=(0.2, 0.2, 0.006), n=1, center=(0.3, 0.3, 0.3))
    write_obj_blender(tmp_path / "plate.obj", V, F, mtl=False)
    path.write_text(scene("{type: mesh, path: plate.obj}", extra="sampling: jittered"))
    prep = prepare(path)
    n = prep.disc.n_particles
    loose = [x for x in prep.plan.notes if "fewer than 4 bonds" in x]
    flat = [x for x in prep.plan.notes if "one particle thick" in x]
    assert loose and flat and all(x.startswith("body 'part': ") for x in loose + flat)
    count = np.diff(prep.disc.bond_start)
    assert f"{int((count < 4).sum())} of {n} particles have fewer than 4 bonds ({int((count == 0).sum())} have none)" \
        in loose[0]
    code, out, _ = cli("validate", path)
    assert code == 0 and out.count("warning: body 'part': ") == 2
    thick = scene("{type: box, center: [0.3, 0.3, 0.3], size: [0.2, 0.2, 0.1]}", extra="sampling: jittered")
    path.write_text(thick)
    assert prepare(path).plan.notes == ()
