"""An emitter pours a liquid from a nozzle (engine/emitter.py): the emitted volume is rate x time, a poured pile keeps
it (measured from the particles: the settled layer's height times the tank's floor area, and sum V0 J), a resumed
run continues bitwise across births, and the outputs hold a particle count that changes between frames."""

import math
import shutil
from types import SimpleNamespace

import meshio
import numpy as np
import pytest
import yaml

from pdmpm_cli.checkpoint import restore, snapshot
from pdmpm_cli.io.hdf5 import read_run
from pdmpm_cli.io.vtk import read_pvd
from pdmpm_cli.scene.schema import Scene
from tests import fluid_cases as F
from tests.conftest import merge


def rate_of(scene) -> float:
    return scene["bodies"][0]["emitter"]["rate"]


def test_emitted_volume_is_rate_times_time(sim_factory):
    """Born particles of volume h^3: at every frame the emitted volume is rate x t to within one layer (layers are
    due at k T, T = N h^3 / rate, and born in the step that starts at or after it), within 1 % once 100 layers are
    out, and exactly at a multiple of T."""
    scene = F.pour(1.0, dx=0.02, radius=0.01, speed=0.2, fill=0.5)  # a 4-particle layer every 0.1 s / 2 = 0.05 s
    sim = sim_factory(base=scene)
    em, n0, rate = sim.model.emitter, sim.plan.particles, rate_of(scene)
    layer = len(em.layer) * em.volume
    for t in np.arange(0.05, 1.0001, 0.05):
        sim.advance(t)
        emitted = (sim.model.n_particles - n0) * em.volume
        assert abs(emitted - rate * t) <= layer * (1 + 1e-9)
    assert emitted == pytest.approx(rate * 1.0, rel=1e-9)
    assert sim.plan.emitted == sim.model.n_particles - n0  # the Plan's capacity is what was born


def test_poured_pile_keeps_its_volume(sim_factory):
    """A thin stream poured onto the floor of a square tank (slip walls) for 100.5 layer intervals, then left to
    settle: the emitted volume is rate x time within 1 % when the pouring stops, and the pile's volume, sum V0 J (as
    for the column at rest in tests/test_fluids.py), equals the poured volume within 3 %. The volume from positions
    (mean surface height x the tank's area) is printed: the pile is about three spacings deep, so that measure is
    rough (docs/results.md, 'Liquids')."""
    tank, stop = 0.12, 100.5 * 0.02
    scene = F.pour(stop + 0.4, radius=0.01, speed=0.5, tank=tank, height=0.2, stop=stop)
    sim = sim_factory(base=scene)
    em, rate, h = sim.model.emitter, rate_of(scene), sim.model.bodies[0].spacing
    assert em.interval == pytest.approx(0.02)
    plug = sim.plan.particles * h**3
    sim.advance(stop)
    emitted = (sim.model.n_particles - sim.plan.particles) * em.volume
    sim.advance(scene["simulation"]["duration"])
    x, poured = sim.state.particle_x, plug + rate * stop
    by_j = float(sim.model.particle_volume @ sim.state.particle_J)
    by_x = F.surface_height(x, h, 0.1) * tank**2
    print(f"\nemitted {emitted / (rate * stop) - 1:+.2%} of rate x time; pile: sum V0 J {by_j / poured - 1:+.2%}, "
          f"surface height x area {by_x / poured - 1:+.2%} of the poured volume, nearest spacing "
          f"{F.nearest_spacing(x) / h:.2f} h; top {x[:, 1].max() - 0.1:.3f} m, "
          f"width {np.ptp(x[:, 0]):.3f} m, speed {np.abs(sim.state.particle_v).max():.3g} m/s")
    assert emitted == pytest.approx(rate * stop, rel=0.01)
    assert by_j == pytest.approx(poured, rel=0.03)
    assert np.ptp(x[:, 0]) > 4 * 0.02 and x[:, 1].max() < 0.1 + 0.1  # it piled and spread: no standing stream


def test_resume_across_births_is_bitwise(sim_factory):
    """A checkpoint taken after some layers were born, restored into a fresh run, continues bitwise (the State and
    the emitted count are the whole state; the Model grows to match)."""
    scene = F.pour(0.2)
    ref = sim_factory(base=scene)
    ref.advance(0.1)
    arrays, scalars = snapshot(ref.state)
    ref.advance(0.2)
    sim = sim_factory(base=scene)
    restore(SimpleNamespace(arrays=arrays, attrs=scalars, path="memory"), sim.state, sim.solver)
    sim.advance(0.2)
    assert sim.model.n_particles == ref.model.n_particles > sim.plan.particles
    for name in ("particle_x", "particle_v", "particle_J", "bond_len0", "bond_force_visc"):
        assert np.array_equal(getattr(sim.state, name), getattr(ref.state, name)), name


