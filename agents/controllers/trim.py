"""An extremum-seeking trim around any policy: a slowly integrated action offset that climbs the
measured power, removing the static bias a policy keeps on a system it has not fully learnt.

Each control step, per instance (B of them), with pi the wrapped policy and c (B, N) the trim:
1. a = clip(pi(obs) + c, -1, 1), in the environment's action units;
2. one probe P(tau + amp s) with random signs s (``agents.controllers.spgd.dither``) gives SPGD's
   one-probe gradient estimate g (``agents.controllers.spgd.slope``, 1/wl), so 2 measurements per
   control step as SPGD; none where nothing would use it (the measured P/Pmax under ``p_gate`` and
   under ``hold``, the escape not testing): there the wrapped policy runs at one measurement per
   step (``probe``'s ``active``, ``agents.api``);
3. while the measured P/Pmax >= ``p_gate``: c <- c + ki g; below it: c <- release c;
4. with ``hold``: where the measured P/Pmax is at or above it, the move is SPGD's proportional step
   up g (``agents.controllers.spgd.held``) instead of a: the wrapped policy acquires, the dither
   holds;
5. the stall escape (``agents.controllers.escape``, as SPGD's; ``jump = 0``: off): after
   ``patience`` steps below ``p_stall`` the probe tests jumps of a line or a pair of lines by
   ``jump`` wl instead of the dither, and a committed jump moves its lines at full action speed, the
   wrapped policy paused on those lines;
6. a wrapped policy that reads its own last move (``Policy.sent``: the physics-informed fit, the fit
   observer) is told the move sent, trim, hold and escape included.

A feedback policy a = -K (x - x0) (x the delay offsets, x0 where the policy believes the optimum is)
settles with the trim at x0 + c / K: the integrator moves the set point until the measured gradient
vanishes, whatever the policy's calibration error. No learning and no model; ``ki = 0`` is the
wrapped policy itself. The gate keeps the trim from integrating while the policy is still acquiring
(P far from the top, where g says little about the final set point); ``release < 1`` lets a trim
that has led the lines away from the top decay, so the policy takes over again. The escape leaves
the local maxima (a stage at a pi phase error) where a policy, like any hill climber, can stop. Gate
and escape are off by default: on the tuning benches the gate kept the trim from freeing episodes in
which the policy alone stops short, and the escape fought policies still acquiring
(docs/learners.md).

    policy, params = trim.trimmed(result)                     # a TrainResult, default TrimConfig
    agents.evaluate((policy, params), env_config, episodes=32)
    policy, params = trim.trimmed(result, {"ki": 0.005})      # overrides of the default preset

The trim's gains are parameters of the wrapped program (traced, not static): one compiled program
serves every ``TrimConfig``. The default preset's tuning: docs/learners.md.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from agents.controllers import escape, spgd
from agents.api import Policy, TrainResult
from agents.config import DITHER, field, optional
from ops_jax import EnvSpec
from ops_jax.ranges import Range
from agents.envs import built, check_env_spec


@dataclasses.dataclass(frozen=True)
class TrimConfig(escape.EscapeConfig):
    """The extremum-seeking trim (``agents.controllers.trim``): integral gain, dither (wl), the gate
    on P/Pmax and the stall escape."""

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
    # integrates only above half of P_max and lets the offset decay below: a trim that led a line
    # off the top is undone (docs/learners.md, "Does the trim ever lose?")
    PRESETS["guarded"] = dict(PRESETS["default"], p_gate=0.5, release=0.9)
    # the guarded trim with a dither above the frame-to-frame change of P, for probes read a frame
    # later (a bench; ops_jax ``EnvConfig.probe="frame"``, docs/learners.md)
    PRESETS["bench"] = dict(PRESETS["guarded"], amp=0.005)

    ki: float = field(Range(0, 1))
    amp: float = field(DITHER)
    p_gate: float = field(Range(0, 1))
    release: float = field(Range(0, 1))
    # the measured P/Pmax at and above which SPGD's proportional step up the probed slope replaces
    # the move (``agents.controllers.spgd.held``; None: never)
    hold: float | None = field(optional(Range(0, 1)), default=None)


DITHER_STREAM = (
    1  # the dither's key: the step's key folded with this, apart from the wrapped policy's
)


def gains(hyper: dict | TrimConfig | None = None, action_scale: float = 0.01) -> dict:
    """The trim's parameters (float32 scalars) from a ``TrimConfig`` or overrides of its default
    preset, plus ``action_scale`` (wl per unit action of the environment it runs in; the escape's
    move needs it)."""
    c = hyper if isinstance(hyper, TrimConfig) else TrimConfig.from_hyper(hyper)
    return {
        **spgd.scaled(c, action_scale),
        "hold": jnp.float32(jnp.inf if c.hold is None else c.hold),
    }


def make_policy(policy: Policy, env_config: EnvSpec | dict) -> Policy:
    """``policy`` with the trim; the wrapped program's params are
    ``{"policy": its params, "trim": gains(...)}`` (``None``: the wrapped policy's default params
    and the default trim)."""
    env, env_params = built(check_env_spec(env_config))
    n, layout = env.num_actions, env.layout
    default = gains(None, float(env_params.action_scale))
    cands = escape.candidates(n)

    def init(key, obs):
        b = obs.shape[0]
        return {
            "policy": policy.init(key, obs),
            "c": jnp.zeros((b, n), jnp.float32),
            **escape.init(b, n),
        }

    def act(params, carry, obs, key, probe):
        inner, p = (None, default) if params is None else (params["policy"], params["trim"])
        a, inner_carry = policy.act(inner, carry["policy"], obs, key, probe)
        s = spgd.dither(jax.random.fold_in(key, DITHER_STREAM), (obs.shape[0], n))
        p0 = layout.power(obs)
        esc = escape.of(carry)
        offsets, testing = escape.probe_offsets(p, esc, cands, p["amp"] * s)
        near = (p0 >= p["p_gate"])[:, None]
        p1 = probe(
            offsets, near[:, 0] | testing | (p0 >= p["hold"])
        )  # none where its reading would go unused
        g = jnp.where(testing[:, None], 0.0, spgd.slope(p0, p1, s, p["amp"]))
        c = jnp.where(near, carry["c"] + p["ki"] * g, p["release"] * carry["c"])
        action = spgd.held(jnp.clip(a + c, -1.0, 1.0), p0, g, p["hold"])
        action, esc = escape.step(p, esc, cands, testing, p0, p1, action)
        return action, {"policy": told(inner, inner_carry, action), "c": c, **esc}

    def told(inner, inner_carry, action):
        """The wrapped policy's carry told the move really sent (``Policy.sent``)."""
        return inner_carry if policy.sent is None else policy.sent(inner, inner_carry, action)

    def sent(params, carry, action):
        return dict(
            carry,
            policy=told(None if params is None else params["policy"], carry["policy"], action),
        )

    return Policy(init, act, sent)


def trimmed(
    result: TrainResult | tuple,
    hyper: dict | TrimConfig | None = None,
    env_config: EnvSpec | dict | None = None,
):
    """``(Policy, params)`` of a ``TrainResult`` (or a ``(Policy, params)`` pair, with
    ``env_config``) with the trim (``hyper``: a ``TrimConfig`` or overrides of its default preset),
    for ``agents.evaluate`` or the bench."""
    if isinstance(result, TrainResult):
        policy, params, env_config = result.policy(), result.params, env_config or result.env_spec
    elif isinstance(result, tuple) and len(result) == 2 and isinstance(result[0], Policy):
        if env_config is None:
            raise ValueError(
                "env_config is needed to trim a (Policy, params) pair (its frame layout and N)"
            )
        policy, params = result
    else:
        raise TypeError(
            f"trimmed takes a TrainResult or a (Policy, params) pair, got {type(result).__name__}"
        )
    trim = gains(hyper, float(built(check_env_spec(env_config))[1].action_scale))
    return make_policy(policy, env_config), {"policy": params, "trim": trim}
