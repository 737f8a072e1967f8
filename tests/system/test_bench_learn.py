"""Learning on the bench (``agents.bench --learn``, ``agents.bench.learning``): a DroQ learner with
tiny networks against a real simulated bench (a caproto IOC on a free localhost port, frames only),
its checkpoint run as a controller, a run SIGKILLed and resumed, and the command line's refusals.
Every wait is bounded."""

import json
import time

import jax
import numpy as np
import pytest

pytest.importorskip("caproto")
pytest.importorskip("ophyd")
pytest.importorskip("bluesky")

from test_bench import START_S, bench_run, documents, finish  # noqa: E402

from agents import api as base  # noqa: E402
from agents.bench import documents as bench_documents, learning as bench_learn
from agents.bench.controller import Controller
from agents.controllers import physics_informed
from agents.learners.offpolicy import replay
from agents.learners.offpolicy.checkpoint import raw_keys
from agents.io import kept_dir  # noqa: E402
from agents.bench import runner  # noqa: E402
from benchmarks.lab import Process, ca_env  # noqa: E402
from ops_jax import EnvSpec  # noqa: E402

TINY = [
    "--set",
    "hidden=[16,16]",
    "--set",
    "critic_hidden=[16,16]",
    "--set",
    "batch_size=16",
    "--set",
    "learning_starts=40",
    "--set",
    "buffer_size=2000",
    "--set",
    "utd_ratio=2.0",
]
BENCH = ["--prefix", "LN:", "--stages", "3", "--no-lengths", "--stale-s", "5", "--rate", "50"]


@pytest.fixture(scope="module")
def ioc(tmp_path_factory):
    """A free-running simulated bench (3 stages, 100 ticks per second)."""
    log = tmp_path_factory.mktemp("ioc") / "ioc.log"
    proc = Process(
        "ops_jax.ioc",
        [
            "--prefix",
            "LN:",
            "--stages",
            "3",
            "--mode",
            "hard",
            "--model",
            "phasor",
            "--rate",
            "100",
        ],
        ca_env(),
        log,
    )
    try:
        yield proc.wait_for("serving", START_S)
    finally:
        proc.kill()


def summary_of(tmp) -> dict:
    return json.loads((tmp / "out" / "summary.json").read_text())


def counts_of(tmp) -> dict | None:
    """The counts of the checkpoint in ``tmp/out`` (None while there is none)."""
    try:
        return json.loads((kept_dir(tmp / "out" / "checkpoint") / "learner.json").read_text())[
            "counts"
        ]
    except (FileNotFoundError, TypeError):  # none yet, or between replace_dir's renames
        return None


def test_learning_run_checkpoints_a_policy_the_runner_runs(ioc, tmp_path):
    """300 env steps of DroQ on the bench: every step an event, gradient steps at most the ratio's,
    the checkpoint's counts the summary's; then ``--controller DIR/checkpoint`` runs what it
    learned."""
    rc, log = finish(
        bench_run(
            ioc,
            tmp_path,
            *BENCH,
            "--learn",
            "droq",
            "--steps",
            "300",
            "--checkpoint-every",
            "100",
            "--catch-up-s",
            "120",
            *TINY,
        )
    )
    assert rc == 0, log
    s = summary_of(tmp_path)
    assert s["controller"] == "learning droq" and s["stopped_by"] == "steps", s
    assert s["steps"] == s["env_steps_total"] == 300, s
    assert s["transitions_total"] == 299 and s["learning_env_steps_total"] == 300 - 40, s
    assert s["learn_steps_total"] == 2.0 * s["learning_env_steps_total"], (
        s
    )  # the loop's shortfall made up at the end
    assert s["update_ratio"] == pytest.approx(
        (s["learn_steps_total"] - s["catch_up_steps"]) / s["learning_env_steps_total"]
    ), s
    assert s["update_ratio_with_catch_up"] == 2.0, s
    assert s["update_ratio_target"] == 2.0 and s["learner_error"] is None, s
    counts = counts_of(tmp_path)
    assert (counts["env_steps"], counts["learn_steps"]) == (300, s["learn_steps_total"]), counts
    assert counts["curve"]["step"] == [100, 200, 300], counts
    docs = documents(tmp_path)
    events = [d["doc"]["data"] for d in docs if d["name"] == "event"]
    assert (
        len(events) == 300
        and docs[-1]["name"] == "stop"
        and docs[-1]["doc"]["exit_status"] == "success"
    )
    actions = np.array([e["control_action"] for e in events])
    assert (
        np.all(np.abs(actions) <= 1) and np.ptp(actions[:40]) > 0.5
    )  # the warm-up's uniform actions
    start = next(d["doc"] for d in docs if d["name"] == "start")
    assert start["learning"]["learner"] == "droq" and start["learning"]["hyper"]["hidden"] == [
        16,
        16,
    ]
    result = base.load(tmp_path / "out" / "checkpoint")
    assert result.algo == "droq" and result.env_spec.observe_lengths is False
    assert (
        float(np.abs(result.params["obs_norm"]["std"] - 1).max()) > 0
    )  # fitted to the warm-up's frames
    assert (tmp_path / "out" / "power.png").stat().st_size > 0
    rc, log = finish(
        Process(
            "agents.bench",
            [
                "--out",
                tmp_path / "run",
                *BENCH,
                "--controller",
                tmp_path / "out" / "checkpoint",
                "--steps",
                "20",
            ],
            ioc.env,
            tmp_path / "controller.log",
        )
    )
    assert rc == 0, log
    ran = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert ran["steps"] == 20 and ran["stopped_by"] == "steps", ran


