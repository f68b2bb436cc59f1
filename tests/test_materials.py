"""A material is one unit: the test-only spring of tests/spring_material.py, registered from outside the package,
runs on both backends and is checkpointed and resumed through its own declarations alone."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pdmpm_cli.engine.materials import BUILTIN, MATERIALS, declared_fields
from tests.spring_material import SCENE

ROOT = Path(__file__).resolve().parents[1]


def python(*args, cuda_sim: bool = False):
    env = dict(os.environ, PDMPM_MATERIALS="tests.spring_material", NUMBA_ENABLE_CUDASIM="1" if cuda_sim else "0")
    r = subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=ROOT, env=env, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return r.stdout


def test_spring_is_checkpointed_and_resumed_bitwise(tmp_path):
    row = json.loads(python("-m", "tests.spring_material", str(tmp_path)))
    assert row["frames"] == [11, 11] and row["resumed_from"] == 6
    assert "bond_peak" in row["checkpointed"] and row["peak"] > 0 and row["moved"] > 0.01
    assert row["bitwise"]  # resumed from frame 6: the frames of the uninterrupted run, bit for bit
    assert row["forgetful_differs"]  # and the bonds' memory mattered: without it the resume diverges


def test_spring_runs_alike_on_cuda(tmp_path):
    scene = tmp_path / "springs.yaml"
    scene.write_text(SCENE)
    row = json.loads(python("-m", "tests.cuda_compare", "--steps", "3", str(scene), cuda_sim=True))
    assert row["phases"] == ["bonds:spring", "p2g", "grid_update", "g2p"]
    assert row["x_rel"] < 1e-12 and row["v_rel"] < 1e-12 and row["arrays_rel"]["bond_peak"] < 1e-12


def test_spring_validates_through_the_cli(tmp_path):
    scene = tmp_path / "springs.yaml"
    scene.write_text(SCENE)
    out = python("-m", "pdmpm_cli", "validate", str(scene), "--explain")
    assert "bonds:spring" in out and "bond_peak" in out


def test_registry_and_declarations():
    """Every registered material's arrays are declared once, consistently with the engine's own."""
    assert set(MATERIALS) >= {k.name for k in BUILTIN} and "spring" not in MATERIALS  # registered only by env
    declared = declared_fields()
    for kind in MATERIALS.values():
        for f in kind.fields:
            assert declared[f.name] == f


@pytest.mark.parametrize("name", ["elastic", "plastic", "viscoelastic"])
def test_builtin_materials_are_units(name):
    """Schema, parameters, forces and constants come from the material's own module."""
    kind = MATERIALS[name]
    assert kind.schema.model_fields["model"].annotation.__args__ == (name,)
    assert kind.forces.__module__.startswith("pdmpm_cli.engine.materials.")
