"""The Table 1 baselines can fail: each case's perturbation (a material parameter changed) moves some metric out of
its tolerance. A file of its own, so the test run's workers share the Table 1 runs between them."""

import pytest

from tests.table1 import BASELINES, CASES, deviations, load_baselines, run_case

BASE = load_baselines()
SLOW_PERTURBATION = {"wall_break"}  # a second 8900-particle fracture run: with -m slow


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_PERTURBATION else n
                                  for n in CASES])
def test_material_change_is_caught(name):
    assert name in BASE, f"no baseline for {name} in {BASELINES}"
    _, perturbed = run_case(name, perturbed=True)
    caught = deviations(name, perturbed, BASE[name])
    print(f"\n{name} with {CASES[name].perturb}: {caught}")
    assert caught
