"""The budget learners (DroQ; the update-to-data ratio of TD3) and the budget benchmark's plan:
learning on a small budget, determinism, vmapped seeds, checkpoints, bad hyperparameters, the
snapshots standing for shorter runs, and the report of tiny records."""

import dataclasses

import jax
import numpy as np
import pytest

import agents
from agents import DroQConfig, TD3Config
from agents.learners.offpolicy import droq, driver as offpolicy, replay
from idle import learned_and_idle
from benchmarks.budget import command, plan as budget

ENV = {"stages": 3, "mode": "easy", "model": "phasor"}
HYPER = dict(
    hidden=(32, 32),
    critic_hidden=(32, 32),
    batch_size=64,
    learning_starts=256,
    utd_ratio=2.0,
    eval_every=512,
    eval_episodes=4,
)
STEPS = 256 + 5 * 512  # the warm-up and five chunks


@pytest.fixture(scope="module")
def trained():
    return agents.train("droq", ENV, seed=3, total_steps=STEPS, **HYPER)


def test_droq_learns_a_small_configuration(trained):
    summary, baseline = learned_and_idle(trained, ENV, 16)
    learned = summary["final_mean"]
    assert learned >= max(0.8, baseline + 0.25), (learned, baseline)
    assert trained.curve["step"].tolist() == [256 + 512 * k for k in range(6)]
    assert trained.config.config == "budget" and trained.config.utd_ratio == 2.0


def test_same_seed_same_result_and_checkpoint_round_trip(trained, tmp_path):
    again = agents.train("droq", ENV, seed=3, total_steps=STEPS, **HYPER)
    jax.tree.map(np.testing.assert_array_equal, trained.params, again.params)
    agents.save(tmp_path / "ckpt", trained)
    loaded = agents.load(tmp_path / "ckpt")
    a = agents.evaluate(trained, ENV, episodes=4, seed=7).normalized_power
    b = agents.evaluate(loaded, ENV, episodes=4, seed=7).normalized_power
    np.testing.assert_array_equal(a, b)


FEW = dict(HYPER, eval_every=32, utd_ratio=1.0)
FEW_STEPS = 256 + 2 * 32  # 64 gradient steps


def test_vmapped_seeds_equal_single_seed_runs():
    """The same draws as each seed alone: equal to float32 rounding before any gradient step (the
    vmapped evaluation is another compiled program), to float rounding after 64."""
    both = agents.train_seeds("droq", ENV, seeds=[3, 5], total_steps=FEW_STEPS, **FEW)
    solo = agents.train("droq", ENV, seed=5, total_steps=FEW_STEPS, **FEW)
    assert [r.seed for r in both] == [3, 5] and both[1].wall_time["seeds_in_call"] == 2
    np.testing.assert_allclose(
        both[1].curve["normalized_power"][0], solo.curve["normalized_power"][0], rtol=1e-5
    )
    gap = lambda a, b: [
        float(np.abs(x - y).max()) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b))
    ]  # noqa: E731
    assert max(gap(both[1].params, solo.params)) < 2e-3  # rounding, grown over 64 Adam steps
    assert min(gap(both[0].params, both[1].params)) > 2e-2  # another seed: every array apart


def test_a_snapshot_is_the_shorter_run():
    """The state a run passes at a chunk end is the state of a run with that budget
    (benchmarks.budget.plan)."""
    snaps = {}
    offpolicy.train_seeds(
        droq.LEARNER,
        ENV,
        seeds=[4],
        total_steps=FEW_STEPS,
        snapshot_fn=lambda step, ps: snaps.update({step: ps[0]}),
        **FEW,
    )
    assert sorted(snaps) == [256, 288, 320]
    short = agents.train("droq", ENV, seed=4, total_steps=288, **FEW)
    jax.tree.map(np.testing.assert_array_equal, snaps[288], short.params)


