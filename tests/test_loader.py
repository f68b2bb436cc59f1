"""Scene loading: YAML positions, overrides, and plain-words messages for every kind of mistake."""

from __future__ import annotations

from typing import Annotated, Literal, Optional, Union

import pytest
from pydantic import BaseModel, ConfigDict, Field, model_validator

from pdmpm_cli.errors import InputError
from pdmpm_cli.scene.loader import Problem, SceneError, load_scene, parse_overrides


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Box(Strict):
    shape: Literal["box"]
    size: tuple[float, float, float]


class Sphere(Strict):
    shape: Literal["sphere"]
    radius: float = Field(gt=0)


class Elastic(Strict):
    model: Literal["elastic"]
    E: float = Field(gt=0)
    nu: float = 0.3

    @model_validator(mode="after")
    def _nu_range(self):
        if not -1 < self.nu < 0.5:
            raise ValueError(f"nu must be in (-1, 0.5), got {self.nu}")
        return self


class Plastic(Strict):
    model: Literal["plastic"]
    E: float = Field(gt=0)
    yield_stress: float = Field(gt=0)


class Body(Strict):
    name: str
    geometry: Annotated[Union[Box, Sphere], Field(discriminator="shape")]
    material: Annotated[Union[Elastic, Plastic], Field(discriminator="model")]
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)


class Sim(Strict):
    dt: float = Field(gt=0)
    steps: int = Field(gt=0)
    solver: Literal["explicit", "implicit"] = "explicit"


class Scene(Strict):
    sim: Sim
    bodies: list[Body]
    gravity: Optional[tuple[float, float, float]] = None


GOOD = """\
sim:
  dt: 1e-4
  steps: 10
bodies:
  - name: block
    geometry: {shape: box, size: [1, 1, 1]}
    material:
      model: plastic
      E: 2e5
      yield_stress: 250
  - name: ball
    geometry:
      shape: sphere
      radius: .5
    material: {model: elastic, E: 1e5}
"""


def write(tmp_path, text, name="scene.yaml"):
    (tmp_path / name).write_text(text, encoding="utf-8")
    return tmp_path / name


def messages(tmp_path, text, overrides=()):
    """Run load_scene from inside tmp_path so file names read as in the CLI: `scene.yaml:L:C ...`."""
    write(tmp_path, text)
    with pytest.raises(SceneError) as info:
        load_scene("scene.yaml", Scene, list(overrides))
    assert isinstance(info.value, InputError) and info.value.exit_code == 2
    assert str(info.value) == "\n".join(map(str, info.value.problems))
    return [str(p) for p in info.value.problems]


def position(text, needle, line_no):
    """1-based (line, col) of `needle` on line `line_no`: checks the marks against the text itself."""
    return line_no, text.splitlines()[line_no - 1].index(needle) + 1


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


def test_good_scene_loads_with_floats_written_as_1e5(tmp_path):
    scene, text = load_scene(write(tmp_path, GOOD), Scene)
    assert text == GOOD
    assert scene.sim.dt == 1e-4 and isinstance(scene.sim.dt, float)
    assert scene.bodies[0].material.E == 200000.0
    assert isinstance(scene.bodies[1].geometry, Sphere) and scene.bodies[1].geometry.radius == 0.5


def test_float_spellings_in_file_and_override(tmp_path):
    written = {"1e5": 1e5, "-2.5E-3": -2.5e-3, ".5": 0.5, "1.": 1.0, "+3_000.5": 3000.5, "1.0e+5": 1e5}
    for spelling, value in written.items():
        [(_, parsed)] = parse_overrides([f"x={spelling}"])
        assert type(parsed) is float and parsed == value, spelling
    not_floats = parse_overrides(["a=10", "b=1e", "c=x1e5", "d=.", "e=.inf"])
    assert [v for _, v in not_floats] == [10, "1e", "x1e5", ".", float("inf")]
    text = "sim: {dt: 2E-3, steps: 1}\nbodies: []\ngravity: [-1e1, .5, 3e0]\n"
    scene, _ = load_scene(write(tmp_path, text), Scene, ["sim.dt=1e5"])
    assert scene.sim.dt == 100000.0 and scene.gravity == (-10.0, 0.5, 3.0)
    scene, _ = load_scene(write(tmp_path, "sim: {dt: 1e5, steps: 2e4}\nbodies: []\n"), Scene)
    assert scene.sim.dt == 1e5 and scene.sim.steps == 20000  # an int field accepts 2e4: it is whole


