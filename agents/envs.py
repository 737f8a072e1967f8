"""Environments built once per configuration: ``built(env_config)`` is
``ops_jax.make(**env_config)`` memoised by the configuration's ``EnvSpec``, so the P_best search of
an imperfect configuration (an ascent over the static optics, ``ops_jax.imperfections.best_power``)
runs once per configuration and process, however many trainings, policies and evaluations use it. A
configuration is an ``ops_jax.EnvSpec`` or a dict of ``ops_jax.make`` keyword arguments
(``check_env_spec`` converts it once, at the API's boundary)."""

from __future__ import annotations

import dataclasses
from collections import OrderedDict

import ops_jax
from ops_jax import EnvSpec

_BUILT: "OrderedDict[EnvSpec, tuple]" = OrderedDict()
_BUILT_MAX = 64


def built(env_config: EnvSpec | dict) -> tuple:
    """``(env, params)`` of ``ops_jax.make(**env_config)`` (raises what ``make`` raises), built once
    per configuration (keyed by its ``EnvSpec``). Shared: do not modify the params' arrays in
    place."""
    spec = EnvSpec.from_options(env_config)
    if spec not in _BUILT:
        _BUILT[spec] = ops_jax.make(**spec.as_dict())
        if len(_BUILT) > _BUILT_MAX:
            _BUILT.popitem(last=False)
    _BUILT.move_to_end(spec)
    return _BUILT[spec]


def best_ratio(env_config: EnvSpec | dict) -> float:
    """P_max / P_best of the environment of ``env_config`` (1 for the ideal system): a P/Pmax times
    it is P/P_best."""
    env, params = built(env_config)
    return env.p_max / float(params.lab.p_best) if env.config.imperfect else 1.0


def train_env_config(env_config: EnvSpec | dict, reward: str | None = None) -> EnvSpec:
    """The spec the learners train on: ``model="phasor"`` unless one is given, and the learner's
    own training ``reward`` (``ops_jax.REWARDS``) if it has one."""
    spec = EnvSpec.from_options(env_config)
    model = "phasor" if spec.model is None else spec.model
    return dataclasses.replace(spec, model=model, reward=spec.reward if reward is None else reward)


def check_env_spec(env_config: EnvSpec | dict) -> EnvSpec:
    """The ``EnvSpec`` of an ``EnvSpec`` or a dict of ``ops_jax.make`` options, its environment
    built (raises what ``make`` raises; TypeError for anything else)."""
    spec = EnvSpec.from_options(env_config)
    built(spec)
    return spec


def check_env_config(env_config: EnvSpec | dict) -> dict:
    """The ``ops_jax.make`` keyword dict of an ``EnvSpec`` or a dict, validated (raises what
    ``make`` raises; TypeError for anything else): ``check_env_spec(env_config).as_dict()``."""
    return check_env_spec(env_config).as_dict()