def test_continued_training_starts_from_the_pretrained_state(trained):
    """A continued run that stops at its warm-up (the policy's own exploration, no gradient step)
    holds the pretrained policy exactly; training on moves it; sizes or a learner that do not match
    are refused."""
    warm_only = agents.train("droq", ENV, seed=3, total_steps=256, start_from=trained, **HYPER)
    jax.tree.map(np.testing.assert_array_equal, warm_only.params, trained.params)
    assert (
        warm_only.curve["normalized_power"][0] == trained.curve["normalized_power"][-1]
    )  # same evaluation keys
    on = agents.train("droq", ENV, seed=8, total_steps=256 + 512, start_from=[trained], **HYPER)
    assert not np.allclose(
        on.params["actor"]["params"]["MLP_0"]["Dense_0"]["kernel"],
        trained.params["actor"]["params"]["MLP_0"]["Dense_0"]["kernel"],
    )
    assert agents.evaluate(on, ENV, episodes=8, seed=1).summary["final_mean"] >= 0.8
    with pytest.raises(ValueError, match="network sizes must match"):
        agents.train(
            "droq", ENV, seed=8, total_steps=256, start_from=trained, **dict(HYPER, hidden=(16, 16))
        )
    with pytest.raises(ValueError, match="one TrainResult per seed"):
        agents.train_seeds(
            "droq", ENV, seeds=[1, 2], total_steps=256, start_from=[trained], **HYPER
        )
    loaded = agents.TrainResult(**{**vars(trained), "state": None})
    with pytest.raises(
        ValueError, match="start_from must hold droq TrainResults trained in this process"
    ):
        agents.train("droq", ENV, seed=8, total_steps=256, start_from=loaded, **HYPER)


def test_unseen_bench_is_the_lab_preset_at_twice_its_size_redrawn():
    import ops_jax
    from ops_jax import imperfections

    hard = dict(stages=5, mode="hard", model="phasor")
    a, b = budget.unseen_bench(hard, 1011), budget.unseen_bench(hard, 1012)
    assert a == budget.unseen_bench(hard, 1011) and a != b
    lab2 = imperfections.preset("lab", 5, 2.0)
    for key in ("waveplate_error_deg", "readout_offset", "actuator_gain_error"):
        assert sorted(np.abs(a[key])) == pytest.approx(sorted(np.abs(lab2[key])))
    env, params = ops_jax.make(**a)
    assert env.config.imperfect and 0.5 < float(params.lab.p_best) / env.p_max < 1.0


def test_bad_hyperparameters_name_the_field():
    with pytest.raises(
        ValueError, match=r"^dropout must be a finite number in \[0, 0.9\], got 1.5"
    ):
        DroQConfig.preset("budget", dropout=1.5)
    with pytest.raises(ValueError, match="exactly one of updates_per_iter .* and utd_ratio"):
        DroQConfig.preset("budget", updates_per_iter=4)
    with pytest.raises(ValueError, match=r"utd_ratio \* num_envs \* unroll must be a whole number"):
        agents.train("droq", ENV, utd_ratio=0.5)
    with pytest.raises(ValueError, match="learning_starts must be >= batch_size"):
        agents.train("droq", ENV, batch_size=512, learning_starts=256)
    with pytest.raises(TypeError, match=r"unknown DroQ hyperparameter\(s\) \['expl_std'\]"):
        agents.train("droq", ENV, expl_std=0.1)


def test_training_reward_is_the_learners_choice():
    assert (
        DroQConfig.preset("budget").train_reward == "linear"
        and TD3Config.preset("paper").train_reward is None
    )
    with pytest.raises(
        ValueError, match=r"^train_reward must be one of \['paper', 'reference', 'linear'\]"
    ):
        DroQConfig.preset("budget", train_reward="power")
    rewards = {}
    for reward in ("paper", "linear"):
        metrics = []
        agents.train(
            "droq",
            ENV,
            seed=0,
            total_steps=256 + 64,
            progress_fn=lambda s, m: metrics.append(m),
            train_reward=reward,
            **dict(HYPER, eval_every=64),
        )
        rewards[reward] = metrics[-1]["reward"]
    # the same start, a reward of -sqrt(-r) of the paper's: lower wherever P is below P_max
    assert rewards["linear"] < rewards["paper"] - 0.02, rewards


