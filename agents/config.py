"""The hyperparameters of every algorithm: one frozen dataclass per algorithm, named presets
overridable per field, validated in one place.

    PPOConfig.preset("fast", learning_rate=1e-3)   # a preset with one field changed
    TD3Config.make("paper")                        # make(config, **overrides): a preset or a config
    SPGDConfig.from_hyper(result.hyper)            # back from the stored dict (``to_hyper``)

A value out of range raises ValueError naming the field and its accepted range (``ops_jax.ranges.Range``,
the one range check of the package); an unknown field
raises TypeError listing the accepted ones. ``to_hyper()`` is the stored form (``TrainResult.hyper``,
checkpoints): the fields (tuples as lists) and, for the learners, ``config``, the preset's name.
The presets' tuning is described in each algorithm's module (``agents.learners.brax.ppo``, ``agents.learners.brax.sac``, ...).
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np

from ops_jax.env import REWARDS
from ops_jax.ranges import Range


def _flag(name: str, v):
    if not isinstance(v, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {v!r}")
    return bool(v)


def _widths(name: str, v):
    if (
        not isinstance(v, (list, tuple))
        or not v
        or not all(
            isinstance(h, (int, np.integer)) and not isinstance(h, bool) and h >= 1 for h in v
        )
    ):
        raise ValueError(f"{name} must be a non-empty sequence of layer widths >= 1, got {v!r}")
    return tuple(int(h) for h in v)


def _choice(*options):
    def check(name: str, v):
        if v not in options:
            raise ValueError(f"{name} must be one of {list(options)}, got {v!r}")
        return v

    return check


def _optional(check):
    """``check``, or None left as it is."""

    def f(name: str, v):
        return None if v is None else check(name, v)

    return f


def field(check, **default):
    """A dataclass field validated by ``check(name, value) -> normalised value``. With ``default=value`` (fields
    added after configurations were stored), the field is left out of the stored form at that value, so stored
    configurations keep their form (and the sweep's cells their keys)."""
    return dataclasses.field(metadata={"check": check}, **default)


DITHER = Range(1e-6, 0.25, unit="wl")  # a dither's amplitude (SPGD, the trim)
# the earlier frames the physics-informed fit compares with the latest, through the moves since (1: the frame before it)
HISTORY = Range(1, 16, integer=True)
COUNT, COUNT0 = Range(1, integer=True), Range(0, integer=True)  # integers >= 1, >= 0
POSITIVE, NONNEG, UNIT = (
    Range(0, lo_open=True),
    Range(0),
    Range(0, 1, lo_open=True),
)  # > 0, >= 0, (0, 1]
# the reward an off-policy learner trains on (``ops_jax.REWARDS``; None: the env_config's own)
TRAIN_REWARD = _optional(_choice(*REWARDS))
# what an off-policy learner adds to its observation, and whether its action corrects the fit's move (``agents.learners.offpolicy.observer``)
OBSERVER = _choice("none", "fit", "fit-residual")


@dataclasses.dataclass(frozen=True)
class AlgoConfig:
    """Base of the algorithms' configurations: presets, overrides, validation, stored form."""

    NAME: ClassVar[str] = ""
    PRESETS: ClassVar[dict] = {}
    DEFAULT_PRESET: ClassVar[str] = "fast"

    def __post_init__(self):
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, f.metadata["check"](f.name, getattr(self, f.name)))
        self.check()

    def check(self) -> None:
        """Constraints between fields (ValueError naming them)."""

    def updates_per_step(self) -> float:
        """Gradient steps per env step of training (0 for a controller that trains no network)."""
        return 0.0

    @classmethod
    def names(cls) -> list:
        """The fields that can be set (``config``, the preset's name, is not one of them)."""
        return [f.name for f in dataclasses.fields(cls) if f.name != "config"]

    @classmethod
    def _check_names(cls, overrides: dict) -> None:
        unknown = set(overrides) - set(cls.names())
        if unknown:
            raise TypeError(
                f"unknown {cls.NAME} hyperparameter(s) {sorted(unknown)}; accepted: config, "
                f"{sorted(cls.names())}"
            )

    @classmethod
    def preset(cls, name: str | None = None, **overrides):
        """The preset ``name`` (default ``DEFAULT_PRESET``) with ``overrides`` of its fields."""
        name = cls.DEFAULT_PRESET if name is None else name
        if name not in cls.PRESETS:
            raise ValueError(f"config must be one of {sorted(cls.PRESETS)}, got {name!r}")
        cls._check_names(overrides)
        named = {"config": name} if "config" in {f.name for f in dataclasses.fields(cls)} else {}
        return cls(**{**cls.PRESETS[name], **overrides, **named})

    @classmethod
    def make(cls, config=None, **overrides):
        """``config``: a preset name (None: the default preset) or a config of this type; plus overrides."""
        if isinstance(config, cls):
            cls._check_names(overrides)
            return dataclasses.replace(config, **overrides)
        return cls.preset(config, **overrides)

    @classmethod
    def from_hyper(cls, hyper: dict | None):
        """The config of a stored ``to_hyper()`` dict (or any ``{"config": name, field: value}``)."""
        hyper = dict(hyper or {})
        return cls.make(hyper.pop("config", None), **hyper)

    def to_hyper(self) -> dict:
        """The stored form: field -> value (tuples as lists), with ``config`` for the learners."""
        return {
            f.name: list(v) if isinstance(v, tuple) else v
            for f in dataclasses.fields(self)
            for v in [getattr(self, f.name)]
            if f.default is dataclasses.MISSING or v != f.default
        }


