"""Contact between bodies (engine/contact.py) against outside references: Newton's third law (momentum), Coulomb's
law of friction (a block decelerates at mu g), an elastic impact that starts where the surfaces touch and ends
with the bodies apart, and no force across a gap. Cases in tests/contact_cases.py; figures in bench/contact.py."""

import numpy as np
import pytest

from pdmpm_cli.engine.contact import overlap_box
from pdmpm_cli.engine.plan import Plan
from pdmpm_cli.study.sim import Sim
from tests import contact_cases as C


def test_one_body_or_shared_mode_allocates_no_fields():
    """A one-body scene, or contact mode shared, runs the single grid: no per-body fields, no contact phase."""
    one = C.sphere_pair(3)
    one["bodies"] = one["bodies"][:1]
    for scene in (one, C.sphere_pair(3, mode="shared")):
        plan: Plan = Sim(scene).plan
        assert not plan.contact and "contact" not in plan.phases
        assert "grid" in plan.fields and not {"grid_field", "grid_surface", "grid_surface_private"} & set(plan.fields)
    plan = Sim(C.sphere_pair(3)).plan
    assert plan.contact and "contact" in plan.phases and "grid" not in plan.fields
    assert plan.fields["grid_field"][0][0] == 2


def test_overlap_box_covers_every_pair_overlap_only():
    """The contact pass's node box: around the overlaps of any two fields' node boxes; empty without one (a field
    without particles has no box)."""
    a, b, c = np.array([0, 10, 0, 10, 0, 10]), np.array([8, 20, 2, 5, 0, 10]), np.array([30, 40, 0, 10, 0, 10])
    assert overlap_box([a, b, c]).tolist() == [8, 10, 2, 5, 0, 10]
    assert overlap_box([a, None, c]).tolist() == [0, 0, 0, 0, 0, 0]
    d = np.array([35, 50, 9, 20, 5, 6])  # meets c only
    assert overlap_box([a, b, c, d]).tolist() == [8, 40, 2, 10, 0, 10]


@pytest.mark.parametrize("mode", ["penalty", "projection"])
def test_spheres_bounce_apart_conserving_momentum(mode):
    """Two identical elastic spheres (5 spacings in radius) head-on at 0.05 c: contact starts within half a cell
    of the geometric touch, total momentum is conserved to round-off, and they end moving apart with a gap, with
    either contact model (in one shared field contact starts most of a cell early). (Kinetic energy kept:
    bench/contact.py, docs/results.md.)"""
    o = C.sphere_collision(5, mode=mode)
    print(o)
    assert o["contact_gap"] is not None and abs(o["contact_gap"]) < 0.5
    assert o["momentum"] < 1e-12
    assert o["v_left"] < 0 < o["v_right"] and o["apart"] > 0


@pytest.mark.slow
def test_spheres_of_ten_spacings():
    """The spheres at radius 10 spacings: contact within half a cell of the touch, momentum to round-off, apart at
    the end, with either model. Kinetic energy kept after separation: 73 % with the penalty, 44 % with the
    projection, 4.6 % in one shared field (the issue asks for 90 %; not met)."""
    penalty, projection = C.sphere_collision(10), C.sphere_collision(10, mode="projection")
    shared = C.sphere_collision(10, mode="shared")
    print(penalty, projection, shared)
    for o in (penalty, projection):
        assert abs(o["contact_gap"]) < 0.5 and o["momentum"] < 1e-12 and o["apart"] > 0
    assert penalty["ke"] > 0.7 and projection["ke"] > 5 * shared["ke"]


def test_penalty_contact_gives_back_the_energy_of_the_impact():
    """The default contact with APIC, the penalty (an elastic push where the fields' materials overlap), against
    the projection on the same sphere pair (5 spacings): no energy gained, and most of the kinetic energy back
    (measured 66.8 % against 7.6 %, bench/contact.py spheres)."""
    penalty, projection = C.sphere_collision(5), C.sphere_collision(5, mode="projection")
    print(penalty, projection)
    assert penalty["energy"] < 1.0 and penalty["ke"] > 0.5 > 5 * projection["ke"]


