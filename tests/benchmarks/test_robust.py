"""The robust statistics of the sweep's reports (benchmarks/robust.py) against scipy's and rliable's
estimators, and the reports that print them (table1, reality, budget) on synthetic cells."""

import csv

import numpy as np
import pytest
from scipy import stats

from benchmarks import robust


def _rliable(module):
    try:
        return __import__(f"rliable.{module}", fromlist=[module])
    except Exception as e:  # rliable absent, or its arch dependency broken on this pandas
        pytest.skip(f"rliable.{module} unusable here: {e}")


@pytest.mark.parametrize("shape", [(5,), (5, 3), (7, 2), (20, 1)])
def test_iqm_is_the_25_percent_trimmed_mean(shape):
    x = np.random.default_rng(sum(shape)).beta(5, 2, size=shape)
    assert robust.iqm(x) == pytest.approx(stats.trim_mean(x, 0.25, axis=None), rel=1e-12)
    assert robust.iqm([0.0, 0.5, 0.6, 0.7, 100.0]) == pytest.approx(0.6)  # the outliers cut


def test_iqm_and_probability_of_improvement_match_rliable():
    metrics = _rliable("metrics")
    rng = np.random.default_rng(3)
    x, y = rng.beta(8, 2, size=(5, 3)), rng.beta(6, 2, size=(7, 3))
    assert robust.iqm(x) == pytest.approx(metrics.aggregate_iqm(x), rel=1e-12)
    assert robust.probability_of_improvement(x, y) == pytest.approx(
        metrics.probability_of_improvement(x, y), rel=1e-12
    )


def test_probability_of_improvement_is_mann_whitney_over_pairs():
    rng = np.random.default_rng(4)
    x, y = rng.normal(size=(6, 2)), rng.normal(0.3, size=(4, 2))
    x[0, 0] = y[1, 0]  # a tie counts half
    want = np.mean(
        [
            stats.mannwhitneyu(x[:, t], y[:, t], alternative="greater").statistic / 24
            for t in range(2)
        ]
    )
    assert robust.probability_of_improvement(x, y) == pytest.approx(want, rel=1e-12)
    assert robust.probability_of_improvement(x, x) == 0.5
    assert (
        robust.probability_of_improvement(y + 10, y) == 1.0
        and robust.probability_of_improvement(y, y + 10) == 0.0
    )
    with pytest.raises(ValueError, match="scores_x and scores_y must have as many tasks"):
        robust.probability_of_improvement(x, y[:, :1])


def test_bootstrap_is_stratified_percentile_and_reproducible():
    # Stratified: each task's runs are resampled within the task, so two constant tasks give no
    # spread at all (resampling the runs of both together would mix them).
    point, lo, hi = robust.bootstrap_ci(
        np.array([[0.0, 1.0]] * 4), statistic=lambda m: float(m.mean())
    )
    assert point == lo == hi == 0.5
    # One task of 20 normal runs: the mean's percentile interval is about mean +- 1.96 s / sqrt(n).
    x = np.random.default_rng(5).normal(size=20)
    point, lo, hi = robust.bootstrap_ci(x, statistic=lambda m: float(m.mean()), reps=4000)
    half = 1.96 * x.std() / np.sqrt(20)
    assert point == pytest.approx(x.mean()) and lo < point < hi
    assert (hi - lo) / 2 == pytest.approx(half, rel=0.15)
    assert robust.bootstrap_ci(x) == robust.bootstrap_ci(x)  # seeded
    with pytest.raises(ValueError, match=r"confidence must be in \(0, 1\)"):
        robust.bootstrap_ci(x, confidence=1.5)
    with pytest.raises(ValueError, match="scores must be a non-empty"):
        robust.iqm([])


def test_bootstrap_interval_matches_rliable():
    library, metrics = _rliable("library"), _rliable("metrics")
    x = np.random.default_rng(6).beta(8, 2, size=(10, 3))
    try:
        _, ci = library.get_interval_estimates(
            {"x": x}, lambda s: np.array([metrics.aggregate_iqm(s)]), reps=5000
        )
    except TypeError as e:  # arch >= 8 refuses rliable 1.2's random_state=None
        pytest.skip(f"rliable's bootstrap unusable with this arch: {e}")
    _, lo, hi = robust.bootstrap_ci(x, reps=5000)
    assert lo == pytest.approx(ci["x"][0][0], abs=0.01) and hi == pytest.approx(
        ci["x"][1][0], abs=0.01
    )


