"""CI regression of the paper's Table 1 scenes (tests/table1.py): each scene at reduced resolution shows its
figure's behaviour and matches the stored baseline (tests/test_table1_perturbations.py: a deliberate material change
is caught by the baseline)."""

import pytest

from tests.table1 import CASES, deviations, fragments, load_baselines, run_case

BASE = load_baselines()


def metrics(name):
    trace, m = run_case(name)
    print(f"\n{name}: {trace.model.n_particles} particles, {trace.seconds:.1f} s: "
          + ", ".join(f"{k} {v:.4g}" for k, v in m.items()))
    return m


@pytest.mark.parametrize("name", list(CASES))
def test_matches_baseline(name):
    """Every metric within its tolerance of tests/baselines/table1.json (regenerate: python -m tests.table1
    --update)."""
    assert name in BASE, f"no baseline for {name}: run python -m tests.table1 --update {name}"
    assert not deviations(name, metrics(name), BASE[name])


def test_cloth_folds_ordered_by_mu():
    """Cloth: the folds grow as the shear modulus falls (mu = 2e4 < 1e5 < 1.5e5 Pa)."""
    folds = [metrics(f"cloth_{v}")["fold_rms_mm"] for v in ("soft", "medium", "stiff")]
    assert folds[0] > folds[1] > folds[2]


def test_beams_sag_ordered_by_mu():
    m = metrics("beams")
    assert m["sag_mu0_mm"] > m["sag_mu50_mm"] > m["sag_mu500_mm"] > 0


def test_elastic_board_springs_back_and_plastic_board_keeps_a_dent():
    elastic, plastic = metrics("board_elastic"), metrics("board_plastic")
    assert elastic["peak_mm"] > 5 and abs(elastic["residual_ratio"]) < 0.15
    assert plastic["peak_mm"] > 5 and plastic["residual_ratio"] > 0.3


def test_elastic_bunnies_recover_and_plastic_bunnies_stay_deformed():
    """Both pairs come apart after the collision (a field per body: they do not weld), with a gap between them;
    the elastic bunnies recover their shape, the plastic ones stay dented."""
    elastic, plastic = metrics("bunnies_elastic"), metrics("bunnies_plastic")
    assert elastic["recovery_ratio"] < 0.35
    assert plastic["recovery_ratio"] > 0.6
    for pair in (elastic, plastic):
        assert pair["gap_mm"] > 30 and pair["restitution"] > 0.05


def test_wall_breaks_into_a_few_large_pieces():
    m = metrics("wall_break")
    trace, _ = run_case("wall_break")
    sizes = fragments(trace, 0)
    print(f"pieces {len(sizes)}; largest (cells) {sizes[:8].tolist()}; pieces of 1 cell {int((sizes == 1).sum())}, "
          f"2-4 cells {int(((sizes > 1) & (sizes < 5)).sum())}, 5-99 cells {int(((sizes >= 5) & (sizes < 100)).sum())}")
    assert 2 <= m["large_pieces"] <= 6 and m["large_share"] > 0.6 and m["dust_share"] < 0.15


def test_honey_spreads_and_piles():
    """Poured from the neck, the honey piles and spreads on the plate, keeping the poured volume within 3 %."""
    m = metrics("honey")
    assert m["spread_ratio"] > 1.5 and m["height_mm"] > 60 and abs(m["volume_ratio"] - 1.0) < 0.03


def test_cream_flows_but_keeps_height():
    m = metrics("cream_pie")
    assert m["spread_ratio"] > 1.1 and m["thickness_ratio"] > 0.6