def test_sigkill_then_resume_ends_with_every_step(ioc, tmp_path):
    """SIGKILL mid-run after a checkpoint: ``--resume`` takes the run on from the checkpoint to all
    its steps, the counts add up, and documents.jsonl keeps every line written before the kill."""
    steps, every = 400, 100
    args = [
        *BENCH,
        "--learn",
        "droq",
        "--steps",
        str(steps),
        "--checkpoint-every",
        str(every),
        *TINY,
    ]
    proc = bench_run(ioc, tmp_path, *args)
    deadline = time.monotonic() + START_S
    while (counts_of(tmp_path) or {"env_steps": 0})["env_steps"] < 200:
        assert proc.proc.poll() is None and time.monotonic() < deadline, proc.text()
        time.sleep(0.05)
    proc.kill()
    written = (tmp_path / "out" / "documents.jsonl").read_text()
    before = written[: written.rfind("\n") + 1]  # every line complete at the kill
    kept = counts_of(tmp_path)
    assert kept["env_steps"] in (200, 300) and not (tmp_path / "out" / "summary.json").exists(), (
        kept
    )
    rc, log = finish(
        bench_run(ioc, tmp_path, *BENCH, "--learn", "droq", "--steps", str(steps), "--resume")
    )
    assert rc == 0, log
    s = summary_of(tmp_path)
    assert s["env_steps_total"] == steps and s["env_steps_resumed_from"] == kept["env_steps"], s
    assert s["steps"] == steps - kept["env_steps"] and s["sessions"] == 2, s
    assert s["learn_steps_resumed_from"] == kept["learn_steps"] <= s["learn_steps_total"], s
    assert s["transitions_total"] == kept["transitions"] + s["steps"] - 1, s
    assert counts_of(tmp_path)["env_steps"] == steps
    after = (tmp_path / "out" / "documents.jsonl").read_text()
    assert after.startswith(before) and before.count('"name": "event"') >= kept["env_steps"] - 50
    docs = [json.loads(line) for line in after[len(before) :].splitlines()]
    assert docs[0]["name"] == "start" and docs[-1]["name"] == "stop"
    assert sum(d["name"] == "event" for d in docs) == s["steps"]
    assert docs[0]["doc"]["learning"]["env_steps_resumed_from"] == kept["env_steps"]


def test_the_lab_benchmark_kills_a_learning_run_past_its_first_checkpoint_and_resumes_it(tmp_path):
    """``benchmarks.lab --learn ... --kill-learner-after 0``: the learning run SIGKILLed once its
    first checkpoint is written, resumed to all its steps, and its checkpoint then run as a
    controller on the same bench."""
    from benchmarks import lab

    learned, ran = lab.run_learning(
        tmp_path,
        lab.LearnSettings(
            "droq", 300, sets=tuple(TINY[1::2]), kill_after=0.0, checkpoint_every=100
        ),
        lab.RunSettings(seconds=2, rate=50, stale_s=5, frames_only=True),
    )
    resumed_from = learned["env_steps_resumed_from"]
    assert resumed_from in (100, 200) and learned["sessions"] == 2, learned
    assert learned["env_steps_total"] == 300 and learned["steps"] == 300 - resumed_from, learned
    assert learned["killed_after_s"] > 0 and learned["wall_s"] > 0, learned
    assert "Traceback" not in (tmp_path / "learn-killed.log").read_text()
    assert (
        ran["controller"].endswith("checkpoint")
        and ran["stopped_by"] == "time"
        and ran["steps"] > 0
    ), ran