def test_performance_profile_and_its_band():
    x = np.array([[0.2, 0.9], [0.6, 0.95], [0.8, 0.99]])
    taus = np.array([0.0, 0.5, 0.85, 0.97, 1.0])
    np.testing.assert_allclose(robust.performance_profile(x, taus), [1.0, 5 / 6, 3 / 6, 1 / 6, 0.0])
    prof, lo, hi = robust.profile_ci(x, np.linspace(0, 1, 21))
    assert np.all(np.diff(prof) <= 0) and np.all(lo <= prof + 1e-12) and np.all(prof <= hi + 1e-12)
    assert np.any(hi > lo)


def _runs(algos, finals_by_algo):
    """table1's runs: (mode, algo, seed) -> record with per-seed final P/Pmax on both evaluation
    envs."""
    from benchmarks.sweep.paper import MODES

    return {
        (mode, a, s): {"train_env": {"final": [v]}, "test_env": {"final": [v]}}
        for mode in MODES
        for a in algos
        for s, v in enumerate(finals_by_algo[a])
    }


def test_table1_writes_iqm_intervals_improvement_and_a_profile(tmp_path):
    from benchmarks.sweep import report_table1

    algos = ["spgd", "td3"]
    finals = {"spgd": [0.1, 0.5, 0.6, 0.7, 0.9], "td3": [0.91, 0.92, 0.93, 0.94, 0.95]}
    report_table1.table1(
        tmp_path, _runs(algos, finals), dict(algos=algos, seeds=5, episodes=4, name="synthetic")
    )
    md = (tmp_path / "table1.md").read_text()
    assert "| | IQM [95 % CI] | 0.6000 [" in md  # the middle three of SPGD's seeds
    assert "| TD3 | 0.9300 [" in md and "| SPGD | 0.6000 [" in md  # aggregated over the modes
    assert "| 1.00 | – |" in md and "| – | 0.00 |" in md  # P(TD3 > SPGD) = 1, P(SPGD > TD3) = 0
    assert "The IQM rows are not bolded." in md and "No bold in these tables." in md
    rows = list(csv.DictReader(open(tmp_path / "table1.csv")))
    assert len(rows) == 3 * 2 * 2
    for r in rows:
        assert float(r["iqm_ci_lo"]) <= float(r["iqm"]) <= float(r["iqm_ci_hi"])
    assert (tmp_path / "performance_profile.png").stat().st_size > 5000


def test_reality_and_budget_reports_carry_iqm_and_improvement(tmp_path):
    from benchmarks.budget import plan as budget
    from benchmarks.sweep import reality
    from ops_jax.imperfections import Ceilings

    results = {
        "spgd/ideal": {
            "none": [0.99, 0.98, 0.97],
            "lab": [0.97, 0.96, 0.95],
            "2x lab": [0.9, 0.91, 0.92],
        },
        "ppo/randomised": {
            "none": [0.9, 0.7, 0.8],
            "lab": [0.5, 0.6, 0.7],
            "2x lab": [0.4, 0.45, 0.5],
        },
    }
    ceilings = {n: Ceilings(None, None, "not drawn here", 64, 0) for n in results["spgd/ideal"]}
    reality.report(
        tmp_path,
        results,
        dict(seeds=3, episodes=8),
        "python -m benchmarks.sweep --only reality",
        ceilings=ceilings,
    )
    md = (tmp_path / "reality.md").read_text()
    assert "| SPGD (ideal) | 0.980 [" in md and "| PPO (randomised) | 0.800 [" in md
    # IQM over the 9 scores of the three levels: the middle 5; SPGD above PPO at every level
    assert "| SPGD (ideal) | 0.9540 [" in md and "| 1.00 |" in md
    assert (tmp_path / "reality_profile.png").stat().st_size > 5000

    def record(algo, seed, scores):
        cell = budget.Cell(
            kind="learner",
            algo=algo,
            hyper={},
            env="hard",
            env_config={},
            seed=seed,
            checkpoints=[1000, 2000],
            episodes=8,
            eval_seed=1,
            settings={},
        )
        return {
            "cell": cell,
            "result": {"scores": dict(zip(["1000", "2000"], scores)), "train_s": 1.0},
        }

    text = budget.report(
        [record("droq", s, [0.1 * s, 0.5 + 0.1 * s]) for s in (1, 2, 3)]
        + [record("td3", s, [0.0, 0.2]) for s in (1, 2, 3)],
        tmp_path / "b",
    )
    assert (
        "| hard | DroQ | 0.200 [" in text
        and "| hard | DroQ | 0.200 [0.100, 0.300] | 0.700 [" in text
    )
    assert (
        "hard, after 2,000 env steps: probability of improvement" in text
        and "| DroQ | 0.7000 [" in text
    )