def test_misspelt_key_suggests_the_right_one(tmp_path):
    text = GOOD.replace("yield_stress: 250", "yeild_stress: 250")
    line, col = position(text, "yeild_stress", 10)
    assert (line, col) == (10, 7)
    assert messages(tmp_path, text) == [
        "scene.yaml:7:5 bodies.0.material.yield_stress: missing required key",
        f"scene.yaml:{line}:{col} bodies.0.material.yeild_stress: unknown key (did you mean yield_stress?)",
    ]


def test_unknown_key_without_close_match_lists_allowed_keys(tmp_path):
    text = GOOD.replace("  steps: 10\n", "  steps: 10\n  colour: red\n")
    assert messages(tmp_path, text) == ["scene.yaml:4:3 sim.colour: unknown key (allowed keys: dt, steps, solver)"]


def test_wrong_type(tmp_path):
    text = GOOD.replace("steps: 10", "steps: many")
    assert messages(tmp_path, text) == [
        "scene.yaml:3:10 sim.steps: must be a valid integer, unable to parse string as an integer (got 'many')"
    ]


def test_constraint_violation_and_literal_suggestion(tmp_path):
    text = GOOD.replace("radius: .5", "radius: -3").replace("steps: 10", "steps: 10\n  solver: explict")
    assert messages(tmp_path, text) == [
        "scene.yaml:4:11 sim.solver: must be 'explicit' or 'implicit' (got 'explict'; did you mean explicit?)",
        "scene.yaml:15:15 bodies.1.geometry.radius: must be greater than 0 (got -3)",
    ]


def test_missing_required_fields(tmp_path):
    """A missing key points at the mapping that lacks it; at top level there is no better place than the file."""
    assert messages(tmp_path, "sim:\n  steps: 10\n") == [
        "scene.yaml bodies: missing required key",
        "scene.yaml:1:1 sim.dt: missing required key",
    ]


def test_missing_field_in_list_item_points_at_the_item(tmp_path):
    text = GOOD.replace("  - name: ball\n    geometry:", "  - geometry:")
    assert messages(tmp_path, text) == ["scene.yaml:11:5 bodies.1.name: missing required key"]


def test_bad_discriminator_tag_lists_tags_and_suggests(tmp_path):
    text = GOOD.replace("shape: sphere", "shape: sphre").replace("model: plastic", "kind: plastic")
    line, col = position(text, "sphre", 13)
    assert messages(tmp_path, text) == [
        "scene.yaml:7:5 bodies.0.material.model: missing model (expected one of: elastic, plastic)",
        f"scene.yaml:{line}:{col} bodies.1.geometry.shape: unknown shape 'sphre'"
        " (expected one of: box, sphere; did you mean sphere?)",
    ]


def test_errors_inside_a_union_member_drop_the_tag_from_the_key(tmp_path):
    text = GOOD.replace("size: [1, 1, 1]", "sise: [1, 1, 1]")
    assert messages(tmp_path, text) == [
        "scene.yaml:6:5 bodies.0.geometry.size: missing required key",
        "scene.yaml:%d:%d bodies.0.geometry.sise: unknown key (did you mean size?)" % position(text, "sise", 6),
    ]


def test_tuple_of_three_floats(tmp_path):
    assert messages(tmp_path, GOOD + "gravity: [0]\n") == ["scene.yaml:16:1 gravity: must have 3 items (got [0])"]
    assert messages(tmp_path, GOOD + "gravity: [0, 0, 0, 0]\n") == [
        "scene.yaml:16:1 gravity: Tuple should have at most 3 items after validation, not 4 (got [0, 0, 0, 0])"
    ]


def test_model_validator_error_is_located_at_its_model(tmp_path):
    text = GOOD.replace("material: {model: elastic, E: 1e5}", "material: {model: elastic, E: 1e5, nu: 0.7}")
    assert messages(tmp_path, text) == ["scene.yaml:15:5 bodies.1.material: nu must be in (-1, 0.5), got 0.7"]


def test_yaml_syntax_error_reports_parser_position(tmp_path):
    text = "sim:\n  dt: 1\n steps: 2\n"
    assert messages(tmp_path, text) == [
        "scene.yaml:3:2: invalid YAML: expected <block end>, but found '<block mapping start>'"
        " (while parsing a block mapping on line 1)"
    ]


def test_tab_indentation_hint(tmp_path):
    assert messages(tmp_path, "sim:\n\tdt: 1\n") == [
        "scene.yaml:2:1: invalid YAML: found character '\\t' that cannot start any token"
        "; indent with spaces, not tabs"
    ]


def test_duplicate_key(tmp_path):
    text = GOOD.replace("  steps: 10\n", "  steps: 10\n  dt: 2e-4\n")
    assert messages(tmp_path, text) == ["scene.yaml:4:3 sim.dt: duplicate key (first written on line 2)"]