def _saved_policy(path, stages: int, lengths: bool):
    """A DroQ policy of the tiny networks saved by ``agents.save`` (untrained)."""
    env_spec = EnvSpec(stages=stages, observe_lengths=lengths)
    config = base.ALGOS["droq"].config.make(hidden=(16, 16))
    params = base.algo_module("droq").params_template(env_spec, config)
    base.save(
        path,
        base.TrainResult(
            "droq", env_spec, config, params, {"step": [0], "normalized_power": [0.0]}, {}, 0
        ),
    )
    return path


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--learn", "ppo"], "--learn must be an off-policy learner (td3, droq), got 'ppo'"),
        (["--learn", "droq", "--controller", "spgd"], "give one of --controller"),
        (["--learn", "droq", "--steps", "0"], "--steps must be >= 1 with --learn"),
        (
            ["--learn", "droq", "--steps", "10", "--checkpoint-every", "0"],
            "--checkpoint-every must be >= 1",
        ),
        (
            ["--learn", "droq", "--steps", "10", "--catch-up-s", "-1"],
            "--catch-up-s must be >= 0 s, got -1.0",
        ),
        (
            ["--learn", "droq", "--steps", "10", "--resume"],
            "--resume needs a checkpoint of a learning run in --out",
        ),
        (
            ["--learn", "droq", "--steps", "10", "--from", "NOPE"],
            "--from must be a folder written by agents.save",
        ),
        (
            ["--learn", "droq", "--steps", "10", "--from", "LENGTHS"],
            "lacks lines[0].length, lines[1].length",
        ),
        (["--learn", "droq", "--steps", "10", "--from", "TWO"], "drives 2 lines, the bench has 3"),
        (
            ["--learn", "td3", "--steps", "10", "--from", "FRAMES"],
            "--learn td3: --from holds a droq policy",
        ),
        (["--learn", "droq", "--steps", "10", "--set", "utd_ratio=-1"], "utd_ratio must be"),
    ],
)
def test_bad_learning_arguments_fail_in_one_line(tmp_path, capsys, extra, needle):
    """Refused before any PV is touched (no bench runs here): exit status 2, one line naming the
    parameter."""
    policies = {"LENGTHS": (3, True), "TWO": (2, False), "FRAMES": (3, False)}
    extra = [str(_saved_policy(tmp_path / x, *policies[x])) if x in policies else x for x in extra]
    assert (
        runner.main(
            [
                "--prefix",
                "NONE:",
                "--stages",
                "3",
                "--no-lengths",
                "--out",
                str(tmp_path / "out"),
                *extra,
            ]
        )
        == 2
    )
    err = [
        line
        for line in capsys.readouterr().err.strip().splitlines()
        if not line.startswith("agents.bench.runner: starting")
    ]
    assert len(err) == 1 and needle in err[0], err


def test_a_checkpoint_in_out_is_continued_or_kept(tmp_path, capsys):
    """A learning run's checkpoint in --out: a new run refuses to write over it; --resume refuses
    new settings."""
    (tmp_path / "out" / "checkpoint").mkdir(parents=True)
    (tmp_path / "out" / "checkpoint" / "learner.json").write_text("{}")
    base_args = [
        "--prefix",
        "NONE:",
        "--stages",
        "3",
        "--out",
        str(tmp_path / "out"),
        "--learn",
        "droq",
        "--steps",
        "9",
    ]
    assert runner.main(base_args) == 2
    assert "continue it with --resume" in capsys.readouterr().err
    assert runner.main([*base_args, "--resume", "--set", "utd_ratio=1"]) == 2
    assert "drop --from, --set and --env" in capsys.readouterr().err
    # --steps at or under the checkpoint's count: refused from its learner.json, before anything is
    # loaded
    (tmp_path / "out" / "checkpoint" / "learner.json").write_text(
        json.dumps({"counts": {"env_steps": 9}})
    )
    assert runner.main([*base_args, "--resume"]) == 2
    assert "--steps must be > the 9 env steps of the checkpoint, got 9" in capsys.readouterr().err


