"""TD3: learns a small configuration (clear margin over doing nothing), is deterministic per seed,
checkpoints round-trip to identical actions, and the training CLI runs end to end."""

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

import agents
from agents import TD3Config
from agents.learners.offpolicy import driver as offpolicy, replay, td3
from idle import learned_and_idle

REPO = Path(__file__).resolve().parents[3]
ENV = {"stages": 3, "mode": "easy", "model": "phasor"}
HYPER = dict(
    num_envs=32,
    hidden=(64, 64),
    batch_size=128,
    learning_starts=1024,
    eval_every=8192,
    eval_episodes=8,
)
STEPS = 16_000


@pytest.fixture(scope="module")
def trained():
    return agents.train("td3", ENV, seed=3, total_steps=STEPS, **HYPER)


def test_td3_beats_doing_nothing(trained):
    learned, baseline = learned_and_idle(trained, ENV, 32)
    assert learned["final_mean"] >= max(0.8, baseline + 0.25), (learned, baseline)
    assert trained.curve["step"][-1] >= STEPS
    assert np.all(np.diff(trained.curve["step"]) > 0)
    wt = trained.wall_time
    assert wt["total"] >= wt["simulation"] + wt["optimisation"] > 0


def test_same_seed_same_result(trained):
    reported = []
    again = agents.train(
        "td3", ENV, seed=3, total_steps=STEPS, progress_fn=lambda *a: reported.append(a), **HYPER
    )
    assert [step for step, _ in reported] == again.curve[
        "step"
    ].tolist()  # progress_fn(step, metrics)
    np.testing.assert_array_equal(
        [m["normalized_power"] for _, m in reported], again.curve["normalized_power"]
    )
    np.testing.assert_array_equal(
        trained.curve["normalized_power"], again.curve["normalized_power"]
    )
    jax.tree.map(np.testing.assert_array_equal, trained.params, again.params)


def test_modes_share_one_build(trained, compiles):
    """Another mode reuses the compiled training programs (EnvParams are arguments) and still
    trains on its own dynamics."""
    with compiles() as n:
        hard = agents.train("td3", {**ENV, "mode": "hard"}, seed=3, total_steps=STEPS, **HYPER)
    assert n[0] == 0
    assert not np.array_equal(hard.curve["normalized_power"], trained.curve["normalized_power"])


def test_checkpoint_round_trip_identical_actions(trained, tmp_path):
    agents.save(tmp_path / "ckpt", trained)
    loaded = agents.load(tmp_path / "ckpt")
    obs = jax.random.normal(jax.random.key(0), (16, 2**3 + 3))
    a, _ = trained.policy().act(trained.params, (), obs, None, None)
    b, _ = loaded.policy().act(loaded.params, (), obs, None, None)
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert np.abs(np.asarray(a)).max() > 0


def test_bad_hyperparameters():
    with pytest.raises(TypeError, match="unknown TD3 hyperparameter"):
        TD3Config.preset("fast", learning_rate=1e-3)
    with pytest.raises(ValueError, match="gamma"):
        TD3Config.preset("fast", gamma=1.5)
    with pytest.raises(ValueError, match="config"):
        TD3Config.make("slow")
    with pytest.raises(ValueError, match="learning_starts"):
        agents.train(
            "td3", ENV, config=TD3Config.preset("fast", batch_size=128), learning_starts=64
        )


def test_cli_end_to_end(tmp_path):
    from agents import cli

    # Same setting as the fixture and a budget of one training chunk of the same length (1024
    # warm-up steps + 234 iterations of 32 envs), so the compiled functions are reused.
    out = tmp_path / "run"
    argv = [
        "--algo",
        "td3",
        "--stages",
        "3",
        "--mode",
        "easy",
        "--out",
        str(out),
        "--steps",
        "8512",
        "--seed",
        "1",
        "--episodes",
        "4",
        "--env",
        "model='phasor'",
        "--set",
    ] + [f"{k}={v!r}" for k, v in HYPER.items()]
    summary = cli.main(argv)
    assert summary["hyper"]["hidden"] == [64, 64] and summary["train_steps"] >= 8512
    assert (out / "checkpoint" / "meta.json").exists() and (out / "curve.png").stat().st_size > 1000
    rows = list(csv.DictReader(open(out / "curve.csv")))
    assert len(rows) == 2 and int(rows[-1]["step"]) >= 8512
    assert (
        json.loads((out / "summary.json").read_text())["evaluation"]["episodes"]
        == summary["evaluation"]["episodes"]
        == 4
    )
    assert agents.load(out / "checkpoint").algo == "td3"
    res = subprocess.run(
        [sys.executable, "-m", "agents", "--help"],
        cwd=REPO,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        timeout=60,
    )
    assert res.returncode == 0 and "--algo" in res.stdout


