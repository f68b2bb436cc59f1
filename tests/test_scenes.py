"""The bundled scenes: every file and variant prepares at its full resolution, `pdmpm scenes` lists them, and
`--variant` applies a scene's named overrides, with its errors located in the scene file."""

from pathlib import Path

import pytest

from pdmpm_cli.runner import prepare
from pdmpm_cli.scene.loader import load_scene
from pdmpm_cli.scene.schema import Scene
from tests.test_cli import SMALL, pdmpm

ROOT = Path(__file__).resolve().parents[1]
SCENES = sorted((ROOT / "scenes").glob("*.yaml"))


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_bundled_scene_and_its_variants_prepare(path):
    scene, _ = load_scene(path, Scene)
    assert scene.description
    for variant in [None, *scene.variants]:
        prep = prepare(path, (), variant)
        assert prep.plan.particles > 0 and prep.plan.bonds > 0


def test_variant_sets_its_values_and_set_wins():
    cloth = ROOT / "scenes" / "cloth.yaml"
    assert [prepare(cloth, (), v).scene.bodies[0].material.mu for v in ("soft", "medium", "stiff")] == [2e4, 1e5, 1.5e5]
    assert prepare(cloth, ["bodies.0.material.mu=3e4"], "soft").scene.bodies[0].material.mu == 3e4


def test_unknown_variant_exit_2_with_the_names():
    r = pdmpm("validate", ROOT / "scenes" / "cloth.yaml", "--variant", "sofft")
    assert r.returncode == 2
    assert "no variant 'sofft'" in r.stderr and "did you mean soft?" in r.stderr and "medium, stiff" in r.stderr


def test_bad_variant_value_is_located_at_its_line(tmp_path):
    text = SMALL + "variants:\n  heavy: {bodies.0.material.density: 2000}\n  broken:\n    bodies.0.material.mu: -5\n"
    path = tmp_path / "small.yaml"
    path.write_text(text)
    assert pdmpm("validate", path, "--variant", "heavy").returncode == 0
    r = pdmpm("validate", path, "--variant", "broken")
    line = text.splitlines().index("    bodies.0.material.mu: -5") + 1
    assert r.returncode == 2 and f"small.yaml:{line}:" in r.stderr and "bodies.0.material.mu" in r.stderr


def test_scenes_lists_every_bundled_scene():
    r = pdmpm("scenes")
    assert r.returncode == 0, r.stderr
    for path in SCENES:
        assert path.name in r.stdout
    assert "soft, medium, stiff" in r.stdout