def test_a_run_that_ends_within_the_warm_up_is_told_so(tmp_path, capsys):
    """--steps that end before ``learning_starts`` transitions are stored: a warning naming both;
    two steps past them: none (the first step stores no transition)."""
    _learning(tmp_path / "short", 32, resume=False)
    assert (
        "--steps 32 ends within the learner's warm-up (learning_starts=32"
        in capsys.readouterr().err
    )
    _learning(tmp_path / "long", 34, resume=False)
    assert "warm-up" not in capsys.readouterr().err


def test_replace_dir_leaves_one_whole_folder(tmp_path):
    """A kill between replace_dir's two renames leaves PATH.old, which kept_dir finds; the next
    write cleans up."""
    from agents.io import replace_dir, temp_dir

    path = tmp_path / "checkpoint"
    for k in range(2):
        tmp = temp_dir(tmp_path, "checkpoint")
        (tmp / "n").write_text(str(k))
        replace_dir(tmp, path)
        assert (kept_dir(path) / "n").read_text() == str(k)
    path.rename(tmp_path / "checkpoint.old")  # as a kill after the first rename leaves it
    assert (kept_dir(path) / "n").read_text() == "1"
    tmp = temp_dir(tmp_path, "checkpoint")
    (tmp / "n").write_text("2")
    replace_dir(tmp, path)
    assert (kept_dir(path) / "n").read_text() == "2" and not (tmp_path / "checkpoint.old").exists()


def test_resume_ends_the_last_line_of_the_documents(tmp_path):
    docs = tmp_path / "documents.jsonl"
    docs.write_text('{"name": "start"}\n{"name": "event"}\n{"name": "ev')
    bench_documents.mend(docs)
    assert docs.read_text() == '{"name": "start"}\n{"name": "event"}\n'
    bench_documents.mend(docs)
    assert docs.read_text() == '{"name": "start"}\n{"name": "event"}\n'
    docs.write_text('{"name": "start"}\n{"name": "event"}')  # whole, its newline not written yet
    bench_documents.mend(docs)
    assert docs.read_text() == '{"name": "start"}\n{"name": "event"}\n'


def _learning(out, steps: int, resume: bool, **extra):
    """A tiny DroQ ``Learning`` on a 3-stage frames-only bench mapping, without a bench; ``extra``:
    more hyperparameters."""
    from types import SimpleNamespace

    from agents.bench.mapping import check_mapping, sim_mapping

    args = SimpleNamespace(
        learn="droq",
        controller=None,
        trim=None,
        steps=steps,
        checkpoint_every=50,
        from_=None,
        catch_up_s=0.0,
        out=str(out),
        resume=resume,
        set=None,
        env=None,
        seed=3,
    )
    hyper = (
        {}
        if resume
        else dict(
            hidden=[16, 16],
            critic_hidden=[16, 16],
            batch_size=16,
            learning_starts=32,
            buffer_size=1000,
            utd_ratio=2.0,
            **extra,
        )
    )
    mapping = check_mapping(sim_mapping("T:", 3, lengths=False))
    return bench_learn.setup(args, mapping, bench_learn.check_args(args), {}, hyper)[0]


def test_from_scratch_the_learner_takes_its_budget_preset_or_the_one_named():
    """A run from scratch learns with DroQ's ``budget`` preset (the learner alone), or with
    ``--set config=bench`` with the bench preset's correction to the fit's move, other ``--set``
    values kept."""
    from types import SimpleNamespace

    from agents.bench.mapping import check_mapping, sim_mapping

    mapping, args = (
        check_mapping(sim_mapping("T:", 3, lengths=False)),
        SimpleNamespace(from_=None, seed=3),
    )
    learner = bench_learn.off_policy_learner("droq")
    env_config, config, _, start = bench_learn.settings(
        args, learner, mapping, None, {}, {"hidden": [16, 16]}
    )
    assert config.config == "budget" and config.observer == "none", config
    assert start is None and env_config["observe_lengths"] is False, env_config
    _, c = bench_learn.settings(
        args, learner, mapping, None, {}, {"config": "bench", "hidden": [16, 16]}
    )[:2]
    assert (c.config, c.observer, c.residual_scale, c.fit_starts, c.fit_iters) == (
        "bench",
        "fit-residual",
        0.25,
        4,
        6,
    ), c
    assert list(c.hidden) == [16, 16] and c.utd_ratio == 10.0, c