@dataclasses.dataclass(frozen=True)
class EscapeConfig(AlgoConfig):
    """The stall escape's fields (``agents.controllers.escape``), shared by SPGD and the trim: jump (wl), patience
    (steps), p_stall and margin (P/Pmax)."""

    jump: float = field(Range(0, 0.5, unit="wl"))
    patience: float = field(Range(1, 1e6))
    p_stall: float = field(Range(0, 1))
    margin: float = field(Range(0, 1))


@dataclasses.dataclass(frozen=True)
class SPGDConfig(EscapeConfig):
    """SPGD-PID (``agents.controllers.spgd``): dither (wl), gain schedule, PID and the stall escape."""

    NAME: ClassVar[str] = "SPGD"
    DEFAULT_PRESET: ClassVar[str] = "default"
    PRESETS: ClassVar[dict] = {
        "default": dict(
            delta=0.002,
            delta0=0.04,
            anneal=20.0,
            kp=16.0,
            kp_min=0.1,
            kp_pow=2.0,
            ki=0.0,
            kd=0.0,
            leak=0.9,
            jump=0.25,
            patience=10.0,
            p_stall=0.9,
            margin=0.005,
        )
    }
    # for probes read a frame later, as on a bench (ops_jax EnvConfig.probe="frame"): a dither above the
    # frame-to-frame change of P, a lower gain (docs/imperfections.md)
    PRESETS["bench"] = dict(PRESETS["default"], delta=0.01, kp=8.0, kp_min=0.05)

    delta: float = field(DITHER)
    delta0: float = field(DITHER)
    anneal: float = field(Range(0, 1e6))
    kp: float = field(Range(0, 1e6))
    kp_min: float = field(Range(0, 1e6))
    kp_pow: float = field(Range(0, 10))
    ki: float = field(Range(0, 1e6))
    kd: float = field(Range(0, 1e6))
    leak: float = field(Range(0, 1))


@dataclasses.dataclass(frozen=True)
class TrimConfig(EscapeConfig):
    """The extremum-seeking trim (``agents.controllers.trim``): integral gain, dither (wl), the gate on P/Pmax and the
    stall escape."""

    NAME: ClassVar[str] = "trim"
    DEFAULT_PRESET: ClassVar[str] = "default"
    PRESETS: ClassVar[dict] = {
        "default": dict(
            ki=0.003,
            amp=0.002,
            p_gate=0.0,
            release=1.0,
            jump=0.0,
            patience=10.0,
            p_stall=0.6,
            margin=0.005,
        )
    }
    # integrates only above half of P_max and lets the offset decay below: a trim that led a line off the top is
    # undone (docs/learners.md, "Does the trim ever lose?")
    PRESETS["guarded"] = dict(PRESETS["default"], p_gate=0.5, release=0.9)
    # the guarded trim with a dither above the frame-to-frame change of P, for probes read a frame later (a bench;
    # ops_jax ``EnvConfig.probe="frame"``, docs/learners.md)
    PRESETS["bench"] = dict(PRESETS["guarded"], amp=0.005)

    ki: float = field(Range(0, 1))
    amp: float = field(DITHER)
    p_gate: float = field(Range(0, 1))
    release: float = field(Range(0, 1))
    # the measured P/Pmax at and above which SPGD's proportional step up the probed slope replaces the move
    # (``agents.controllers.spgd.held``; None: never)
    hold: float | None = field(_optional(Range(0, 1)), default=None)


