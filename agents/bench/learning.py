"""Learning on a bench: an off-policy learner of ``agents.learners.offpolicy.driver`` (DroQ, TD3)
acting in the control loop of ``agents.bench`` and learning from the bench's own transitions.

    python -m agents.bench --prefix OPS: --learn droq [--from DIR] --steps 20000 --out DIR \\
        [--resume]

The actor (the loop's thread, ``Learning.act``) hands each step's observation (``Loop.observe``: the
simulator's layout) with the previous observation and action to the learner, and sends the
exploration action of the newest actor network it was handed. The learner (a thread of its own)
stores the transitions in the replay buffer, their reward the configuration's (``OPSEnv.reward``) at
the detector's reading, and takes gradient steps one at a time as the wall clock allows, at most the
preset's ratio (``utd_ratio``) per env step after the warm-up; every ``PUBLISH_STEPS`` env steps it
hands the actor a copy of the actor network (a swap under a lock).

A free-running bench has no reset and no terminal state: the task is continuing, every transition's
discount 1 (every target bootstrapped). The warm-up is ``learning_starts`` transitions of uniform
random actions, the observation statistics then frozen from them; from ``--from`` (a policy of
``agents.save``) it is the policy's own exploration and its statistics are kept, as
``agents.learners.offpolicy.driver`` continues a run.

``DIR/checkpoint``, written every ``--checkpoint-every`` env steps and at the end
(``agents.io.replace_dir``): an ``agents.save`` folder of the current policy
(``--controller DIR/checkpoint`` runs it), ``learner.msgpack`` (networks, targets, optimiser states,
replay buffer, gradient step count, PRNG key) and ``learner.json`` (``Counts``). ``--resume``
continues from it; the actor's draws are keyed by the run's seed and env step.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import logging
import shutil
import sys
import threading
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents import api as base, registry
from agents.learners.offpolicy import observer, driver as offpolicy, replay
from agents.learners.offpolicy.checkpoint import is_key, raw_keys
from agents.bench.loop import check_lengths
from agents.envs import built, train_env_config
from agents.io import kept_dir, replace_dir, temp_dir, write_json_atomic
from ops_jax import EnvSpec
from ops_jax.cli.progress import progress

PUBLISH_STEPS = 10  # env steps between two hand-overs of the actor network
CHECKPOINT_EVERY = 1000  # env steps between two checkpoints (default)
CATCH_UP_S = (
    0.0  # most seconds of gradient steps taken after the loop to make up the ratio (default: none)
)
LIVE = (
    "env_state",
    "obs",
    "env_params",
)  # training-state fields of a simulated run: not saved, fresh on resume
log = logging.getLogger("agents.bench")


@dataclasses.dataclass
class Counts:
    """A run's counts, total over its sessions: env steps (actions sent), gradient steps, env steps
    after the warm-up, transitions stored, sessions; ``p_init`` the first frame's power (units of
    P_max's, -1 before it), ``seconds`` of learning; ``curve``: env step and mean P / P_max read
    between checkpoints."""

    env_steps: int = 0
    learn_steps: int = 0
    learning_env_steps: int = 0
    transitions: int = 0
    sessions: int = 0
    p_init: float = -1.0
    seconds: float = 0.0
    curve: dict = dataclasses.field(default_factory=lambda: {"step": [], "normalized_power": []})


def off_policy_learner(name: str) -> offpolicy.Learner:
    """The ``Learner`` of ``--learn name`` (ValueError naming the off-policy learners otherwise)."""
    names = [a.name for a in registry.REGISTRY.values() if a.off_policy]
    if name not in names:
        raise ValueError(
            f"--learn must be an off-policy learner ({', '.join(names)}), got {name!r}"
        )
    return registry.get(name).load().LEARNER


def check_args(args) -> Path | None:
    """The learning arguments checked (ValueError, one line naming the parameter); the checkpoint to
    resume."""
    off_policy_learner(args.learn)
    if args.controller or args.trim is not None:
        raise ValueError("--learn replaces --controller and --trim: give --learn alone")
    if args.steps < 1:
        raise ValueError(
            "--steps must be >= 1 with --learn (env steps in all, resumes included), got "
            f"{args.steps}"
        )
    if not args.catch_up_s >= 0:
        raise ValueError(f"--catch-up-s must be >= 0 s, got {args.catch_up_s}")
    if args.checkpoint_every < 1:
        raise ValueError(f"--checkpoint-every must be >= 1 env step, got {args.checkpoint_every}")
    if args.from_ is not None and not Path(args.from_).is_dir():
        raise ValueError(f"--from must be a folder written by agents.save, got {args.from_!r}")
    checkpoint = kept_dir(Path(args.out) / "checkpoint")
    if args.resume:
        if args.from_ or args.set or args.env:
            raise ValueError(
                "--resume continues the run in --out with its own settings: drop --from, --set "
                "and --env"
            )
        if checkpoint is None or not (checkpoint / "learner.json").exists():
            raise ValueError(
                f"--resume needs a checkpoint of a learning run in --out, none in {args.out}"
            )
        try:
            done = json.loads((checkpoint / "learner.json").read_text())["counts"]["env_steps"]
        except (OSError, ValueError, KeyError, TypeError):
            done = None  # unreadable: restoring it says why
        if done is not None and done >= args.steps:
            raise ValueError(
                f"--steps must be > the {done} env steps of the checkpoint, got {args.steps}"
            )
    elif checkpoint is not None:
        raise ValueError(
            f"--out {args.out} holds a learning run's checkpoint: continue it with --resume, or "
            "give another --out"
        )
    return checkpoint if args.resume else None


def default_stages(args, checkpoint: Path | None) -> int:
    """The simulated bench's stages: the resumed run's, the ``--from`` policy's, else 5."""
    source = checkpoint or args.from_
    return base.load(source).env_spec.stages if source else 5


