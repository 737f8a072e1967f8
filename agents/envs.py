"""Environments built once per configuration: ``built(env_config)`` is
``ops_jax.make(**env_config)`` memoised by the configuration's content, so the P_best search of an
imperfect configuration (an ascent over the static optics, ``ops_jax.imperfections.best_power``)
runs once per configuration and process, however many trainings, policies and evaluations use it. A
configuration is an ``ops_jax.EnvSpec`` or a dict of ``ops_jax.make`` keyword arguments
(``check_env_config`` converts it once, at the API's boundary)."""

from __future__ import annotations

import json
from collections import OrderedDict

import ops_jax
from ops_jax import EnvSpec

_BUILT: "OrderedDict[str, tuple]" = OrderedDict()
_BUILT_MAX = 64


def built(env_config: EnvSpec | dict) -> tuple:
    """``(env, params)`` of ``ops_jax.make(**env_config)`` (raises what ``make`` raises), built once
    per configuration. Shared: do not modify the params' arrays in place."""
    if isinstance(env_config, EnvSpec):
        env_config = env_config.as_dict()
    if not isinstance(env_config, dict):
        raise TypeError(
            f"env_config must be an ops_jax.EnvSpec or a dict of ops_jax.make keyword arguments, "
            f"got {type(env_config).__name__}"
        )
    try:
        key = json.dumps(env_config, sort_keys=True)
    except TypeError:  # arrays or numpy scalars: their spec's form
        env_config = EnvSpec.from_options(env_config).as_dict()
        key = json.dumps(env_config, sort_keys=True)
    if key not in _BUILT:
        _BUILT[key] = ops_jax.make(**env_config)
        if len(_BUILT) > _BUILT_MAX:
            _BUILT.popitem(last=False)
    _BUILT.move_to_end(key)
    return _BUILT[key]


def best_ratio(env_config: EnvSpec | dict) -> float:
    """P_max / P_best of the environment of ``env_config`` (1 for the ideal system): a P/Pmax times
    it is P/P_best."""
    env, params = built(env_config)
    return env.p_max / float(params.lab.p_best) if env.config.imperfect else 1.0


def train_env_config(env_config: dict, reward: str | None = None) -> dict:
    """The env_config the learners train on: ``model="phasor"`` unless one is given, and the
    learner's own training ``reward`` (``ops_jax.REWARDS``) if it has one."""
    return {"model": "phasor", **env_config, **({"reward": reward} if reward is not None else {})}


def check_env_config(env_config: EnvSpec | dict) -> dict:
    """The ``ops_jax.make`` keyword dict of an ``EnvSpec`` or a dict, validated (raises what
    ``make`` raises; TypeError for anything else):
    ``EnvSpec.from_options(env_config).as_dict()``."""
    options = EnvSpec.from_options(env_config).as_dict()
    built(options)
    return options