@dataclasses.dataclass(frozen=True)
class PhysicsConfig(AlgoConfig):
    """The physics-informed controller (``agents.controllers.physics_informed``): the fit and the control gain."""

    NAME: ClassVar[str] = "physics"
    DEFAULT_PRESET: ClassVar[str] = "default"
    PRESETS: ClassVar[dict] = {
        "default": dict(  # identifies the imperfections and reads the calibrated length readout
            starts=16,
            iters=8,
            damping=1e-3,
            w_hist=1.0,
            gain=1.0,
            drift_gain=0.0,
            use_lengths=True,
            lengths_only=False,
            identify=True,
            forget=0.98,
        ),
        "frames": dict(  # the detector's frames alone, the ideal model: no identification, no length readout
            starts=16,
            iters=8,
            damping=1e-3,
            w_hist=1.0,
            gain=1.0,
            drift_gain=0.0,
            use_lengths=False,
            lengths_only=False,
            identify=False,
            forget=0.98,
        ),
    }
    # the frames' fit to acquire, SPGD's dither step to hold near the top (2 measurements per step); it gains over
    # "frames" only where a probe is read in the frame's instant (ops_jax EnvConfig.probe; docs/imperfections.md)
    PRESETS["frames-hold"] = dict(PRESETS["frames"], hold=0.85)

    starts: int = field(Range(0, 4096, integer=True))
    iters: int = field(Range(1, 1000, integer=True))
    damping: float = field(Range(0, 1e6))
    w_hist: float = field(Range(0, 1e6))
    gain: float = field(Range(0, 10))
    drift_gain: float = field(Range(0, 1))
    use_lengths: bool = field(_flag)
    lengths_only: bool = field(_flag)
    identify: bool = field(_flag)
    forget: float = field(Range(0, 1, lo_open=True))
    history: int = field(HISTORY, default=1)
    # the measured P/Pmax at and above which SPGD's proportional step from one dither probe (its preset's gains)
    # moves the lines instead of the fit (None: the fit's move throughout, 1 measurement per step)
    hold: float | None = field(_optional(Range(0, 1)), default=None)

    def check(self):
        if self.starts == 0 and not self.use_lengths:
            raise ValueError(
                "starts must be >= 1 unless use_lengths=True (nothing to start the fit from)"
            )


_ACTIVATION = _choice("tanh", "relu", "swish", "elu")


@dataclasses.dataclass(frozen=True)
class PPOConfig(AlgoConfig):
    """PPO (``agents.learners.brax.ppo``, brax's trainer): presets "paper" (the paper's Table 5) and "fast"."""

    NAME: ClassVar[str] = "PPO"
    PRESETS: ClassVar[dict] = {
        "paper": dict(
            num_envs=8,
            unroll_length=64,
            batch_size=1,
            num_minibatches=8,
            num_updates_per_batch=10,
            learning_rate=3e-4,
            entropy_cost=1e-3,
            discounting=0.99,
            gae_lambda=0.95,
            clipping_epsilon=0.2,
            vf_loss_coefficient=0.5,
            max_grad_norm=0.5,
            reward_scaling=1.0,
            normalize_observations=False,
            hidden=(256, 256),
            activation="tanh",
            init_noise_std=1.0,
            bootstrap_on_timeout=True,
            total_steps=300_000,
            num_evals=10,
            num_eval_envs=64,
        ),
        "fast": dict(
            num_envs=256,
            unroll_length=16,
            batch_size=32,
            num_minibatches=32,
            num_updates_per_batch=8,
            learning_rate=3e-4,
            entropy_cost=0.0,
            discounting=0.99,
            gae_lambda=0.95,
            clipping_epsilon=0.2,
            vf_loss_coefficient=0.5,
            max_grad_norm=0.5,
            reward_scaling=1.0,
            normalize_observations=True,
            hidden=(128, 128),
            activation="tanh",
            init_noise_std=0.3,
            bootstrap_on_timeout=True,
            total_steps=8_000_000,
            num_evals=10,
            num_eval_envs=64,
        ),
    }

    config: str = field(_choice("paper", "fast"))
    num_envs: int = field(COUNT)
    unroll_length: int = field(COUNT)
    batch_size: int = field(COUNT)
    num_minibatches: int = field(COUNT)
    num_updates_per_batch: int = field(COUNT)
    learning_rate: float = field(POSITIVE)
    entropy_cost: float = field(NONNEG)
    discounting: float = field(UNIT)
    gae_lambda: float = field(UNIT)
    clipping_epsilon: float = field(NONNEG)
    vf_loss_coefficient: float = field(NONNEG)
    max_grad_norm: float = field(NONNEG)
    reward_scaling: float = field(NONNEG)
    normalize_observations: bool = field(_flag)
    hidden: tuple = field(_widths)
    activation: str = field(_ACTIVATION)
    init_noise_std: float = field(POSITIVE)
    bootstrap_on_timeout: bool = field(_flag)
    total_steps: int = field(COUNT0)
    num_evals: int = field(COUNT)
    num_eval_envs: int = field(COUNT)

    def updates_per_step(self) -> float:
        """Per training step brax collects ``batch_size * num_minibatches * unroll_length`` env steps and
        takes ``num_updates_per_batch * num_minibatches`` gradient steps."""
        return self.num_updates_per_batch / (self.batch_size * self.unroll_length)

    def check(self):
        if (self.batch_size * self.num_minibatches) % self.num_envs:
            raise ValueError(
                f"batch_size * num_minibatches must be divisible by num_envs, got "
                f"{self.batch_size} * {self.num_minibatches} and {self.num_envs}"
            )


