"""The shared agents API: evaluate (probes counted, deterministic, device-count independent),
checkpoints (round trip, missing, corrupt), bad input."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import agents
from agents import SPGDConfig
from agents.api import Policy, TrainResult
from ops_jax import EnvSpec

REPO = Path(__file__).resolve().parents[2]
ENV = {"stages": 3, "mode": "hard"}


def _dither_policy():
    def act(params, carry, obs, key, probe):
        d = 0.05 * jnp.sign(jax.random.normal(key, obs.shape[:1] + (3,)))
        gain = probe(d) - probe(-d)  # two extra measurements
        return jnp.clip(params["k"] * gain[:, None] * d / 0.05, -1, 1), carry

    return Policy(lambda key, obs: (), act)


def test_evaluate_counts_probes_and_is_deterministic():
    pair = (_dither_policy(), {"k": jnp.float32(5.0)})
    a = agents.evaluate(pair, ENV, episodes=6, seed=3, steps=20)
    b = agents.evaluate(pair, ENV, episodes=6, seed=3, steps=20)
    c = agents.evaluate(pair, ENV, episodes=6, seed=4, steps=20)
    assert a.normalized_power.shape == (6, 20)
    assert a.summary["measurements_per_step"] == 3
    assert b is not a and not np.shares_memory(
        a.normalized_power, b.normalized_power
    )  # computed again
    np.testing.assert_array_equal(a.normalized_power, b.normalized_power)
    assert not np.allclose(a.normalized_power, c.normalized_power)
    assert 0 < a.summary["final_mean"] <= 1


def test_evaluate_is_the_same_on_two_devices(this_build):
    code = (
        "import numpy as np, jax, jax.numpy as jnp, agents; from agents.api import Policy;"
        "p = Policy(lambda k, o: (), lambda pr, c, o, k, probe: (jnp.tanh(-3 * o[:, -3:]), c));"
        "r = agents.evaluate(p, {'stages': 3, 'mode': 'hard'}, episodes=8, seed=1, steps=15);"
        "print(len(jax.devices())); np.save(__import__('sys').argv[1], r.normalized_power)"
    )
    outs = []
    for count in (1, 2):
        path = f"/tmp/ops_eval_{count}_{os.getpid()}.npy"
        # this process's build
        flags = f"{os.environ['XLA_FLAGS']} --xla_force_host_platform_device_count={count}"
        env = {**os.environ, "PYTHONPATH": str(REPO), "XLA_FLAGS": flags}
        res = subprocess.run(
            [sys.executable, "-c", code, path], env=env, capture_output=True, text=True, check=True
        )
        assert res.stdout.strip() == str(count)
        outs.append(np.load(path))
        os.unlink(path)
    np.testing.assert_allclose(outs[0], outs[1], atol=1e-6)


def test_checkpoint_round_trip_missing_and_corrupt(tmp_path):
    params = {"k": np.float32(5.0), "w": np.arange(6, dtype=np.float32).reshape(2, 3)}
    result = TrainResult(
        "spgd",
        EnvSpec(stages=3, mode="easy"),
        SPGDConfig.make(kp=0.5),
        params,
        {"step": np.array([0, 10]), "normalized_power": np.array([0.5, 0.9])},
        {"simulation": 1.0, "optimisation": 0.0, "total": 1.0},
        7,
    )
    path = agents.save(tmp_path / "ck", result)
    (tmp_path / "plain").mkdir()
    assert path.stat().st_mode == (tmp_path / "plain").stat().st_mode  # its neighbours' permissions
    back = agents.load(path)
    assert back.algo == "spgd" and back.seed == 7 and back.config == SPGDConfig.make(kp=0.5)
    assert back.env_spec == EnvSpec(stages=3, mode="easy")
    meta = json.loads((path / "meta.json").read_text())  # the stored form: dicts
    assert meta["env_config"] == {"stages": 3, "mode": "easy"} and meta["hyper"]["kp"] == 0.5
    np.testing.assert_array_equal(np.asarray(back.curve["normalized_power"]), [0.5, 0.9])
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        agents.load(tmp_path / "nothing")
    blob = path / "params.msgpack"
    blob.write_bytes(blob.read_bytes()[:-3] + b"xyz")
    with pytest.raises(ValueError, match="corrupt checkpoint"):
        agents.load(path)


@pytest.mark.parametrize(
    "call, exc, words",
    [
        (lambda: agents.train("dqn", ENV), ValueError, "algo"),
        (lambda: agents.train("spgd", "stages=5"), TypeError, "env_config"),
        (lambda: agents.train("spgd", {"stages": 0}), ValueError, "stages"),
        (lambda: agents.train("spgd", ENV, total_steps=-5), ValueError, "total_steps"),
        (lambda: agents.evaluate(_dither_policy(), ENV, episodes=0), ValueError, "episodes"),
        (lambda: agents.evaluate("policy", ENV), TypeError, "evaluate takes"),
        (
            lambda: agents.evaluate(
                TrainResult("spgd", EnvSpec(stages=5), SPGDConfig.make(), None, {}, {}, 0), ENV
            ),
            ValueError,
            r"trained on observations of stages=5.*env_config gives stages=3",
        ),
        (
            lambda: TrainResult("spgd", {"stages": 5}, SPGDConfig.make(), None, {}, {}, 0),
            TypeError,
            r"env_spec must be an ops_jax.EnvSpec \(of a dict: EnvSpec.from_options\), got dict",
        ),
        (
            lambda: TrainResult("spgd", EnvSpec(), {"kp": 0.5}, None, {}, {}, 0),
            TypeError,
            r"config must be an agents.config.AlgoConfig .*, got dict",
        ),
        (
            lambda: agents.api.algo_module("spgd").make_policy(ENV, {"kp": 0.5}),
            TypeError,
            "config must be a SPGDConfig or None",
        ),
    ],
)
def test_bad_input(call, exc, words):
    with pytest.raises(exc, match=words):
        call()


def test_evaluate_compiles_once_per_policy_and_static_config(compiles):
    """Seeds, testing environments and other modes with the same static configuration reuse one
    compiled evaluation program; another static configuration (feedback_k) gets its own."""
    env = {"stages": 3, "mode": "easy", "model": "phasor"}
    result = agents.train("spgd", env, seed=0)  # evaluates itself once (32 episodes)
    with compiles() as n:
        for mode, seed in (("easy", 1), ("easy", 2), ("hard", 1), ("medium", 3)):
            agents.evaluate(result, {**env, "mode": mode}, episodes=32, seed=seed, steps=200)
    assert n[0] == 0
    for algo, hyper in (
        ("spgd", {}),
        ("physics", {"starts": 3, "iters": 2}),
    ):  # trained in another mode
        first = agents.train(algo, env, seed=0, **hyper)
        with compiles() as n:
            agents.evaluate(
                agents.train(algo, {**env, "mode": "medium"}, seed=0, **hyper),
                env,
                episodes=32,
                seed=1,
            )
        assert n[0] == 0, algo
        if algo == "physics":  # its numbers from the environment are parameters, not constants
            assert set(first.params) == {"action_scale", "window"}
    with compiles() as n:
        agents.evaluate(result, {**env, "feedback_k": 3}, episodes=32, seed=1)
    assert n[0] >= 1  # another static configuration: its own program


def test_repeated_evaluation_runs_the_program_again(compiles):
    """Only the compiled program is kept: a repeated call runs it (the policy's host callback fires
    again) without compiling, and gives the same numbers in a new result."""
    runs = []
    inner = _dither_policy()

    def act(params, carry, obs, key, probe):
        jax.debug.callback(lambda: runs.append(1))
        return inner.act(params, carry, obs, key, probe)

    pair = (Policy(inner.init, act), {"k": jnp.float32(5.0)})
    a = agents.evaluate(pair, ENV, episodes=4, seed=11, steps=10)
    before = len(runs)
    with compiles() as n:
        b = agents.evaluate(pair, ENV, episodes=4, seed=11, steps=10)
    assert n[0] == 0 and len(runs) > before
    assert b is not a
    np.testing.assert_array_equal(a.normalized_power, b.normalized_power)
    other = agents.evaluate(
        (pair[0], {"k": jnp.float32(4.0)}), ENV, episodes=4, seed=11, steps=10
    )  # other params
    assert not np.array_equal(other.normalized_power, a.normalized_power)
    assert not np.array_equal(
        agents.evaluate(pair, ENV, episodes=4, seed=12, steps=10).normalized_power,
        a.normalized_power,
    )


def test_training_cli_shows_progress_and_writes_its_summary(tmp_path):
    """``python -m agents`` (here SPGD, whose training is one evaluation): a progress line
    with the evaluation P/Pmax, and summary.json with the evaluation it returns."""
    out = tmp_path / "spgd"
    env = {**os.environ, "PYTHONPATH": str(REPO), "OPS_JAX_PROGRESS_INTERVAL": "0"}
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "agents",
            "--algo",
            "spgd",
            "--stages",
            "2",
            "--mode",
            "easy",
            "--episodes",
            "4",
            "--out",
            str(out),
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["algo"] == "spgd" and summary["evaluation"]["episodes"] == 4
    assert 0 < summary["evaluation"]["final_mean"] <= 1
    assert re.search(r"P/Pmax \d\.\d{3}, \d+:\d\d compiling and warming up", res.stderr), res.stderr
    assert "(simulation " in res.stdout and "both include compiling" in res.stdout, res.stdout
    assert (out / "summary.json").stat().st_mode == (
        out / "curve.csv"
    ).stat().st_mode  # its neighbours' permissions


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--algo", "td3", "--stages", "0"], "stages must be an integer >= 1, got 0"),
        (["--algo", "physics", "--env", "observe_lengths=False"], 'config="frames"'),
    ],
)
def test_training_cli_refuses_bad_arguments_in_one_line(argv, words, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO), "OPS_JAX_PROGRESS_INTERVAL": "0"}
    res = subprocess.run(
        [sys.executable, "-m", "agents", *argv, "--out", str(tmp_path / "run")],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.splitlines() == [
        f"python -m agents: error: {res.stderr.split('error: ', 1)[-1].strip()}"
    ]
    assert words in res.stderr and not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--algo", "spgd", "--steps", "400"], "--steps: spgd trains nothing"),
        (
            ["--algo", "droq", "--config", "budget", "--steps", "500"],
            "--steps 500 takes no gradient step: its first 1,000 env steps are the random warm-up",
        ),
        (
            ["--algo", "td3", "--steps", "4096"],
            "--steps 4096 takes no gradient step: its first 4,096 env steps are the random warm-up",
        ),
    ],
)
def test_training_cli_refuses_a_budget_that_cannot_learn_in_one_line(argv, words, tmp_path):
    """--steps for a controller with nothing to train, or one that ends within a learner's warm-up
    (no gradient step): one error line before any other output, naming the budget to type instead;
    exit status 2, nothing written."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "OPS_JAX_PROGRESS_INTERVAL": "0"}
    res = subprocess.run(
        [sys.executable, "-m", "agents", *argv, "--stages", "2", "--out", str(tmp_path / "run")],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 2 and res.stdout == "", res.stderr
    said = res.stderr.strip()
    assert res.stderr.splitlines() == [said], said  # one line, no progress before it
    assert said.startswith(f"python -m agents: error: {words}"), said
    if "takes no gradient step" in words:
        assert re.search(r"; try --steps \d+ \(--steps \d+ takes one\)$", said), said
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("algo", sorted(agents.ALGOS))
def test_every_algorithm_has_one_config_type(algo):
    """Presets build and round-trip through the stored form; one error style for every algorithm."""
    import dataclasses

    from agents.registry import CONFIG_TYPES

    cls = CONFIG_TYPES[algo]
    for name in cls.PRESETS:
        config = cls.preset(name)
        assert cls.from_hyper(config.to_hyper()) == config
        with pytest.raises(dataclasses.FrozenInstanceError):
            config.total_steps = 1
    field = next(f for f in cls.names() if isinstance(getattr(config, f), float))
    changed = cls.preset(None, **{field: getattr(config, field) / 2})
    assert getattr(changed, field) == getattr(config, field) / 2
    with pytest.raises(ValueError, match=rf"^{field} must be a finite number in [\[(].*got -1"):
        cls.preset(None, **{field: -1.0})
    with pytest.raises(
        TypeError, match=r"unknown .* hyperparameter\(s\) \['nope'\]; accepted: config, \["
    ):
        agents.train(algo, ENV, nope=1)


def test_evaluate_reports_p_best_and_builds_the_environment_once(monkeypatch):
    """On an imperfect configuration ``evaluate`` runs the P_best search once and returns P/P_best
    beside P/Pmax; on the ideal system the two are the same array."""
    from agents import envs
    from ops_jax import imperfections

    calls = []
    search = imperfections.best_power
    monkeypatch.setattr(imperfections, "best_power", lambda *a: calls.append(1) or search(*a))
    lab = {"stages": 5, "mode": "hard", "imperfections": "lab"}
    result = agents.train("spgd", {"stages": 5, "mode": "hard"}, curve_episodes=2)
    envs._BUILT.clear()
    ev = agents.evaluate(result, lab, episodes=4, seed=1)
    assert len(calls) == 1
    env, params = envs.built(lab)
    ratio = env.p_max / float(params.lab.p_best)
    assert ratio > 1.0 and ev.summary["score"] == "P/P_best"
    np.testing.assert_allclose(ev.normalized_power_best, ev.normalized_power * ratio, rtol=1e-6)
    assert ev.summary["final_mean_best"] == pytest.approx(ev.normalized_power_best[:, -1].mean())
    ideal = agents.evaluate(result, {"stages": 5, "mode": "hard"}, episodes=4, seed=1)
    assert (
        ideal.normalized_power_best is ideal.normalized_power and ideal.summary["score"] == "P/Pmax"
    )
    for key in (
        "final_mean",
        "final_std",
        "mean_last10",
    ):  # the documented P/P_best score, P/Pmax here
        assert ideal.summary[key + "_best"] == ideal.summary[key]
    assert len(calls) == 1


def test_evaluate_summary_reports_the_lock_figures_over_its_episodes():
    """The median lock step and RMS power noise after lock of the episodes that lock
    (``ops_jax.lock``), beside the summary's other figures; a lock comes no earlier than P first
    reaches 0.9."""
    from ops_jax.lock import lock_figures

    result = agents.train("physics", ENV, starts=3, iters=2)
    ev = agents.evaluate(result, ENV, episodes=6, seed=2, steps=60)
    figures = lock_figures(ev.normalized_power)
    s = ev.summary
    assert s["fraction_locked"] == pytest.approx(figures.locked.mean()) and s["fraction_locked"] > 0
    assert s["lock_step_median"] == np.median(figures.lock_step[figures.locked])
    assert s["rms_after_lock_median"] == pytest.approx(
        np.median(figures.rms_after_lock[figures.locked])
    )
    assert 0 < s["rms_after_lock_median"] < s["lock_band"] == 0.02 and s["lock_reason"] is None
    assert s["lock_step_median"] >= s["steps_to_0p9_median"]
    short = agents.summarize(np.full((2, 3), 0.5, np.float32))  # 3 steps: too short to score a lock
    assert short["lock_step_median"] is None and "too short" in short["lock_reason"]
    assert short["final_mean"] == 0.5 and short["steps"] == 3  # the other figures as before