def test_td3_update_to_data_ratio():
    """TD3's utd_ratio sets the gradient steps per iteration (32 envs x 0.25 = 8); presets keep
    updates_per_iter."""
    c = TD3Config.preset("fast", updates_per_iter=None, utd_ratio=0.25)
    assert replay.updates_per_iter(c) == 8 and TD3Config.from_hyper(c.to_hyper()) == c
    assert replay.updates_per_iter(TD3Config.preset("fast")) == 4
    budget_cfg = TD3Config.preset("budget")
    assert (
        budget_cfg.num_envs == 1 and budget_cfg.utd_ratio >= 1 and budget_cfg.total_steps <= 20_000
    )


def test_budget_plan_cells_and_report(tmp_path):
    default = [c for c in budget.cells("default") if c.kind in ("learner", "reference")]
    assert {c.algo for c in default} == {"droq", "spgd", "physics"}
    assert {c.algo for c in budget.cells("full")} == {
        "droq",
        "td3",
        "sac",
        "ppo",
        "spgd",
        "physics",
    }
    # the default plan fits the sweep's 20 minutes on 2 workers by the cost model (docs/learners.md:
    # measured)
    assert sum(map(budget.cost, budget.cells("default"))) <= 2 * 20 * 60 * 1.05
    assert {c.env for c in default} == {"hard", "hard + lab"}
    assert all(
        c.checkpoints == (1000, 2000, 5000, 10_000, 20_000) and c.seed not in range(5)
        for c in default
    )
    assert len({c.seed for c in default if c.algo == "droq"}) == 5
    # a cell names every setting its preset resolves to, so a changed preset is another cell, never
    # a stored one
    droq_cell = next(c for c in default if c.algo == "droq")
    assert (
        droq_cell.hyper == {"config": "budget"}
        and droq_cell.settings == DroQConfig.preset("budget").to_hyper()
    )
    assert (
        len([c for c in default if c.algo == "spgd"]) == 2
    )  # one per environment: nothing to seed
    with pytest.raises(ValueError, match="preset must be one of"):
        budget.cells("slow")
    narrowed = budget.cells("default", only=["droq", "spgd"], seeds=[11, 12], envs=["hard"])
    assert [(c.algo, c.seed, c.env) for c in narrowed] == [
        ("droq", 11, "hard"),
        ("droq", 12, "hard"),
        ("spgd", 11, "hard"),
    ]
    with pytest.raises(ValueError, match=r"only must name some of \["):
        budget.cells("default", only=["a2c"])

    def record(algo, seed, scores, kind="learner"):
        cell = budget.Cell(
            kind=kind,
            algo=algo,
            hyper={},
            env="hard",
            env_config={},
            seed=seed,
            checkpoints=[1000, 2000, 5000],
            episodes=32,
            eval_seed=4242,
            settings={},
        )
        return {
            "cell": cell,
            "result": {"scores": dict(zip(["1000", "2000", "5000"], scores)), "train_s": 1.0},
        }

    records = [
        record("droq", 1, [0.2, 0.91, 0.95]),
        record("droq", 2, [0.3, 0.5, 0.92]),
        record("droq", 3, [0.1, 0.4, 0.5]),
        record("td3", 1, [0.1, 0.2, 0.3]),
        record("spgd", 1, [0.85] * 3, "reference"),
    ]
    text = budget.report(records, tmp_path)
    rows = {
        line.split(" | ")[1].split(" (")[0]: line
        for line in text.splitlines()
        if line.startswith("| hard |") and " ± " in line
    }  # the mean ± std table
    assert (
        "| 5,000 (2/3) |" in rows["DroQ"]
        and "not reached" in rows["TD3"]
        and "no training" in rows["SPGD"]
    )
    last = [0.95, 0.92, 0.5]
    assert f"{np.mean(last):.3f} ± {np.std(last):.3f} |" in rows["DroQ"]
    assert (tmp_path / "budget.png").stat().st_size > 5000 and (tmp_path / "budget.json").exists()