@dataclasses.dataclass(frozen=True)
class SACConfig(AlgoConfig):
    """SAC (``agents.learners.brax.sac``, brax's trainer): presets "paper" (the paper's Table 6), "fast" and "budget"
    (<= 20k env steps). Its update-to-data ratio is ``grad_updates_per_step / num_envs`` (brax's)."""

    NAME: ClassVar[str] = "SAC"
    PRESETS: ClassVar[dict] = {
        "paper": dict(
            num_envs=1,
            batch_size=256,
            grad_updates_per_step=1,
            learning_rate=3e-4,
            discounting=0.99,
            tau=0.002,
            max_replay_size=10_000,
            min_replay_size=1000,
            reward_scaling=1.0,
            normalize_observations=False,
            hidden=(256, 256),
            activation="relu",
            total_steps=300_000,
            num_evals=10,
            num_eval_envs=64,
        ),
        "fast": dict(
            num_envs=64,
            batch_size=256,
            grad_updates_per_step=16,
            learning_rate=1e-3,
            discounting=0.95,
            tau=0.005,
            max_replay_size=200_000,
            min_replay_size=8192,
            reward_scaling=1.0,
            normalize_observations=True,
            hidden=(128, 128),
            activation="relu",
            total_steps=400_000,
            num_evals=10,
            num_eval_envs=64,
        ),
        "budget": dict(
            num_envs=1,
            batch_size=128,
            grad_updates_per_step=10,
            learning_rate=1e-3,
            discounting=0.9,
            tau=0.005,
            max_replay_size=20_000,
            min_replay_size=500,
            reward_scaling=1.0,
            normalize_observations=True,
            hidden=(64, 64),
            activation="relu",
            total_steps=20_000,
            num_evals=10,
            num_eval_envs=16,
        ),
    }

    config: str = field(_choice("paper", "fast", "budget"))
    num_envs: int = field(COUNT)
    batch_size: int = field(COUNT)
    grad_updates_per_step: int = field(
        COUNT
    )  # per batched env step: the update-to-data ratio x num_envs
    learning_rate: float = field(POSITIVE)
    discounting: float = field(UNIT)
    tau: float = field(UNIT)
    max_replay_size: int = field(COUNT)
    min_replay_size: int = field(COUNT0)
    reward_scaling: float = field(NONNEG)
    normalize_observations: bool = field(_flag)
    hidden: tuple = field(_widths)
    activation: str = field(_ACTIVATION)
    total_steps: int = field(COUNT0)
    num_evals: int = field(COUNT)
    num_eval_envs: int = field(COUNT)

    def updates_per_step(self) -> float:
        return self.grad_updates_per_step / self.num_envs

    def check(self):
        if self.min_replay_size > self.max_replay_size:
            raise ValueError(
                f"min_replay_size must be <= max_replay_size, got {self.min_replay_size} > "
                f"{self.max_replay_size}"
            )