def _settings(
    args, learner, mapping: dict, checkpoint: Path | None, env_options: dict, hyper: dict
):
    """(env_config, stored hyperparameters, seed, start: the ``--from`` or resumed TrainResult or
    None)."""
    stages, lengths = len(mapping["lines"]), all("length" in line for line in mapping["lines"])
    start = base.load(checkpoint or args.from_) if (checkpoint or args.from_) else None
    if start is None:
        presets = (
            learner.config_type.PRESETS
        )  # one instance, few env steps: the budget preset where there is one
        h = learner.config_type.make(
            hyper.pop("config", "budget" if "budget" in presets else None), **hyper
        ).to_hyper()
        return {"stages": stages, "observe_lengths": lengths, **env_options}, h, args.seed, None
    what = "--from" if checkpoint is None else f"the checkpoint in {args.out}"
    if start.algo != learner.name:
        raise ValueError(f"--learn {learner.name}: {what} holds a {start.algo} policy")
    h = learner.config_type.from_hyper({**start.config.to_hyper(), **hyper}).to_hyper()
    env_config = {**start.env_spec.as_dict(), **env_options}
    return env_config, h, (start.seed if checkpoint else args.seed), start


def setup(args, mapping: dict, checkpoint: Path | None, env_options: dict, hyper: dict):
    """(Learning, env_config, action scale (wl per unit), window (wl)) of the arguments on the bench
    of ``mapping``."""
    learner = off_policy_learner(args.learn)
    env_config, h, seed, start = _settings(args, learner, mapping, checkpoint, env_options, hyper)
    env_config = base.check_env_config(env_config)
    env, env_params = built(train_env_config(env_config, h["train_reward"]))
    stages = len(mapping["lines"])
    if env.num_actions != stages:
        raise ValueError(
            f"--learn: the policy's env_config drives {env.num_actions} lines, the bench has "
            f"{stages}"
        )
    if env.config.include_noise:
        raise ValueError(
            "--env include_noise=True: the noise state is the simulator's, no bench measures it"
        )
    check_lengths(
        f"--from {args.from_}" if args.from_ else f"--learn {args.learn}", True, env, mapping
    )
    out = Path(args.out)
    for stale in out.glob("checkpoint.*.tmp"):  # a checkpoint's folder a kill left half-written
        shutil.rmtree(stale, ignore_errors=True)
    learning = Learning(learner, env_config, h, seed, out, args.checkpoint_every)
    if checkpoint is not None:
        learning.restore(checkpoint)
    elif start is not None:
        learning.start_from(start, args.from_)
    if learning.counts.transitions + args.steps - learning.counts.env_steps <= h["learning_starts"]:
        print(
            f"agents.bench.runner: warning: --steps {args.steps} ends within the learner's "
            f"warm-up (learning_starts={h['learning_starts']} transitions of random actions): it "
            "takes no gradient step",
            file=sys.stderr,
        )
    learning.compile()
    return learning, env_config, float(env_params.action_scale), float(env_params.window)


