"""The stall escape from the landscape's local maxima, shared by SPGD (``agents.controllers.spgd``)
and the trim (``agents.controllers.trim``).

The objective is periodic in each line with period wl/2 and has local maxima with one or more stages
at a pi phase error (offset wl/4 = 0.25 wl): P/Pmax near 0.5, 0.44, 0.34, 0.24, from which no hill
climber moves. After ``patience`` consecutive steps below ``p_stall`` (measured P/Pmax), the
controller's one probe of the next steps tests P at tau + jump * c for the candidates c in turn
instead of its dither: each line alone (c = e_k), then each pair of lines (c = e_k + e_l), N (N + 1)
/ 2 in all. The first candidate that beats P(tau) by ``margin`` is committed: its lines are moved by
``jump`` wl at full action speed (0.25 wl: 25 steps at 0.01 wl per step), overriding the
controller's action on those lines. If none passes, the escape waits ``patience`` steps and tests
again. Pairs matter: the most common trap (P/Pmax ~0.24, lines 1 and 3 at pi, line 2 near wl/8) is
left by no single-line jump. ``jump = 0`` turns the escape off.

    cands = escape.candidates(n)
    state = escape.init(b, n)
    offsets, testing = escape.probe_offsets(p, state, cands, dither_offsets)  # the step's one probe
    action, state = escape.step(p, state, cands, testing, p0, probe(offsets), action)

``p``: the controller's parameters with ``jump`` (wl), ``patience`` (steps), ``p_stall``, ``margin``
(P/Pmax) and ``action_scale`` (wl per unit action).
"""

from __future__ import annotations

import dataclasses
import itertools

import jax.numpy as jnp
import numpy as np

from agents.config import AlgoConfig, field
from ops_jax.ranges import Range


@dataclasses.dataclass(frozen=True)
class EscapeConfig(AlgoConfig):
    """The stall escape's fields (``agents.controllers.escape``), shared by SPGD and the trim: jump
    (wl), patience (steps), p_stall and margin (P/Pmax)."""

    jump: float = field(Range(0, 0.5, unit="wl"))
    patience: float = field(Range(1, 1e6))
    p_stall: float = field(Range(0, 1))
    margin: float = field(Range(0, 1))


def candidates(n: int) -> jnp.ndarray:
    """The escape's candidate moves (N (N + 1) / 2, N) in the order tested: each line, then each
    pair."""
    pairs = [np.eye(n)[i] + np.eye(n)[j] for i, j in itertools.combinations(range(n), 2)]
    return jnp.asarray(np.concatenate([np.eye(n), np.reshape(pairs, (-1, n))]), jnp.float32)


def init(b: int, n: int) -> dict:
    """stall: steps below p_stall; cand: next candidate; move: what is left of a committed jump per
    line (wl)."""
    return {
        "stall": jnp.zeros((b,), jnp.float32),
        "cand": jnp.zeros((b,), jnp.int32),
        "move": jnp.zeros((b, n), jnp.float32),
    }


def of(carry: dict) -> dict:
    """The escape's state held in a controller's carry (the keys of ``init``)."""
    return {k: carry[k] for k in ("stall", "cand", "move")}


def _moving(state):
    return jnp.any(state["move"] != 0, axis=1)


def probe_offsets(p: dict, state: dict, cands, dither_offsets):
    """The step's probe offsets (B, N) wl: the next candidate's jump where testing, else
    ``dither_offsets``; and ``testing`` (B,)."""
    testing = (state["stall"] >= p["patience"]) & ~_moving(state) & (p["jump"] > 0)
    return jnp.where(testing[:, None], p["jump"] * cands[state["cand"]], dither_offsets), testing


def step(p: dict, state: dict, cands, testing, p0, p1, action):
    """The action with a committed jump's lines at full speed, and the escape's next state; ``p0``:
    P/Pmax at tau, ``p1``: the probe's."""
    moving = _moving(state)
    commit = testing & (p1 > p0 + p["margin"])
    move = jnp.where(commit[:, None], p["jump"] * cands[state["cand"]], state["move"])
    push = jnp.clip(move / p["action_scale"], -1.0, 1.0)
    action = jnp.where(move != 0, push, action)
    left = move - push * p["action_scale"]
    move = jnp.where(jnp.abs(left) < 1e-6, 0.0, left)
    stall = jnp.where((p0 < p["p_stall"]) & ~commit & ~moving, state["stall"] + 1, 0.0)
    cand = jnp.where(testing & ~commit, (state["cand"] + 1) % cands.shape[0], state["cand"])
    stall = jnp.where(
        testing & ~commit & (cand == 0), 0.0, stall
    )  # all candidates failed: wait again
    return action, {"stall": stall, "cand": cand, "move": move}