def test_penalty_contact_needs_apic():
    """The penalty with a FLIP share is refused (it gained energy there), naming the key; contact.model auto (the
    default) takes the projection with a FLIP share."""
    from pdmpm_cli.errors import InputError

    flip = C.sphere_pair(3)
    flip["simulation"]["flip"] = 0.5
    assert not Sim(flip).model.contact_stiffness.any()
    assert Sim(C.sphere_pair(3)).model.contact_stiffness.all()
    scene = C.sphere_pair(3, mode="penalty")
    scene["simulation"]["flip"] = 0.5
    with pytest.raises(InputError, match="contact.model"):
        Sim(scene)


def test_ball_rebounds_to_80_percent_with_a_full_flip_share():
    """An elastic ball dropped on a rigid, frictionless floor rebounds to e^2 of its drop height (e = 1 for an
    elastic impact; the issue's bar: 80 %). With simulation.flip = 1 (FLIP with MUSL's position pass) it reaches
    81 % at 5 spacings per radius; APIC (flip 0, the default) keeps 22 %, FLIP 0.95 55 % (bench/contact.py
    rebound)."""
    o = C.ball_drop(5, flip=1.0)
    print(o)
    assert o["rebound"] > 0.8


def test_ball_rebounds_to_80_percent_at_the_defaults():
    """The same ball at the scene defaults: APIC, and a separate floor's response auto, the penalty (an elastic push
    on the particles that touch it, stiffness 1): 82 % of the drop height (measured 0.8195; with the floor's
    response projection 22 %; bench/contact.py rebound --response penalty)."""
    o = C.ball_drop(5)
    print(o)
    assert o["rebound"] > 0.8


@pytest.mark.parametrize("friction", [0.3, 0.0])
def test_block_slides_on_a_penalty_floor_at_mu_g(friction):
    """A block sliding on a penalty floor: Coulomb friction decelerates it at mu g (within 5 %; measured 1.003);
    frictionless it keeps its speed (within 1 %); its particles do not sink below the floor (the push starts
    half a spacing above it, where the material touches)."""
    o = C.floor_slide(friction, duration=0.1)
    print(friction, o["deceleration"], o["v"][-1], o["deepest"])
    if friction:
        assert o["deceleration"] == pytest.approx(friction * C.G, rel=0.05)
    else:
        assert o["v"][-1] == pytest.approx(1.0, rel=0.01) and abs(o["deceleration"]) < 0.01 * C.G
    assert o["deepest"] < 0.05


@pytest.mark.parametrize("change,key", [
    ({"colliders": [{"type": "plane", "point": [0, 0.1, 0], "normal": [0, 1, 0], "boundary": "slip",
                     "response": "penalty"}]}, "boundary: separate"),
    ({"simulation": {"flip": 0.5},
      "colliders": [{"type": "plane", "point": [0, 0.1, 0], "normal": [0, 1, 0], "response": "penalty"}]},
     "simulation.flip"),
])
def test_penalty_collider_input_errors(sim_factory, change, key):
    """A penalty collider that cannot work is refused on input, saying what to change."""
    from pydantic import ValidationError

    from pdmpm_cli.errors import InputError

    with pytest.raises((InputError, ValidationError), match=key):
        sim_factory(change)


@pytest.mark.parametrize("mode", ["penalty", "projection"])
@pytest.mark.parametrize("friction", [0.3, 0.0])
def test_sliding_block_decelerates_at_mu_g(friction, mode):
    """A block sliding on an elastic slab: Coulomb friction decelerates it at mu g (within 5 %); frictionless it keeps
    its speed (within 1 %)."""
    o = C.sliding(friction, duration=0.1, mode=mode)
    print(friction, o["deceleration"], o["v"][-1])
    if friction:
        assert o["deceleration"] == pytest.approx(friction * C.G, rel=0.05)
    else:
        assert o["v"][-1] == pytest.approx(1.0, rel=0.01) and abs(o["deceleration"]) < 0.01 * C.G