def test_budget_plan_simulator_to_bench(tmp_path, capsys):
    """Protocol (b): one adapt cell per seed, each on its own unseen bench; its table gives mean and
    worst seed."""
    adapt = [c for c in budget.cells("default") if c.kind == "adapt"]
    assert [c.seed for c in adapt] == [11, 12, 13, 14, 15] and len(
        {c.bench_seed for c in adapt}
    ) == 5
    assert all(
        c.pretrain_env["randomize"] == c.pretrain_env["randomize_layout"] == 1.0
        and c.checkpoints[-1] <= 5000
        for c in adapt
    )
    assert budget.cells("default", envs=[budget.BENCH], seeds=[11])[0].kind == "adapt"
    at_lab = budget.cells("default", envs=[budget.BENCH], seeds=[11], bench_scale=1.0)
    assert (
        {c.env_config["imperfection_scale"] for c in at_lab}
        == {1.0}
        != {adapt[0].env_config["imperfection_scale"]}
    )
    assert at_lab[0].env_config == budget.unseen_bench(
        budget.PRESETS["default"]["adapt"]["bench_env"], 1011, 1.0
    )
    for bad in (0, -1.0, 11.0, "2"):
        with pytest.raises(ValueError, match="bench_scale must be a number in"):
            budget.cells("default", bench_scale=bad)
    framed = budget.cells("default", envs=[budget.BENCH], seeds=[11], bench_probe="frame")
    assert {c.env_config["probe"] for c in framed} == {"frame"} and "probe" not in adapt[
        0
    ].env_config
    with pytest.raises(ValueError, match=r"bench_probe must be one of \['instant', 'frame'\]"):
        budget.cells("default", bench_probe="later")
    trimmed = budget.cells("default", envs=[budget.BENCH], seeds=[11], bench_trim="bench")
    assert [c.trim for c in trimmed if c.kind == "adapt"] == [{"config": "bench"}] and adapt[
        0
    ].trim == {}
    with pytest.raises(
        ValueError, match=r"bench_trim must be one of \[.*'guarded'\], got 'coarse'"
    ):
        budget.cells("default", bench_trim="coarse")
    with pytest.raises(SystemExit):
        command.main(["--bench-scale", "0", "--out", str(tmp_path)])
    assert (
        "--bench-scale must be a number in (0, 10]" in capsys.readouterr().err
        and not (tmp_path / "cells").exists()
    )
    assert not [
        c for c in budget.cells("full", only=["td3"]) if c.kind in ("adapt", "bench reference")
    ]
    on_bench = [c for c in budget.cells("default") if c.kind == "bench reference"]
    assert sorted((c.algo, c.bench_seed) for c in on_bench) == sorted(
        (a, c.bench_seed) for a in ("spgd", "physics") for c in adapt
    )
    assert all(
        c.env_config == next(a.env_config for a in adapt if a.bench_seed == c.bench_seed)
        for c in on_bench
    )
    by_algo = {c.algo: c for c in budget.cells("default") if c.kind in ("learner", "reference")}
    assert (
        budget.cost(by_algo["droq"]) > budget.cost(by_algo["spgd"]) > 0
        and budget.cost(adapt[0]) > 0
    )
    assert (
        "cost" not in by_algo["droq"].to_dict()
    )  # an estimate, not part of the cell's configuration

    def record(seed, before, after):
        return {
            "cell": dataclasses.replace(adapt[0], seed=seed, bench_seed=seed + 1000),
            "result": {
                "before": before,
                "scores": dict(zip(["1000", "2000", "5000"], after)),
                "pretrain_s": 9.0,
                "train_s": 3.0,
            },
        }

    def reference(algo, bench_seed, score):
        cell = next(c for c in on_bench if c.algo == algo and c.bench_seed == bench_seed)
        return {
            "cell": cell,
            "result": {"scores": {str(k): score for k in cell.checkpoints}, "train_s": 1.0},
        }

    records = [
        record(11, 0.6, [0.7, 0.8, 0.97]),
        record(12, 0.5, [0.9, 0.93, 0.91]),
        reference("spgd", 1011, 0.96),
        reference("spgd", 1012, 0.94),
        reference("physics", 1011, 0.95),
    ]
    text = budget.report(records, tmp_path)
    assert "| SPGD on the bench | Physics on the bench |" in text
    assert "| 11 | 1011 | 0.600 | 0.700 | 0.800 | 0.970 | 0.960 | 0.950 | 9 | 3 |" in text
    assert "| 12 | 1012 | 0.500 | 0.900 | 0.930 | 0.910 | 0.940 | - | 9 | 3 |" in text
    assert "| worst | | 0.500 | 0.700 | 0.800 | 0.910 | 0.940 | 0.950 | | |" in text
    assert "| unseen bench |" not in text  # the bench references stay out of protocol (a)'s table
    assert (tmp_path / "budget.png").stat().st_size > 5000
    # with the trim's scores ("0": around the pretrained policy), two more columns
    for r, trimmed in zip(
        records,
        (
            {"0": 0.8, "1000": 0.9, "2000": 0.95, "5000": 0.99},
            {"0": 0.7, "1000": 0.9, "2000": 0.95, "5000": 0.96},
        ),
    ):
        r["result"]["trimmed"] = trimmed
    text = budget.report(records, tmp_path)
    assert "| after 5,000 | before, trimmed | after 5,000, trimmed | SPGD on the bench |" in text
    assert (
        "| 11 | 1011 | 0.600 | 0.700 | 0.800 | 0.970 | 0.800 | 0.990 | 0.960 | 0.950 | 9 | 3 |"
        in text
    )
    assert "| worst | | 0.500 | 0.700 | 0.800 | 0.910 | 0.700 | 0.960 | 0.940 | 0.950 | | |" in text


