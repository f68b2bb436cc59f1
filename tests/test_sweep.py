"""`pdmpm sweep`: the grid of variants, their validation, and a run on a two-worker Dask LocalCluster in which one
variant fails and the others finish."""

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pdmpm_cli.errors import InputError
from pdmpm_cli.io.hdf5 import read_run
from pdmpm_cli.sweep import expand, parse_param, split_values
from tests.test_cli import SMALL

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = "variants:\n  soft: {bodies.0.material.mu: 5.0e3}\n  stiff: {bodies.0.material.mu: 5.0e4}\n"


@pytest.fixture
def scene(tmp_path) -> Path:
    path = tmp_path / "small.yaml"
    path.write_text(SMALL + VARIANTS)
    return path


def test_values_split_outside_brackets():
    assert split_values("2e4,1e5, 1.5e5") == ["2e4", "1e5", "1.5e5"]
    assert split_values("[0, 1, 0],[0,2,0],'a,b'") == ["[0, 1, 0]", "[0,2,0]", "'a,b'"]
    assert parse_param("bodies.0.material.mu=1,2") == ("bodies.0.material.mu", ["1", "2"])
    for bad in ("mu", "=1,2", "a..b=1", "a=1,,2", "a="):
        with pytest.raises(InputError, match="expected KEY=V1,V2"):
            parse_param(bad)
    with pytest.raises(InputError, match="repeated value"):
        parse_param("a=1,1")


def test_grid_is_the_product_of_variants_and_params(scene):
    variants = expand(scene, ["bodies.0.material.lam=1e4,2e4", "simulation.fps=10,20"], ["soft", "stiff"],
                      ["simulation.duration=0.2"])
    assert len(variants) == 8
    first = variants[0]
    assert first.name == "variant=soft,lam=1e4,fps=10" and first.variant == "soft"
    assert first.overrides == ("simulation.duration=0.2", "bodies.0.material.lam=1e4", "simulation.fps=10")
    assert len({v.name for v in variants}) == 8
    centres = expand(scene, ["bodies.0.geometry.shape.center=[0.4,0.45,0.4],[0.45,0.45,0.4]"], [], [])
    assert [v.name for v in centres] == ["center=0.4_0.45_0.4", "center=0.45_0.45_0.4"]


def test_bad_key_or_value_is_named_before_anything_runs(scene):
    with pytest.raises(InputError, match=r"--param bodies.0.material.muu: unknown key \(did you mean mu\?\)"):
        expand(scene, ["bodies.0.material.muu=1,2"], [], [])
    with pytest.raises(InputError, match="--param bodies.0.material.lam"):
        expand(scene, ["bodies.0.material.lam=1e4,-1"], [], [])
    with pytest.raises(InputError, match="no variant 'medium'"):
        expand(scene, [], ["medium"], [])
    with pytest.raises(InputError, match="nothing to sweep"):
        expand(scene, [], [], [])


def test_sweep_on_two_local_workers_reports_a_failed_variant(scene, tmp_path):
    """Four variants on a LocalCluster of two workers; the one whose body lies outside the domain fails at run
    time (discretisation), is reported, and the three others finish; exit code 1."""
    out = tmp_path / "sweeps"
    env = dict(os.environ, COLUMNS="200",
               PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    param = "bodies.0.geometry.shape.center=[0.4,0.45,0.4],[0.42,0.45,0.4],[0.4,0.5,0.4],[0.75,0.45,0.4]"
    r = subprocess.run([sys.executable, "-m", "pdmpm_cli", "sweep", scene, "--param", param, "--set",
                        "simulation.duration=0.05", "--workers", "2", "--out", out],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 1, r.stderr
    assert "4 variants on 2 workers (local cluster)" in r.stderr and "enlarge grid.domain" in r.stderr
    base = out / "small"
    with open(base / "summary.csv") as f:
        rows = list(csv.DictReader(f))
    assert [row["folder"] for row in rows] == [v.name for v in expand(scene, [param], [], [])]
    assert [row["status"] for row in rows] == ["ok", "ok", "ok", "bad input"]
    assert "enlarge grid.domain" in rows[3]["message"] and not (base / rows[3]["folder"] / "run.h5").exists()
    for row in rows[:3]:
        assert int(row["steps"]) > 0 and float(row["max_speed_m_s"]) > 0 and float(row["wall_s"]) > 0
        assert len(read_run(base / row["folder"] / "run.h5")) == int(row["frames"]) + 1 == 2
    md = (base / "summary.md").read_text().splitlines()
    assert len(md) == 6 and md[0].startswith("| folder | bodies.0.geometry.shape.center | status |")