def test_bodies_half_a_cell_apart_exert_no_force():
    """A block sliding past another half a cell away (friction 0.5) moves it not at all, with either contact model;
    in one shared grid field the grid couples them across the gap."""
    shared = C.passing("shared")
    for mode in ("penalty", "projection"):
        apart = C.passing(mode)
        print(mode, apart, shared)
        assert apart["picked_up"] < 1e-9 and apart["speed"] == pytest.approx(1.0, abs=1e-9)
    assert shared["picked_up"] > 0.05


def test_contact_pairs_are_checked(tmp_path):
    """A friction pair naming an unknown body, or one body twice, is bad input: file:line, the key and the fix."""
    from pdmpm_cli.errors import InputError
    from pdmpm_cli.runner import prepare

    scene = tmp_path / "pair.yaml"
    bodies = "\n".join(f"  - name: {n}\n    geometry: {{mode: cloud, shape: {{type: sphere, center: [{x}, 0.5, 0.5], "
                       f"radius: 0.1}}}}\n    material: {{model: elastic, density: 1000.0, lam: 1.0e5, mu: 1.0e5}}"
                       for n, x in (("a", 0.3), ("b", 0.7)))
    for pair, expected in (("[a, c]", "no body is named 'c'"), ("[a, a]", "two different bodies")):
        scene.write_text(f"simulation: {{duration: 0.1}}\ngrid: {{cell_size: 0.05, domain: {{min: [0, 0, 0], "
                         f"max: [1, 1, 1]}}}}\nbodies:\n{bodies}\ncontact:\n  pairs:\n    - {{bodies: {pair}, "
                         f"friction: 0.2}}\n")
        with pytest.raises(InputError) as e:
            prepare(scene, [])
        message = str(e.value)
        assert "pair.yaml:" in message and "contact.pairs.0.bodies" in message and expected in message
    scene.write_text(scene.read_text().replace("bodies: [a, a]", "bodies: [b, a]"))
    model = prepare(scene, []).model
    assert np.array_equal(model.contact_friction, [[0.0, 0.2], [0.2, 0.0]])


@pytest.mark.parametrize("model", ["penalty", "projection"])
def test_blocks_meeting_at_several_wave_speeds_do_not_pass_through(model):
    """Two blocks head-on at 6.6 times the P-wave speed each (`pdmpm stability` case impact_pair_1): neither model
    stops them before they interpenetrate, and once they had, the mass gradients' normals meant nothing: they
    passed through each other and left the domain (a SimulationError here). Where the fields' mass centres at a
    node are within DEEP_GAP the fields now stick: the blocks stop where they met, as on the paper's one shared
    field (flattened into one slab: an impact far outside what the grid resolves, but not a pass-through)."""
    import copy

    from pdmpm_cli import stability as st
    from pdmpm_cli.engine.solver import Solver
    from pdmpm_cli.scene.loader import merge

    case = next(c for c in st.cases() if c.name == "impact_pair_1")
    case = st.Case(case.name, case.category, case.parameter, case.probes,
                   merge(case.changes, {"contact": {"model": model}}), impact=case.impact)
    ready = st.prepare_case(case)
    state = copy.deepcopy(ready.state)
    solver = Solver(ready.prep.model, ready.prep.plan)
    solver.start(state)
    (a0, a1), (b0, b1) = ready.prep.model.body_ranges
    v0 = abs(state.particle_v[a0, 1])
    meet = 0.5 * (state.particle_x[a0:a1, 1].mean() + state.particle_x[b0:b1, 1].mean())
    solver.advance(state, 0.02)  # about 130 steps; they met at the 3rd
    dx = ready.prep.plan.cell_size
    for s, e in ((a0, a1), (b0, b1)):
        assert abs(state.particle_v[s:e, 1].mean()) < 0.02 * v0
        assert np.abs(state.particle_x[s:e, 1] - meet).max() < dx