class Killed(Exception):
    """Stands in for a kill after a frame (the checkpoints written so far stay)."""


class KillAt:
    def __init__(self, frame):
        self.at = frame

    def start(self, plan, frame):
        pass

    def substep(self, state, dt):
        pass

    def frame(self, index, state):
        if index == self.at:
            raise Killed


def pour_run(folder, scene, reporter=None, resume=False):
    from pdmpm_cli.runner import prepare_resume, prepare_scene, simulate

    folder.mkdir(exist_ok=True)
    path = folder.parent / f"{folder.name}.yaml"
    text = yaml.safe_dump(scene)
    path.write_text(text)
    if resume:
        prep, ckpt = prepare_resume(folder)
        return simulate(prep, folder, resume=ckpt)
    return simulate(prepare_scene(Scene.model_validate(scene), path, text), folder, reporter)


@pytest.fixture(scope="module")
def poured(tmp_path_factory):
    """A pour written to run.h5, VTK and PLY (fluid surfaces): once straight through, once killed after frame 3
    (checkpoints every 2 frames) and resumed."""
    root = tmp_path_factory.mktemp("pour")
    scene = merge(F.pour(0.3), {"output": {"fields": ["particle_v", "particle_J"], "checkpoint_every": 2}})
    whole = pour_run(root / "whole", scene)
    with pytest.raises(Killed):
        pour_run(root / "resumed", scene, KillAt(3))
    pour_run(root / "resumed", scene, resume=True)
    return root, whole


def test_outputs_hold_the_count_of_each_frame(poured):
    """run.h5 records each frame's count and returns each frame at it; the static fields cover every particle the
    emitter bears; each VTU holds its frame's particles; the fluid surface PLY files follow the growing body."""
    root, state = poured
    run = read_run(root / "whole" / "run.h5")
    n = run.counts
    assert len(run) == 7 and n[0] == 24 and n[-1] == len(state.particle_x) and np.all(np.diff(n) > 0)
    assert np.all(np.diff(n) % 12 == 0)  # whole layers of the nozzle's 12 lattice points
    assert len(run.static["particle_body"]) == run.plan["particles"] + run.plan["emitted"] >= n[-1]
    for i in (0, 3, -1):
        frame = run.frame(i)
        assert {len(a) for a in frame.values()} == {n[i]} and np.isfinite(frame["particle_x"]).all()
    np.testing.assert_array_equal(run.frame(-1)["particle_x"], state.particle_x)
    entries = read_pvd(root / "whole" / "vtk" / "particles.pvd")
    assert len(entries) == 7
    for (_, name), count in zip(entries, n):
        mesh = meshio.read(root / "whole" / "vtk" / name)
        assert len(mesh.points) == count and len(mesh.point_data["particle_volume"]) == count
    plys = sorted((root / "whole" / "meshes").glob("pour_surface_*.ply"))
    assert len(plys) == 7
    assert len(meshio.read(plys[-1]).points) > len(meshio.read(plys[0]).points)


def test_resumed_pour_is_bitwise(poured):
    """Killed after frame 3 and resumed from the checkpoint of frame 2: every frame equals the uninterrupted run's,
    counts included."""
    root, _ = poured
    whole, resumed = read_run(root / "whole" / "run.h5"), read_run(root / "resumed" / "run.h5")
    np.testing.assert_array_equal(whole.counts, resumed.counts)
    for i in range(len(whole)):
        a, b = whole.frame(i), resumed.frame(i)
        for name in a:
            np.testing.assert_array_equal(a[name], b[name], err_msg=f"frame {i} {name}")


def test_render_reads_a_pour(poured, monkeypatch, capsys):
    """`pdmpm render` draws the frames of a run whose particle count grows."""
    from tests.test_render import pdmpm

    folder = root = poured[0] / "whole"
    code, err = pdmpm(monkeypatch, capsys, "render", folder, "--no-video", "--resolution", "160x120")
    assert code == 0, err
    assert len(sorted((root / "frames").glob("frame_*.png"))) == 7


def test_render_reads_a_pour_from_its_vtk_series(poured):
    """Without run.h5 `pdmpm render` reads the VTU files: every frame's particles are drawn (the last frame's
    bodies and volumes cover the earlier frames' particles)."""
    from pdmpm_cli.render.scene import present
    from pdmpm_cli.render.source import open_run

    folder = poured[0] / "vtk_only"
    shutil.copytree(poured[0] / "whole", folder, ignore=shutil.ignore_patterns("run.h5", "frames"))
    source = open_run(folder)
    last = source.read(len(source) - 1)
    assert len(source.particle_body) == len(last.x) > len(source.read(0).x)
    idx = np.flatnonzero(source.particle_body == 0)
    assert len(present(idx, last)) == len(last.x)