def test_cli_logdir_writes_the_curve_to_tensorboard(tmp_path):
    """``--logdir``: the evaluation curve, losses and update ratio as TensorBoard scalars against
    env steps."""
    from agents import cli

    pytest.importorskip("tensorboardX")
    from test_tensorboard import read_scalars

    out, logdir = tmp_path / "run", tmp_path / "tb"
    argv = [
        "--algo",
        "td3",
        "--stages",
        "3",
        "--mode",
        "easy",
        "--out",
        str(out),
        "--steps",
        "8512",
        "--seed",
        "1",
        "--episodes",
        "4",
        "--env",
        "model='phasor'",
        "--logdir",
        str(logdir),
        "--set",
    ] + [f"{k}={v!r}" for k, v in HYPER.items()]
    summary = cli.main(argv)
    rows = list(csv.DictReader(open(out / "curve.csv")))
    scalars = read_scalars(logdir)
    steps, values = scalars["eval/normalized_power"]
    assert steps == [int(r["step"]) for r in rows]
    np.testing.assert_allclose(values, [float(r["normalized_power"]) for r in rows], rtol=1e-6)
    c = TD3Config.from_hyper(summary["hyper"])  # the summary's stored form
    ratio = replay.updates_per_iter(c) / (c.num_envs * c.unroll)
    np.testing.assert_allclose(scalars["train/update_ratio"][1], ratio, rtol=1e-6)
    assert scalars["loss/critic_loss"][0] == steps[1:]  # losses from the first training chunk on
    assert np.all(np.isfinite(scalars["loss/critic_loss"][1]))


FEW = dict(HYPER, eval_every=320)  # the warm-up, then chunks of 10 iterations (40 gradient steps)
FEW_STEPS = 1024 + 2 * 320


def test_seeds_in_one_call_and_on_two_devices(tmp_path, this_build):
    """train_seeds: reproducible for a seed list, the same draws as each seed alone (equal before
    any gradient step, equal to float rounding after 80), the seeds differ; with two (forced CPU)
    devices (a subprocess, started first to overlap) the seed axis is split across them."""
    code = (
        "import json, sys, numpy as np, jax, agents; from agents.learners.offpolicy import td3;"
        f"both = td3.train_seeds({ENV!r}, seeds=[3, 5], total_steps={FEW_STEPS}, **{FEW!r});"
        "np.savez(sys.argv[1], *[np.ravel(x) for r in both for x in jax.tree.leaves(r.params)]);"
        "sharded = [str(agents.evaluation.split_over_devices(2, 'seeds').spec)];"
        "print(json.dumps(dict(devices=jax.device_count(), sharded=sharded)))"
    )
    env = {
        **os.environ,
        "PYTHONPATH": str(REPO),  # this process's build, on two devices
        "XLA_FLAGS": f"{os.environ['XLA_FLAGS']} --xla_force_host_platform_device_count=2",
    }
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(tmp_path / "two.npz")],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )

    both = agents.train_seeds("td3", ENV, seeds=[3, 5], total_steps=FEW_STEPS, **FEW)
    again = td3.train_seeds(ENV, seeds=[3, 5], total_steps=FEW_STEPS, **FEW)
    solo = agents.train("td3", ENV, seed=5, total_steps=FEW_STEPS, **FEW)
    assert [r.seed for r in both] == [3, 5] and both[0].wall_time["seeds_in_call"] == 2
    jax.tree.map(np.testing.assert_array_equal, both[1].params, again[1].params)
    assert both[1].curve["normalized_power"][0] == solo.curve["normalized_power"][0]
    np.testing.assert_allclose(
        both[1].curve["normalized_power"], solo.curve["normalized_power"], atol=1e-4
    )
    jax.tree.map(
        lambda a, b: np.testing.assert_allclose(a, b, atol=1e-4), both[1].params, solo.params
    )
    kernel = lambda r: r.params["actor"]["params"]["MLP_0"]["Dense_0"]["kernel"]  # noqa: E731
    assert not np.allclose(kernel(both[0]), kernel(both[1]))
    with pytest.raises(ValueError, match="distinct"):
        td3.train_seeds(ENV, seeds=[1, 1], total_steps=FEW_STEPS, **FEW)

    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr[-2000:]
    out = json.loads(stdout.strip().splitlines()[-1])
    assert out["devices"] == 2 and len(out["sharded"]) == 1 and "seeds" in out["sharded"][0], out
    two = np.load(tmp_path / "two.npz")
    two = [two[f"arr_{i}"] for i in range(len(two.files))]
    ours = [np.ravel(x) for r in (both[0], solo) for x in jax.tree.leaves(r.params)]
    for a, b in zip(two, ours):
        np.testing.assert_allclose(a, b, atol=1e-4)


@pytest.mark.parametrize("total", [4_096, 20_000, 60_000, 60_160, 300_000])
def test_schedule_keeps_the_budget(total):
    c = TD3Config.preset("fast", eval_every=5_000, total_steps=total)
    warm, n_chunks, chunk = offpolicy.schedule(c)
    per_iter = c.num_envs * c.unroll
    trained = (warm + n_chunks * chunk) * per_iter
    assert trained <= total and total - trained < per_iter * max(n_chunks, 1)
    assert warm * per_iter >= c.learning_starts


def test_budget_below_the_warm_up_is_refused():
    with pytest.raises(
        ValueError, match="total_steps must be >= the warm-up of learning_starts = 4096"
    ):
        agents.train("td3", ENV, total_steps=4_000)