def mend_documents(path: Path) -> None:
    """End the last line of ``path`` (documents.jsonl) before a resumed run appends: a whole
    document a kill left without its newline gets it, a half-written one is cut."""
    if path.exists() and (size := path.stat().st_size):
        with open(path, "rb+") as f:
            f.seek(max(0, size - (1 << 20)))
            tail = f.read()
            if tail.endswith(b"\n"):
                return
            start = tail.rfind(b"\n") + 1
            try:
                json.loads(tail[start:])
                f.write(b"\n")
            except ValueError:
                f.truncate(size - len(tail) + start)


def _acting(ts):
    """What the exploration reads of a training state: the actor's parameters and the observation
    statistics."""
    return ts._replace(
        actor=ts.actor.replace(opt_state=None),
        **{f: None for f in ts._fields if f not in ("actor", "obs_norm")},
    )


class Learning:
    """A learner on a bench: the controller protocol of ``agents.bench.loop.Agent`` for the loop's
    thread (``start``, ``act``; no probes), the learning thread (``begin``, ``finish``), checkpoints
    and the summary."""

    probes = 0

    def __init__(
        self, learner, env_config: dict, h: dict, seed: int, out: Path, checkpoint_every: int
    ):
        self.learner, self.env_config, self.h, self.seed, self.out = (
            learner,
            env_config,
            h,
            seed,
            out,
        )
        self.checkpoint_every, self.from_policy = checkpoint_every, None
        self.env, env_params = built(train_env_config(env_config, h["train_reward"]))
        self.config = learner.config_type.from_hyper(h)
        self.ratio = replay.updates_per_iter(self.config) / (
            h["num_envs"] * h["unroll"]
        )  # target gradient steps per env step
        self.train_env = learner.training_env(
            self.env, env_config, self.config
        )  # with the observer's entries, if any
        self.observer = (
            self.train_env.observer if isinstance(self.train_env, observer.Observed) else None
        )
        self.fns = learner.build(self.train_env, self.config)
        self.ts = jax.jit(self.fns.init)(jax.random.key(seed), env_params)
        self.k_act = jax.random.fold_in(jax.random.key(seed), 1)
        self.k_observe = jax.random.fold_in(jax.random.key(seed), 2)
        self.counts, self.warm_obs = Counts(), []
        self.queue: collections.deque = collections.deque()
        self.lock, self.wake = threading.Lock(), threading.Event()
        self.thread, self.error, self.on_error, self.bar = None, None, None, None
        self.ending, self.prev, self.t, self.power_sum, self.seen = False, None, 0, [0.0, 0], None
        self.catch_up_s, self.in_loop_steps = 0.0, 0
        # (perf_counter time, this invocation's gradient steps, its env steps after the warm-up)
        self.ratio_rec: list = []

    # -- the run's state -------------------------------------------------------------------------
    @property
    def learning(self) -> bool:
        """Past the warm-up (``learning_starts`` transitions stored)."""
        return self.counts.transitions >= self.h["learning_starts"]

    def start_from(self, result: base.TrainResult, path: str) -> None:
        """Start from the policy saved at ``path``: its actor (targets too) and observation
        statistics, kept."""
        self.from_policy = str(path)
        actor = result.params["actor"]
        if [x.shape for x in jax.tree.leaves(actor)] != [
            x.shape for x in jax.tree.leaves(self.ts.actor.params)
        ]:
            raise ValueError("--from: the policy's networks do not fit the settings (--set hidden)")
        targets = {"actor_target": actor} if "actor_target" in self.ts._fields else {}
        self.ts = self.ts._replace(
            actor=self.ts.actor.replace(params=actor), obs_norm=result.params["obs_norm"], **targets
        )
        self.warm_obs = None

    def _saved(self) -> dict:
        return {f: getattr(self.ts, f) for f in self.ts._fields if f not in LIVE}

    def restore(self, checkpoint: Path) -> None:
        """Continue the run of ``checkpoint`` (its ``learner.msgpack`` and ``learner.json``)."""
        from flax import serialization

        try:
            state = serialization.msgpack_restore((checkpoint / "learner.msgpack").read_bytes())
            meta = json.loads((checkpoint / "learner.json").read_text())
            template = self._saved()
            raw = serialization.from_state_dict(raw_keys(template), state["state"])
            fields = jax.tree.map(
                lambda f, r: jax.random.wrap_key_data(r) if is_key(f) else jnp.asarray(r, f.dtype),
                template,
                raw,
            )
            self.counts = Counts(**meta["counts"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(
                f"--resume: the checkpoint at {checkpoint} cannot be read: {exc!r}"
            ) from exc
        self.ts = self.ts._replace(**fields)
        self.from_policy = meta["from"]
        self.warm_obs = (
            None if self.learning or meta["from"] else list(np.asarray(state["warm_obs"]))
        )

    # -- the jitted programs ---------------------------------------------------------------------
    def compile(self) -> None:
        """Compile exploration, insertion, gradient step and the statistics' fit before the run."""
        env, fns, ts, d_raw = self.env, self.fns, self.ts, self.env.observation_size
        buffer = replay.replay_buffer(self.train_env, self.config)

        def explore(snap, t, obs, random):
            return fns.explore(snap, jax.random.fold_in(self.k_act, t), obs[None], random)[0]

        def insert(ts, obs, action, next_obs, p_init):
            reward = env.reward(env.layout.power(next_obs[:d_raw]) * env.p_max, p_init).astype(
                jnp.float32
            )
            tr = dict(
                obs=obs, action=action, reward=reward, discount=jnp.float32(1.0), next_obs=next_obs
            )
            return ts._replace(buffer=buffer.insert(ts.buffer, jax.tree.map(lambda x: x[None], tr)))

        d, n = self.train_env.observation_size, env.num_actions
        obs, act = jax.ShapeDtypeStruct((d,), jnp.float32), jax.ShapeDtypeStruct((n,), jnp.float32)
        if self.observer is None:
            self._act = (
                jax.jit(explore).lower(_acting(ts), jnp.int32(0), obs, jnp.bool_(True)).compile()
            )
        else:
            ob, raw = self.observer, jax.ShapeDtypeStruct((1, d_raw), jnp.float32)

            def act_observed(carry, frame, t, snap, random):
                """(the observation with the fit's entries, the learner's action, the move sent, the
                carry)."""
                seen, carry = ob.observe(
                    None, carry, frame[None], jax.random.fold_in(self.k_observe, t)
                )
                action = explore(snap, t, seen[0], random)
                sent = ob.command(carry, action[None])
                return seen[0], action, sent[0], ob.moved(None, carry, sent)

            carry, frame = (
                jax.eval_shape(ob.init, None, raw),
                jax.ShapeDtypeStruct((d_raw,), jnp.float32),
            )
            self._init_seen = jax.jit(lambda obs: ob.init(None, obs)).lower(raw).compile()
            self._moved = (
                jax.jit(lambda carry, sent: ob.moved(None, carry, sent[None]))
                .lower(carry, act)
                .compile()
            )
            self._act = (
                jax.jit(act_observed)
                .lower(carry, frame, jnp.int32(0), _acting(ts), jnp.bool_(True))
                .compile()
            )
        scalar = jax.ShapeDtypeStruct((), jnp.float32)
        self._insert = jax.jit(insert, donate_argnums=0).lower(ts, obs, act, obs, scalar).compile()
        self._update = (
            jax.jit(lambda ts: fns.update(ts, None)[0], donate_argnums=0).lower(ts).compile()
        )
        warm = jax.ShapeDtypeStruct((self.h["learning_starts"], d), jnp.float32)
        self._fit_norm = jax.jit(fns.fit_norm).lower(ts, warm).compile()
        self._publish()

    # -- the actor (the loop's thread) -----------------------------------------------------------
    def start(self, obs) -> None:
        """An invocation's first frame: no transition before it (and the observer's fit without
        history)."""
        self.prev, self.t = None, self.counts.env_steps
        if self.observer is not None:
            self.seen = self._init_seen(np.asarray(obs, np.float32)[None])

    def act(self, obs, results) -> np.ndarray:
        """The move sent (N,) in [-1, 1] at ``obs``: the exploration action (with the fit-residual
        observer, added to the fit's own move); the step (with the learner's action) handed to the
        learner."""
        del results
        obs = np.asarray(obs, np.float32)
        with self.lock:
            snap, random = self.snapshot
        if self.observer is None:
            action = sent = np.asarray(self._act(snap, np.int32(self.t), obs, random))
        else:
            obs, action, sent, self.seen = self._act(self.seen, obs, np.int32(self.t), snap, random)
            obs, action = np.asarray(obs), np.asarray(action)
        self.queue.append((obs, self.prev))
        self.prev, self.t = (obs, action), self.t + 1
        self.wake.set()
        return np.asarray(sent, np.float64)

    def tell(self, action) -> bool:
        """The move (N,) really sent where the bench's limits cut this step's: the step stored with
        it where the learner's action is the move (no observer, or ``fit``; ``fit-residual`` keeps
        its correction), and the fit told it (``Policy.sent``)."""
        done = np.asarray(action, np.float32)
        if self.observer is None or self.h["observer"] == "fit":
            self.prev = (self.prev[0], done)
        if self.observer is not None:
            self.seen = self._moved(self.seen, done)
        return True

    # -- the learner (its own thread) ------------------------------------------------------------
    def begin(self, steps: int, on_error) -> None:
        """Start the learning thread for an invocation of ``steps`` env steps; ``on_error(exc)`` if
        it fails."""
        self.on_error, self.t0, self.session0 = (
            on_error,
            time.perf_counter(),
            dataclasses.replace(self.counts),
        )
        self.counts.sessions += 1
        self.bar = progress(total=steps, desc=f"learning {self.learner.name}", unit="step")
        self.thread = threading.Thread(target=self._run, name="learner", daemon=True)
        self.thread.start()

    def end(self, catch_up_s: float = 0.0) -> None:
        """The loop has stopped: the thread stores what the loop handed over; then, for at most
        ``catch_up_s`` seconds, takes the gradient steps the learner fell behind the ratio
        (``catch_up_steps``); writes the last checkpoint and ends (``finish`` waits for it)."""
        self.catch_up_s = catch_up_s
        self.ending = True
        self.wake.set()

    def finish(self) -> None:
        """``end`` (unless called already: without a catch-up), and wait for the thread."""
        if not self.ending:
            self.end()
        self.thread.join()
        self.bar.close()

    def _run(self) -> None:
        try:
            while not (self.ending and not self.queue):
                if self.queue:
                    self._take(*self.queue.popleft())
                elif self._may_update():
                    self.ts = self._update(self.ts)
                    jax.block_until_ready(self.ts.updates)
                    self.counts.learn_steps += 1
                else:
                    self.wake.wait(0.005)
                    self.wake.clear()
            self.in_loop_steps = self._session("learn_steps")
            deadline = time.perf_counter() + self.catch_up_s
            while self._may_update() and time.perf_counter() < deadline:
                self.ts = self._update(self.ts)
                jax.block_until_ready(self.ts.updates)
                self.counts.learn_steps += 1
            self.checkpoint()
        except Exception as exc:  # the loop stops (on_error), the last checkpoint stays
            self.error = exc
            log.error("the learner failed", exc_info=exc)
            self.on_error(exc)

    def _session(self, name: str) -> int:
        return getattr(self.counts, name) - getattr(self.session0, name)

    def update_ratio(self, learn_steps: int | None = None) -> float:
        """This invocation's gradient steps (``learn_steps``, default all so far) per env step after
        the warm-up."""
        steps = self._session("learning_env_steps")
        learn_steps = self._session("learn_steps") if learn_steps is None else learn_steps
        return learn_steps / steps if steps else 0.0

    def _may_update(self) -> bool:
        return self.learning and self._session("learn_steps") < self.ratio * self._session(
            "learning_env_steps"
        )

    def _take(self, obs, prev) -> None:
        """One env step: its transition stored, the warm-up ended, the actor handed its network, a
        checkpoint."""
        c = self.counts
        if c.p_init < 0:
            c.p_init = (
                float(self.env.layout.power(obs[: self.env.observation_size])) * self.env.p_max
            )
        if prev is not None:
            self.ts = self._insert(self.ts, prev[0], prev[1], obs, np.float32(c.p_init))
            if self.warm_obs is not None:
                self.warm_obs.append(prev[0])
            c.transitions += 1
            if self.warm_obs is not None and self.learning:
                self.ts, self.warm_obs = self._fit_norm(self.ts, np.stack(self.warm_obs)), None
                self._publish()
        c.learning_env_steps += int(self.learning)
        c.env_steps += 1
        self.power_sum[0] += float(self.env.layout.power(obs[: self.env.observation_size]))
        self.power_sum[1] += 1
        self.bar.update(1)
        if c.env_steps % PUBLISH_STEPS == 0:
            self._publish()
        if c.env_steps % self.checkpoint_every == 0:
            self.checkpoint()

    def _publish(self) -> None:
        """Hand the actor a copy of the actor network (and whether it still explores uniformly)."""
        snap = jax.device_put(jax.tree.map(np.array, _acting(self.ts)))
        with self.lock:
            self.snapshot = (snap, np.bool_(self.warm_obs is not None and not self.learning))
        if self.bar is not None:
            ratio = self.update_ratio()
            self.ratio_rec.append(
                (
                    time.perf_counter(),
                    self._session("learn_steps"),
                    self._session("learning_env_steps"),
                )
            )
            self.bar.set_postfix_str(
                f"env steps {self.counts.env_steps}, learn steps {self.counts.learn_steps}, "
                f"updates per env step {ratio:.2f} of {self.ratio:g}"
            )

    # -- checkpoints and the summary -------------------------------------------------------------
    def checkpoint(self) -> Path:
        """Write ``out/checkpoint`` (module docstring) in place of the last one."""
        from flax import serialization

        c, now = self.counts, time.perf_counter()
        c.seconds, self.t0 = c.seconds + now - self.t0, now
        if self.power_sum[1]:
            c.curve["step"].append(c.env_steps)
            c.curve["normalized_power"].append(self.power_sum[0] / self.power_sum[1])
            self.power_sum = [0.0, 0]
        host = jax.device_get(raw_keys(self._saved()))
        result = base.TrainResult(
            self.learner.name,
            EnvSpec.from_options(self.env_config),
            self.config,
            offpolicy.policy_params(self.ts),
            dict(c.curve),
            {"total": c.seconds},
            self.seed,
        )
        warm = (
            np.stack(self.warm_obs)
            if self.warm_obs
            else np.zeros((0, self.train_env.observation_size), np.float32)
        )
        blob = serialization.msgpack_serialize(
            {"state": serialization.to_state_dict(host), "warm_obs": warm}
        )
        staging = temp_dir(self.out, "checkpoint")
        base.save(staging, result)
        (staging / "learner.msgpack").write_bytes(blob)
        write_json_atomic(
            staging / "learner.json", {"counts": dataclasses.asdict(c), "from": self.from_policy}
        )
        replace_dir(staging, self.out / "checkpoint")
        return self.out / "checkpoint"

    def describe(self) -> dict:
        """The start document's ``learning`` entry."""
        return {
            "learner": self.learner.name,
            "hyper": self.h,
            "from": self.from_policy,
            "seed": self.seed,
            "env_steps_resumed_from": self.counts.env_steps,
            "update_ratio_target": self.ratio,
        }

    def ratio_series(self, t0: float | None, window: int = 10):
        """(seconds since ``t0`` (perf_counter), gradient steps per env step over the last
        ``window`` hand-overs, NaN in the warm-up) for the plot, or None."""
        if t0 is None or len(self.ratio_rec) <= window:
            return None
        t, learn, env = np.asarray(self.ratio_rec, float).T
        d_env = env[window:] - env[:-window]
        ratio = np.divide(
            learn[window:] - learn[:-window],
            d_env,
            out=np.full_like(d_env, np.nan),
            where=d_env > 0,
        )
        return t[window:] - t0, ratio

    def report(self) -> dict:
        """The summary's learning entries: totals over the run's sessions and this invocation's
        update ratio."""
        c = self.counts
        return {
            "learner": self.learner.name,
            "env_steps_total": c.env_steps,
            "learn_steps_total": c.learn_steps,
            "env_steps_resumed_from": self.session0.env_steps,
            "learn_steps_resumed_from": self.session0.learn_steps,
            "transitions_total": c.transitions,
            "learning_env_steps_total": c.learning_env_steps,
            "update_ratio": self.update_ratio(self.in_loop_steps),
            "update_ratio_target": self.ratio,
            "catch_up_steps": self._session("learn_steps") - self.in_loop_steps,
            "update_ratio_with_catch_up": self.update_ratio(),
            "update_ratio_total": c.learn_steps / c.learning_env_steps
            if c.learning_env_steps
            else 0.0,
            "sessions": c.sessions,
            "learner_error": None if self.error is None else repr(self.error),
        }
