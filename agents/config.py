"""The base of every algorithm's hyperparameters: a frozen dataclass per algorithm, declared beside
its code (``agents.controllers.spgd.SPGDConfig``, ``agents.learners.offpolicy.td3.TD3Config``, ...;
all exported by ``agents``), with named presets overridable per field, validated in one place.

    PPOConfig.preset("fast", learning_rate=1e-3)   # a preset with one field changed
    TD3Config.make("paper")                        # make(config, **overrides): a preset or a config
    SPGDConfig.from_hyper(meta["hyper"])           # back from the stored dict (``to_hyper``)

A value out of range raises ValueError naming the field and its accepted range
(``ops_jax.ranges.Range``, the one range check of the package); an unknown field raises TypeError
listing the accepted ones. ``to_hyper()`` is the stored form (checkpoints' ``meta.json``, the
sweep): the fields (tuples as lists) and, for the learners, ``config``, the preset's name. The
field checks shared by several algorithms (``flag``, ``widths``, ``choice``, ``optional`` and the
ranges below) are here; the presets' tuning is described in each algorithm's module.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np

from ops_jax.ranges import Range


def flag(name: str, v):
    if not isinstance(v, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {v!r}")
    return bool(v)


def widths(name: str, v):
    if (
        not isinstance(v, (list, tuple))
        or not v
        or not all(
            isinstance(h, (int, np.integer)) and not isinstance(h, bool) and h >= 1 for h in v
        )
    ):
        raise ValueError(f"{name} must be a non-empty sequence of layer widths >= 1, got {v!r}")
    return tuple(int(h) for h in v)


def choice(*options):
    def check(name: str, v):
        if v not in options:
            raise ValueError(f"{name} must be one of {list(options)}, got {v!r}")
        return v

    return check


def optional(check):
    """``check``, or None left as it is."""

    def f(name: str, v):
        return None if v is None else check(name, v)

    return f


def field(check, **default):
    """A dataclass field validated by ``check(name, value) -> normalised value``. With
    ``default=value`` (fields added after configurations were stored), the field is left out of the
    stored form at that value, so stored configurations keep their form (and the sweep's cells their
    keys)."""
    return dataclasses.field(metadata={"check": check}, **default)


DITHER = Range(1e-6, 0.25, unit="wl")  # a dither's amplitude (SPGD, the trim)
# the earlier frames the physics-informed fit compares with the latest, through the moves since (1:
# the frame before it)
HISTORY = Range(1, 16, integer=True)
COUNT, COUNT0 = Range(1, integer=True), Range(0, integer=True)  # integers >= 1, >= 0
POSITIVE, NONNEG, UNIT = (
    Range(0, lo_open=True),
    Range(0),
    Range(0, 1, lo_open=True),
)  # > 0, >= 0, (0, 1]
ACTIVATION = choice("tanh", "relu", "swish", "elu")  # the brax learners' hidden activation


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

    def budget_layout(self) -> tuple[int, int, str] | None:
        """(env steps before the first gradient step, env steps per training step, what the first
        ones are) of a budget (``agents.learners.budgets``); None for a controller, which trains
        nothing."""
        return None

    def trained_units(self, units: int) -> int:
        """Training steps that ``units`` affordable ones become (whole chunks or epochs)."""
        return units

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
        """``config``: a preset name (None: the default preset) or a config of this type; plus
        overrides."""
        if isinstance(config, cls):
            cls._check_names(overrides)
            return dataclasses.replace(config, **overrides)
        return cls.preset(config, **overrides)

    @classmethod
    def of(cls, config):
        """``config`` (a config of this type) or, for None, the default preset; TypeError for
        anything else (a stored dict: ``from_hyper``)."""
        if config is None:
            return cls.preset()
        if not isinstance(config, cls):
            raise TypeError(
                f"config must be a {cls.__name__} or None (the default preset), got "
                f"{type(config).__name__}"
            )
        return config

    @classmethod
    def from_hyper(cls, hyper: dict | None):
        """The config of a stored ``to_hyper()`` dict (or any
        ``{"config": name, field: value}``)."""
        hyper = dict(hyper or {})
        return cls.make(hyper.pop("config", None), **hyper)

    @classmethod
    def from_stored(cls, hyper: dict | None):
        """The config of a checkpoint's stored ``hyper`` (keys that are not fields are left
        out)."""
        names = {*cls.names(), "config"}
        return cls.from_hyper({k: v for k, v in (hyper or {}).items() if k in names})

    def to_hyper(self) -> dict:
        """The stored form: field -> value (tuples as lists), with ``config`` for the learners."""
        return {
            f.name: list(v) if isinstance(v, tuple) else v
            for f in dataclasses.fields(self)
            for v in [getattr(self, f.name)]
            if f.default is dataclasses.MISSING or v != f.default
        }