def test_learner_compiles_once_and_its_checkpoint_restores_its_state(tmp_path, compiles):
    """200 steps of acting, storing, gradient steps and checkpoints compile nothing after setup;
    --resume restores every saved leaf of the training state bit for bit, and the counts."""
    learning = _learning(tmp_path, 200, resume=False)
    obs = (
        np.random.default_rng(0)
        .uniform(-1, 1, (201, learning.parts.env.observation_size))
        .astype(np.float32)
    )
    with compiles() as n:
        learning.begin(200, lambda exc: None)
        learning.actor.start(obs[0])
        actions = [
            learning.actor.act(o, np.zeros(0)) for o in obs[1:] if time.sleep(0.002) is None
        ]  # a 500 Hz loop
        learning.thread.finish()
    assert n[0] == 0 and learning.thread.error is None and isinstance(learning.actor, Controller)
    assert np.all(np.abs(actions) <= 1) and learning.state.counts.learn_steps > 0
    assert learning.state.counts.learn_steps == int(learning.state.ts.updates)
    leaves = lambda ts: {
        jax.tree_util.keystr(k): np.asarray(v)
        for k, v in jax.tree_util.tree_leaves_with_path(  # noqa: E731
            jax.device_get(raw_keys(ts.state.saved()))
        )
    }
    saved = leaves(learning)
    again = _learning(tmp_path, 300, resume=True)
    assert again.state.counts == learning.state.counts and again.state.warm_obs is None
    restored = leaves(again)
    assert saved.keys() == restored.keys() and any("buffer" in k for k in saved), sorted(saved)
    assert all(np.array_equal(saved[k], restored[k]) for k in saved), [
        k for k in saved if not np.array_equal(saved[k], restored[k])
    ]


@pytest.mark.parametrize("kind", ["fit", "fit-residual"])
def test_learner_with_the_fit_stores_frames_and_offsets_and_its_policy_reads_frames(
    tmp_path, compiles, kind
):
    """With ``observer=fit`` the loop's frames get the fit's offsets before the learner sees them
    (stored transitions hold both), nothing compiles after setup, and the checkpoint's policy acts
    on raw frames. The stored actions are the moves sent; with ``fit-residual`` they are the
    learner's corrections, not the moves sent (the fit's move added). A move the bench's limits cut
    is told to the fit, and stored where the action is the move."""
    learning = _learning(tmp_path, 120, resume=False, observer=kind)
    d = learning.parts.env.observation_size
    assert (
        learning.parts.train_env.observation_size == d + 2
    )  # 3 stages, detector "total": 2 fitted lines
    obs = np.random.default_rng(1).uniform(-1, 1, (121, d)).astype(np.float32)
    scale = physics_informed.policy_params(learning.parts.env_config)["action_scale"]
    with compiles() as n:
        learning.begin(120, lambda exc: None)
        learning.actor.start(obs[0])
        actions = []
        for i, o in enumerate(obs[1:]):
            actions.append(learning.actor.act(o, np.zeros(0)))
            if (
                i == 60
            ):  # the bench's limits cut this step's move: the fit is told it, and the stored step
                actions[-1] = done = np.array([0.5, -0.25, 0.0])
                assert learning.actor.tell(done)
                np.testing.assert_allclose(
                    np.asarray(learning.actor.seen["dz_prev"])[0], done[:2] * scale, rtol=1e-6
                )
                assert np.array_equal(learning.actor.prev[1], done) == (kind == "fit")
        learning.thread.finish()
    assert n[0] == 0 and learning.thread.error is None and np.all(np.abs(actions) <= 1)
    _, batch = replay.replay_buffer(learning.parts.train_env, learning.parts.config).sample(
        learning.state.ts.buffer
    )
    fitted = np.asarray(batch["obs"])[:, d:]
    assert fitted.shape[1] == 2 and np.any(fitted != 0) and np.all(np.abs(fitted) <= 0.25)
    sent = np.asarray(actions)
    was_sent = np.mean(
        [np.any(np.all(np.abs(sent - a) < 1e-6, axis=1)) for a in np.asarray(batch["action"])]
    )
    assert was_sent == 1.0 if kind == "fit" else was_sent < 0.05, was_sent
    result = base.load(tmp_path / "checkpoint")
    assert result.config.observer == kind and result.params["obs_norm"]["mean"].shape == (d + 2,)
    ev = base.evaluate(result, result.env_spec, episodes=2, seed=0, steps=5)
    assert np.all(np.isfinite(ev.normalized_power))