@dataclasses.dataclass(frozen=True)
class ReplayConfig(AlgoConfig):
    """Base of the off-policy learners' configs (``agents.learners.offpolicy.driver``): gradient steps per iteration are
    ``updates_per_iter``, or ``utd_ratio`` per env step (exactly one of the two); the observer's fields
    (``agents.learners.offpolicy.observer``), keyword-only, are common to them."""

    observer: str = field(OBSERVER, default="none", kw_only=True)
    # with observer="fit-residual": the fit's move plus this times the learner's action is sent
    residual_scale: float = field(UNIT, default=1.0, kw_only=True)
    # with an observer: the fit's random starts and iterations per start (None: the physics "frames" preset's)
    fit_starts: int | None = field(_optional(COUNT), default=None, kw_only=True)
    fit_iters: int | None = field(_optional(COUNT), default=None, kw_only=True)
    # with an observer: the earlier frames its fit compares with the latest (None: the "frames" preset's, 1)
    fit_history: int | None = field(_optional(HISTORY), default=None, kw_only=True)

    def updates_per_step(self) -> float:
        from agents.learners.offpolicy.replay import updates_per_iter

        return updates_per_iter(self.to_hyper()) / (self.num_envs * self.unroll)

    def check(self):
        """One of updates_per_iter and utd_ratio, a whole number of gradient steps per iteration, the buffer
        and batch sizes."""
        c = self
        if (c.updates_per_iter is None) == (c.utd_ratio is None):
            raise ValueError(
                f"set exactly one of updates_per_iter (gradient steps per iteration) and utd_ratio "
                f"(per env step), the other None; got {c.updates_per_iter!r} and {c.utd_ratio!r}"
            )
        if c.utd_ratio is not None:
            per_iter = c.utd_ratio * c.num_envs * c.unroll
            if per_iter < 1 or abs(per_iter - round(per_iter)) > 1e-6:
                raise ValueError(
                    f"utd_ratio * num_envs * unroll must be a whole number >= 1 of gradient steps per "
                    f"iteration, got {c.utd_ratio!r} * {c.num_envs} * {c.unroll}"
                )
        if c.buffer_size < c.num_envs * c.unroll:
            raise ValueError(
                f"buffer_size must be >= num_envs * unroll = {c.num_envs * c.unroll}, got {c.buffer_size}"
            )
        if c.learning_starts < c.batch_size:
            raise ValueError(
                f"learning_starts must be >= batch_size = {c.batch_size}, got {c.learning_starts}"
            )
        if c.batch_size > c.buffer_size:
            raise ValueError(
                f"batch_size must be <= buffer_size = {c.buffer_size}, got {c.batch_size}"
            )


@dataclasses.dataclass(frozen=True)
class TD3Config(ReplayConfig):
    """TD3 (``agents.learners.offpolicy.td3``): presets "paper" (the paper's Table 4), "fast" and "budget" (<= 20k env
    steps). Gradient steps per iteration: ``updates_per_iter``, or ``utd_ratio`` per env step (one of the two)."""

    NAME: ClassVar[str] = "TD3"
    PRESETS: ClassVar[dict] = {
        "paper": dict(
            num_envs=1,
            unroll=100,
            updates_per_iter=100,
            batch_size=100,
            hidden=(256, 256),
            actor_lr=3e-4,
            critic_lr=3e-4,
            gamma=0.98,
            tau=0.005,
            buffer_size=10_000,
            learning_starts=1000,
            expl_std=0.7,
            target_noise=0.2,
            noise_clip=0.5,
            policy_delay=2,
            normalize_obs=False,
            total_steps=300_000,
            eval_every=10_000,
            eval_episodes=16,
            utd_ratio=None,
            train_reward=None,
        ),
        "fast": dict(
            num_envs=32,
            unroll=1,
            updates_per_iter=4,
            batch_size=256,
            hidden=(256, 256),
            actor_lr=1e-3,
            critic_lr=1e-3,
            gamma=0.98,
            tau=0.005,
            buffer_size=100_000,
            learning_starts=4096,
            expl_std=0.4,
            target_noise=0.2,
            noise_clip=0.5,
            policy_delay=2,
            normalize_obs=True,
            total_steps=300_000,
            eval_every=20_000,
            eval_episodes=16,
            utd_ratio=None,
            train_reward=None,
        ),
        "budget": dict(
            num_envs=1,
            unroll=1,
            updates_per_iter=None,
            utd_ratio=10.0,
            batch_size=128,
            hidden=(64, 64),
            actor_lr=1e-3,
            critic_lr=1e-3,
            gamma=0.9,
            tau=0.005,
            buffer_size=20_000,
            learning_starts=1000,
            expl_std=0.2,
            target_noise=0.2,
            noise_clip=0.5,
            policy_delay=2,
            normalize_obs=True,
            total_steps=20_000,
            eval_every=1_000,
            eval_episodes=16,
            train_reward=None,
        ),
    }

    config: str = field(_choice("paper", "fast", "budget"))
    num_envs: int = field(COUNT)
    unroll: int = field(COUNT)
    updates_per_iter: int | None = field(_optional(COUNT))
    batch_size: int = field(COUNT)
    hidden: tuple = field(_widths)
    actor_lr: float = field(POSITIVE)
    critic_lr: float = field(POSITIVE)
    gamma: float = field(UNIT)
    tau: float = field(UNIT)
    buffer_size: int = field(COUNT)
    learning_starts: int = field(COUNT0)
    expl_std: float = field(NONNEG)
    target_noise: float = field(NONNEG)
    noise_clip: float = field(NONNEG)
    policy_delay: int = field(COUNT)
    normalize_obs: bool = field(_flag)
    total_steps: int = field(COUNT0)
    eval_every: int = field(COUNT)
    eval_episodes: int = field(COUNT)
    utd_ratio: float | None = field(_optional(Range(0, 1e4, lo_open=True)))
    train_reward: str | None = field(TRAIN_REWARD)


