"""What a learner on a bench keeps from one run to the next (``State``: training state, ``Counts``,
warm-up observations) and its checkpoint, ``DIR/checkpoint`` (``Checkpoints``; the layout:
``agents.bench.learning``)."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from agents import api as base
from agents.bench.learning.programs import Built
from agents.io import replace_dir, temp_dir, write_json_atomic
from agents.learners.offpolicy import driver as offpolicy
from agents.learners.offpolicy.checkpoint import is_key, raw_keys
from ops_jax import EnvSpec

# training-state fields of a simulated run: not saved, fresh on resume
LIVE = ("env_state", "obs", "env_params")


@dataclasses.dataclass
class Counts:
    """A run's counts, total over its invocations: env steps (actions sent), gradient steps, env
    steps after the warm-up, transitions stored, invocations (``sessions``); ``p_init`` the first
    frame's power (units of P_max's, -1 before it), ``seconds`` of learning; ``curve``: env step and
    mean P / P_max read between checkpoints."""

    env_steps: int = 0
    learn_steps: int = 0
    learning_env_steps: int = 0
    transitions: int = 0
    sessions: int = 0
    p_init: float = -1.0
    seconds: float = 0.0
    curve: dict = dataclasses.field(default_factory=lambda: {"step": [], "normalized_power": []})


@dataclasses.dataclass
class State:
    """The learner's state: the training state ``ts``, the ``counts``, the warm-up's observations
    (None once the statistics are fitted, or from a policy, whose statistics are kept), the policy
    the run started from (``from_policy``, or None)."""

    ts: object
    counts: Counts = dataclasses.field(default_factory=Counts)
    warm_obs: list | None = dataclasses.field(default_factory=list)
    from_policy: str | None = None

    def saved(self) -> dict:
        """The training state's fields a checkpoint keeps."""
        return {f: getattr(self.ts, f) for f in self.ts._fields if f not in LIVE}


def fresh(parts: Built, env_params) -> State:
    """A run from scratch: the training state ``parts.fns.init`` draws from the seed."""
    return State(jax.jit(parts.fns.init)(jax.random.key(parts.seed), env_params))


def start_from(state: State, result: base.TrainResult, path: str) -> None:
    """Start from the policy saved at ``path``: its actor (targets too) and observation statistics,
    kept."""
    actor, ts = result.params["actor"], state.ts
    if [x.shape for x in jax.tree.leaves(actor)] != [
        x.shape for x in jax.tree.leaves(ts.actor.params)
    ]:
        raise ValueError("--from: the policy's networks do not fit the settings (--set hidden)")
    targets = {"actor_target": actor} if "actor_target" in ts._fields else {}
    state.ts = ts._replace(
        actor=ts.actor.replace(params=actor), obs_norm=result.params["obs_norm"], **targets
    )
    state.from_policy, state.warm_obs = str(path), None


def restore(state: State, checkpoint: Path, learning_starts: int) -> None:
    """Continue the run of ``checkpoint`` (its ``learner.msgpack`` and ``learner.json``); the
    warm-up's observations kept while fewer than ``learning_starts`` transitions are stored."""
    from flax import serialization

    try:
        blob = serialization.msgpack_restore((checkpoint / "learner.msgpack").read_bytes())
        meta = json.loads((checkpoint / "learner.json").read_text())
        template = state.saved()
        raw = serialization.from_state_dict(raw_keys(template), blob["state"])
        fields = jax.tree.map(
            lambda f, r: jax.random.wrap_key_data(r) if is_key(f) else jnp.asarray(r, f.dtype),
            template,
            raw,
        )
        counts = Counts(**meta["counts"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(
            f"--resume: the checkpoint at {checkpoint} cannot be read: {exc!r}"
        ) from exc
    warming = counts.transitions < learning_starts and not meta["from"]
    state.ts, state.counts, state.from_policy = state.ts._replace(**fields), counts, meta["from"]
    state.warm_obs = list(np.asarray(blob["warm_obs"])) if warming else None


class Checkpoints:
    """``out/checkpoint``, written every ``every`` env steps and at the end in place of the last;
    between two, the mean P / P_max read (a point of the curve) and the seconds of learning."""

    def __init__(self, parts: Built, out: Path, every: int):
        self.parts, self.out, self.every = parts, Path(out), every
        self.power_sum, self.readings = 0.0, 0  # P / P_max read since the last checkpoint
        self.clock = time.perf_counter()  # when the seconds since the last were counted

    def read(self, power: float) -> None:
        """One env step's P / P_max, for the curve's next point."""
        self.power_sum, self.readings = self.power_sum + power, self.readings + 1

    def restart_clock(self) -> None:
        """An invocation starts: its seconds of learning count from now."""
        self.clock = time.perf_counter()

    def _count(self, c: Counts) -> None:
        """The seconds since the last and the curve's point, added to the counts."""
        now = time.perf_counter()
        c.seconds, self.clock = c.seconds + now - self.clock, now
        if self.readings:
            c.curve["step"].append(c.env_steps)
            c.curve["normalized_power"].append(self.power_sum / self.readings)
            self.power_sum, self.readings = 0.0, 0

    def write(self, state: State) -> Path:
        """Write ``out/checkpoint`` (an ``agents.save`` folder of the policy, ``learner.msgpack``,
        ``learner.json``) in place of the last one."""
        from flax import serialization

        p, c = self.parts, state.counts
        self._count(c)
        host = jax.device_get(raw_keys(state.saved()))
        result = base.TrainResult(
            p.learner.name,
            EnvSpec.from_options(p.env_config),
            p.config,
            offpolicy.policy_params(state.ts),
            dict(c.curve),
            {"total": c.seconds},
            p.seed,
        )
        d = p.train_env.observation_size
        warm = np.stack(state.warm_obs) if state.warm_obs else np.zeros((0, d), np.float32)
        blob = serialization.msgpack_serialize(
            {"state": serialization.to_state_dict(host), "warm_obs": warm}
        )
        staging = temp_dir(self.out, "checkpoint")
        base.save(staging, result)
        (staging / "learner.msgpack").write_bytes(blob)
        meta = {"counts": dataclasses.asdict(c), "from": state.from_policy}
        write_json_atomic(staging / "learner.json", meta)
        replace_dir(staging, self.out / "checkpoint")
        return self.out / "checkpoint"