def test_top_level_must_be_a_mapping(tmp_path):
    assert messages(tmp_path, "- sim\n- bodies\n") == [
        "scene.yaml:1:1: top level must be a mapping of keys (e.g. 'bodies:'), found a list"
    ]
    assert messages(tmp_path, "# nothing\n") == [
        "scene.yaml: file is empty (expected a mapping of scene settings, e.g. 'bodies:')"
    ]


def test_missing_file_and_bad_encoding(tmp_path):
    with pytest.raises(SceneError) as info:
        load_scene("nope.yaml", Scene)
    assert str(info.value) == f"nope.yaml: file not found (relative paths start from the current directory, {tmp_path})"
    (tmp_path / "latin1.yaml").write_bytes("sim:\n  name: caf\xe9\n".encode("latin-1"))
    with pytest.raises(SceneError) as info:
        load_scene("latin1.yaml", Scene)
    assert str(info.value) == "latin1.yaml:2:12: not UTF-8 text (byte 0xe9); save the file as UTF-8"


def test_override_is_applied_before_validation(tmp_path):
    overrides = ["sim.steps=20", "bodies.1.material.E=3e5", "gravity=[0, 0, -9.81]"]
    scene, text = load_scene(write(tmp_path, GOOD), Scene, overrides)
    assert scene.sim.steps == 20 and scene.bodies[1].material.E == 300000.0
    assert scene.gravity == (0.0, 0.0, -9.81)
    assert text == GOOD  # the file text, not the overridden data


def test_override_errors_are_reported_against_the_override(tmp_path):
    overrides = ["bodies.0.material.E=-3", "sim.colour=red", "bodies.1.geometry={shape: cube}"]
    assert messages(tmp_path, GOOD, overrides) == [
        "--set sim.colour: unknown key (allowed keys: dt, steps, solver)",
        "--set bodies.0.material.E: must be greater than 0 (got -3)",
        "--set bodies.1.geometry.shape: unknown shape 'cube' (expected one of: box, sphere)",
    ]


def test_override_creates_missing_mappings(tmp_path):
    text = "bodies: []\n"
    scene, _ = load_scene(write(tmp_path, text), Scene, ["sim.dt=1e-3", "sim.steps=5"])
    assert scene.sim.dt == 0.001 and scene.sim.steps == 5


def test_model_check_failing_after_an_override_names_it(tmp_path):
    text = GOOD.replace("material: {model: elastic, E: 1e5}", "material: {model: elastic, E: 1e5, nu: 0.4}")
    assert messages(tmp_path, text, ["bodies.1.material.nu=0.6"]) == [
        "scene.yaml:15:5 bodies.1.material: nu must be in (-1, 0.5), got 0.6 (with --set bodies.1.material.nu)"
    ]


def test_override_that_creates_a_mapping_owns_its_errors(tmp_path):
    assert messages(tmp_path, "bodies: []\n", ["sim.dt=1e-3"]) == ["--set sim.steps: missing required key"]


def test_yaml_1_1_booleans_stay_strings(tmp_path):
    text = GOOD.replace("name: block", "name: no")
    scene, _ = load_scene(write(tmp_path, text), Scene, ["bodies.1.name=off"])
    assert [b.name for b in scene.bodies] == ["no", "off"]


def test_override_index_past_end_of_list(tmp_path):
    assert messages(tmp_path, GOOD, ["bodies.2.material.E=1"]) == [
        "--set bodies.2.material.E: index 2 is past the end of bodies (it has 2 items)"
    ]
    assert messages(tmp_path, GOOD, ["bodies.first.name=x"]) == [
        "--set bodies.first.name: bodies is a list; use an item number, e.g. bodies.0"
    ]


def test_malformed_overrides(tmp_path):
    with pytest.raises(SceneError) as info:
        parse_overrides(["sim.dt", "=3", "a..b=1", "ok=1"])
    assert str(info.value) == "\n".join(
        f"--set: malformed override {item!r} (expected KEY=VALUE, e.g. --set bodies.0.material.mu=2e5)"
        for item in ("sim.dt", "=3", "a..b=1")
    )
    assert parse_overrides(["bodies.0.name=a=b", "x.y= [1, 2]"]) == [
        (["bodies", 0, "name"], "a=b"),
        (["x", "y"], [1, 2]),
    ]


def test_problem_formatting():
    assert str(Problem("s.yaml", 9, 17, "a.b", "bad")) == "s.yaml:9:17 a.b: bad"
    assert str(Problem("s.yaml", None, None, "a", "bad")) == "s.yaml a: bad"
    assert str(Problem("s.yaml", None, None, "", "bad")) == "s.yaml: bad"
    assert str(Problem("--set", None, None, "a.b", "bad")) == "--set a.b: bad"