@dataclasses.dataclass(frozen=True)
class DroQConfig(ReplayConfig):
    """DroQ (``agents.learners.offpolicy.droq``): SAC with dropout + LayerNorm critics at a high update-to-data
    ratio; preset "budget" (<= 20k env steps). Gradient steps as in ``TD3Config``."""

    NAME: ClassVar[str] = "DroQ"
    DEFAULT_PRESET: ClassVar[str] = "budget"
    PRESETS: ClassVar[dict] = {
        "budget": dict(
            num_envs=1,
            unroll=1,
            updates_per_iter=None,
            utd_ratio=10.0,
            batch_size=128,
            hidden=(64, 64),
            critic_hidden=(64, 64),
            dropout=0.0,
            layer_norm=True,
            actor_lr=1e-3,
            critic_lr=1e-3,
            alpha_lr=1e-3,
            init_alpha=0.1,
            target_entropy=-1.0,
            gamma=0.97,
            tau=0.005,
            buffer_size=20_000,
            learning_starts=1000,
            policy_delay=1,
            normalize_obs=True,
            total_steps=20_000,
            eval_every=1_000,
            eval_episodes=16,
            train_reward="linear",
        )
    }
    # learning on a bench from its frames (``agents.bench --learn droq``): a correction, a quarter of the action
    # range at most, added to the physics-informed fit's move, the fit at 4 starts x 6 iterations (a bench's pace)
    PRESETS["bench"] = dict(
        PRESETS["budget"], observer="fit-residual", residual_scale=0.25, fit_starts=4, fit_iters=6
    )

    config: str = field(_choice("budget", "bench"))
    num_envs: int = field(COUNT)
    unroll: int = field(COUNT)
    updates_per_iter: int | None = field(_optional(COUNT))
    utd_ratio: float | None = field(_optional(Range(0, 1e4, lo_open=True)))
    batch_size: int = field(COUNT)
    hidden: tuple = field(_widths)
    critic_hidden: tuple = field(_widths)
    dropout: float = field(Range(0, 0.9))
    layer_norm: bool = field(_flag)
    actor_lr: float = field(POSITIVE)
    critic_lr: float = field(POSITIVE)
    alpha_lr: float = field(NONNEG)
    init_alpha: float = field(POSITIVE)
    target_entropy: float = field(Range(-100, 100))
    gamma: float = field(UNIT)
    tau: float = field(UNIT)
    buffer_size: int = field(COUNT)
    learning_starts: int = field(COUNT0)
    policy_delay: int = field(COUNT)
    normalize_obs: bool = field(_flag)
    total_steps: int = field(COUNT0)
    eval_every: int = field(COUNT)
    eval_episodes: int = field(COUNT)
    train_reward: str | None = field(TRAIN_REWARD)