def with_emitter(**changes) -> dict:
    scene = F.pour(0.1)
    body = scene["bodies"][0]
    return merge(scene, {"bodies": [merge(body, {"emitter": body["emitter"] | changes})]})


@pytest.mark.parametrize("changes, message", [
    ({"rate": 0.0}, "greater than 0"),
    ({"velocity": [0, 0, 0]}, "never leave the nozzle"),
    ({"start": 0.2, "stop": 0.1}, "must be after start"),
])
def test_impossible_emitters_are_refused(changes, message):
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match=message):
        Scene.model_validate(with_emitter(**changes))


def test_emitter_needs_a_last_viscoelastic_body():
    from pydantic import ValidationError

    scene = F.pour(0.1)
    solid = {"name": "cube", "geometry": {"mode": "cloud", "shape": {"type": "box", "center": [0.2, 0.15, 0.2],
                                                                      "size": [0.04] * 3}},
             "material": {"model": "elastic", "density": 1000.0, "lam": 1e5, "mu": 1e5}}
    with pytest.raises(ValidationError, match="only the last body"):
        Scene.model_validate(merge(scene, {"bodies": [scene["bodies"][0], solid]}))
    with pytest.raises(ValidationError, match="needs a viscoelastic body"):
        Scene.model_validate(merge(scene, {"bodies": [solid | {"emitter": scene["bodies"][0]["emitter"]}]}))


def test_a_rate_the_nozzle_cannot_pass_is_refused(tmp_path):
    """Continuity: a 12-point layer one spacing thick passes at most 12 h^2 |v| (m^3/s); twice that is refused with
    the largest rate, at the scene key; so are the CUDA backend and USD output."""
    from pdmpm_cli.errors import InputError, SceneValueError
    from pdmpm_cli.runner import prepare_scene

    scene = F.pour(0.1)
    most = scene["bodies"][0]["emitter"]["rate"]
    with pytest.raises(SceneValueError, match=f"use rate <= {most:.4g}") as err:
        prepare_scene(Scene.model_validate(with_emitter(rate=2 * most)), tmp_path / "s.yaml")
    assert err.value.key == ("bodies", 0, "emitter", "rate")
    with pytest.raises(InputError, match="CPU backend only"):
        prepare_scene(Scene.model_validate(merge(scene, {"simulation": {"backend": "cuda"}})), tmp_path / "s.yaml")
    with pytest.raises(InputError, match="output.usd"):
        prepare_scene(Scene.model_validate(merge(scene, {"output": {"usd": True}})), tmp_path / "s.yaml")


def test_pours_are_stable_with_the_automatic_step():
    """The stability sweep's pours (pdmpm_cli/stability.py): a fast one (5 m/s) onto the floor and one onto a plate
    sliding away, stable with the automatic step, the born particles' energy counted in the start."""
    from pdmpm_cli import stability as st

    for case in st.select(["fluid_pour_fast", "fluid_pour_plate"]):
        row = st.run_case(case)
        assert row["class"] == "stable", row
        assert row["particles"] > 400 and row["dt_ratio"] <= 0.4 + 1e-9 and row["cells_per_step"] < 0.1, row


def test_a_nozzle_outside_the_domain_is_refused(tmp_path):
    from pdmpm_cli.errors import SceneValueError
    from pdmpm_cli.runner import prepare_scene

    scene = F.pour(0.1)
    shape = scene["bodies"][0]["emitter"]["shape"] | {"center": [0.18, 0.02, 0.18]}
    with pytest.raises(SceneValueError, match="3.5 cells from the domain's walls") as err:
        prepare_scene(Scene.model_validate(with_emitter(shape=shape)), tmp_path / "s.yaml")
    assert err.value.key == ("bodies", 0, "emitter", "shape")


def test_the_memory_check_counts_what_the_emitter_bears(tmp_path):
    """budget.estimate adds rate x time / h^3 to the emitting body, so a pour too large for the machine's memory is
    refused before any sampling."""
    from pdmpm_cli import budget
    from pdmpm_cli.errors import InputError

    scene = Scene.model_validate(F.pour(0.3))
    est = budget.estimate(scene, tmp_path)
    h, rate = 0.01, scene.bodies[0].emitter.rate
    head = 2 * math.pi * 0.02**2 * h / h**3  # the head's cylinder: volume / h^3
    assert est.particles == pytest.approx(head + rate * 0.3 / h**3)
    huge = Scene.model_validate(merge(F.pour(1e4), {"simulation": {"fps": 0.01}}))
    with pytest.raises(InputError, match="memory"):
        budget.check_memory(huge, tmp_path, "pour.yaml", available=int(1e9))