def test_budget_cells_are_frozen_records_of_their_stored_form():
    """A cell is a frozen record; its stored form lists the fields in their order, the protocol (b)
    fields only on protocol (b)'s cells, and reads back equal; a misspelt field, an unknown kind or
    a protocol (b) field on another kind's cell fails where the record is built."""
    cells = budget.cells("default")
    assert {c.kind for c in cells} == {"learner", "reference", "adapt", "bench reference"}
    for c in cells:
        stored = c.to_dict()
        assert budget.Cell.from_dict(stored) == c and isinstance(stored["checkpoints"], list)
        assert list(stored) == [f.name for f in dataclasses.fields(c) if f.name in stored]
        assert ("bench_seed" in stored) == (c.kind in ("adapt", "bench reference"))
        assert ("pretrain_steps" in stored) == (c.kind == "adapt")
    with pytest.raises(dataclasses.FrozenInstanceError):
        cells[0].seed = 1
    stored = cells[0].to_dict()
    with pytest.raises(TypeError, match="sead"):
        budget.Cell.from_dict({**stored, "sead": 1})
    with pytest.raises(ValueError, match="kind must be one of"):
        budget.Cell.from_dict({**stored, "kind": "learned"})
    with pytest.raises(ValueError, match="bench_seed"):
        budget.Cell.from_dict({**stored, "bench_seed": 1011})


def test_budget_quick_cell_end_to_end():
    """A reference cell of the quick preset: one evaluation, the same score at every checkpoint."""
    cell = next(c for c in budget.cells("quick") if c.algo == "spgd")
    rec = budget.compute(cell)
    assert set(rec["scores"]) == {"600", "1200"} and len(set(rec["scores"].values())) == 1
    assert 0.5 < rec["scores"]["600"] <= 1.0


def test_budget_baselines_example_without_its_libraries():
    """examples/budget_baselines.py imports without torch or sbx and refuses an unknown learner."""
    import importlib.util
    from pathlib import Path

    import gymnasium

    path = Path(__file__).resolve().parents[3] / "examples" / "budget_baselines.py"
    spec = importlib.util.spec_from_file_location("budget_baselines", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    env = gymnasium.make("ops_jax/OPS-v0", **{**example.ENV_KWARGS, "max_steps": 3})
    with pytest.raises(ValueError, match="algo must be one of"):
        example.make_model("sb3-ppo", env, 0)
    finals = example._final_power()(
        env, lambda obs: np.zeros(env.action_space.shape, np.float32), 2, 0
    )
    assert finals.shape == (2,) and np.all((finals > 0) & (finals <= 1.0 + 1e-5))
