"""SPGD with a PID loop: the optics community's classic model-free controller, batched and jitted,
with a gain schedule and an escape from the landscape's local maxima.

Each control step, per instance (B of them):
1. draw a perturbation d = amp * s, s in {-1, +1}^N (Bernoulli signs), d in wavelengths (wl);
2. P(tau) is read from the current observation (its latest frame's P/Pmax, ``env.layout.power``,
   with the observation noise; no extra measurement) and P(tau + d) is one counted ``probe``: 2
   measurements per control step;
3. gradient estimate g = [P(tau + d) - P(tau)] * s / amp  (P in units of P/Pmax, g in 1/wl;
   this is the classic [P(tau+d) - P(tau)] * d rescaled by 1/amp^2, an estimate of dP/dx);
4. PID on g: i <- leak * i + g, u = Kp(P) g + Ki i + Kd (g - g_prev), action = clip(u, -1, 1)
   (one unit of action moves a delay line by the environment's ``action_scale``, 0.01 wl). The PID
   state lives in the carry; ``leak`` in [0, 1] bounds the integral (anti-windup).

Amplitude and gain schedules. amp_t = delta + (delta0 - delta) exp(-t / anneal) (t = control steps
since ``init``): a large dither first (a smoothed gradient), then a fine one. The proportional gain
falls as P rises, Kp(P) = kp_min + (kp - kp_min) (1 - P)^kp_pow: far from the top a high gain moves
the lines at full speed; near it the estimate's cross-talk between stages (every stage is dithered
at once, so g_i carries the other stages' gradients) makes a high gain a random walk. Near the top
P/Pmax ~ 1 - 79 sum_i x_i^2 (x_i in wl, 5 stages), and the per-step update is stable only for
Kp < ~0.3 (kp_min 0.1 chosen); with a fixed Kp of 16 the lines jitter by ~0.01 wl and P hovers
at 0.85-0.98.

Stall escape (``jump`` > 0; ``jump = 0`` is plain SPGD-PID): ``agents.controllers.escape``, which
the trim (``agents.controllers.trim``) shares; during a committed jump its lines move at full action
speed.

``SPGDConfig``'s preset holds values chosen by a grid search (5-stage, phasor, tuning seed 1000;
other seeds for evaluation); ``python -m agents.controllers.spgd --search`` reruns the patience x
margin grid. Measured results: docs/results.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from agents.controllers import escape
from agents.api import Policy, TrainResult, evaluated_result
from agents.config import DITHER, field
from agents.registry import Algo
from ops_jax import EnvSpec
from ops_jax.ranges import Range
from agents.envs import built, check_env_spec


@dataclasses.dataclass(frozen=True)
class SPGDConfig(escape.EscapeConfig):
    """SPGD-PID (``agents.controllers.spgd``): dither (wl), gain schedule, PID and the stall
    escape."""

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
    # for probes read a frame later, as on a bench (ops_jax EnvConfig.probe="frame"): a dither above
    # the frame-to-frame change of P, a lower gain (docs/imperfections.md)
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


ALGO = Algo("spgd", __name__, SPGDConfig, "SPGD")


def dither(key, shape) -> jax.Array:
    """Random signs s in {-1, +1} (float32) of a one-probe perturbation d = amp * s."""
    return jnp.where(jax.random.bernoulli(key, 0.5, shape), 1.0, -1.0).astype(jnp.float32)


def slope(p0, p1, s, amp) -> jax.Array:
    """The one-probe gradient estimate g = [P(tau + amp s) - P(tau)] s / amp (B, N), 1/wl."""
    return ((p1 - p0)[:, None] * s / amp).astype(jnp.float32)


def proportional_gain(p: dict, p0) -> jax.Array:
    """Kp(P) = kp_min + (kp - kp_min) (1 - P)^kp_pow (B, 1) at the measured P/Pmax ``p0`` (B,): the
    gain schedule."""
    return p["kp_min"] + (p["kp"] - p["kp_min"]) * jnp.clip(1 - p0, 0, 1)[:, None] ** p["kp_pow"]


HOLD = {
    k: np.float32(v) for k, v in SPGDConfig.PRESETS["default"].items()
}  # the hold's dither (delta) and gains


def held(action, p0, g, hold) -> jax.Array:
    """The hold of the physics-informed controller and the trim: ``action`` (B, N) where the
    measured P/Pmax ``p0`` (B,) is under ``hold``, at or above it the proportional step up the
    probed slope ``g`` (B, N), 1/wl, with the preset's gain schedule."""
    step = jnp.clip(proportional_gain(HOLD, p0) * g, -1.0, 1.0)
    return jnp.where((p0 >= hold)[:, None], step, action)


def gains(hyper: dict | SPGDConfig, action_scale: float = 0.01) -> dict:
    """The controller's parameters (float32 scalars) from hyperparameters (a ``SPGDConfig`` or
    overrides of its default preset), plus ``action_scale`` (wl per unit action of the environment
    it runs in; the escape's move needs it)."""
    return scaled(
        hyper if isinstance(hyper, SPGDConfig) else SPGDConfig.from_hyper(hyper), action_scale
    )


def scaled(config, action_scale: float) -> dict:
    """A controller's parameters: ``config``'s fields as float32 scalars and ``action_scale`` (wl
    per unit action)."""
    if (
        isinstance(action_scale, bool)
        or not isinstance(action_scale, (int, float, np.number))
        or not action_scale > 0
    ):
        raise ValueError(
            f"action_scale must be a number > 0 (wl per unit action), got {action_scale!r}"
        )
    return {
        **{k: jnp.float32(v) for k, v in config.to_hyper().items()},
        "action_scale": jnp.float32(action_scale),
    }


def params_template(env_spec, config):
    del env_spec, config
    return None


def make_policy(env_spec: EnvSpec, config: SPGDConfig | None = None) -> Policy:
    """SPGD-PID policy on the environment of ``env_spec`` (an ``EnvSpec`` or a dict of its
    options). ``params``: ``gains(config, action_scale)``; ``None`` uses ``config`` (None: the
    default preset) and the environment's default action scale."""
    env, env_params = built(check_env_spec(env_spec))
    n, layout = env.num_actions, env.layout
    default = gains(SPGDConfig.of(config), float(env_params.action_scale))
    cands = escape.candidates(n)

    def init(key, obs):
        del key
        b = obs.shape[0]
        z = jnp.zeros((b, n), jnp.float32)
        # PID state; t: steps since init; the escape's state (agents.controllers.escape)
        return {"i": z, "g_prev": z, "t": jnp.zeros((b,), jnp.float32), **escape.init(b, n)}

    def act(params, carry, obs, key, probe):
        p = default if params is None else params
        b = obs.shape[0]
        s = dither(key, (b, n))
        p0 = layout.power(obs)
        # Annealed amplitude: delta0 at t = 0 decaying to delta with time constant `anneal` steps.
        frac = jnp.exp(-carry["t"] / jnp.maximum(p["anneal"], 1e-6))[:, None]
        amp = p["delta"] + (p["delta0"] - p["delta"]) * frac
        offsets, testing = escape.probe_offsets(p, carry, cands, amp * s)
        p1 = probe(offsets)  # one probe either way
        g = jnp.where(testing[:, None], 0.0, slope(p0, p1, s, amp))
        i = p["leak"] * carry["i"] + g
        kp = proportional_gain(p, p0)
        u = jnp.clip(kp * g + p["ki"] * i + p["kd"] * (g - carry["g_prev"]), -1.0, 1.0)
        action, esc = escape.step(p, escape.of(carry), cands, testing, p0, p1, u)
        return action, {"i": i, "g_prev": g, "t": carry["t"] + 1, **esc}

    return Policy(init, act)


def train(
    env_config: dict,
    *,
    seed: int = 0,
    total_steps: int | None = None,
    progress_fn=None,
    curve_episodes: int = 32,
    config: SPGDConfig | str | None = None,
    **hyper,
) -> TrainResult:
    """No learning: the params are ``gains(config)`` (default: the searched preset) with the
    environment's action scale. The curve is
    ``agents.evaluate(result, env_config, episodes=curve_episodes, seed=seed)``, reported once to
    ``progress_fn(0, metrics)``; ``total_steps`` is ignored (0 env steps used)."""
    env_spec = check_env_spec(env_config)
    c = SPGDConfig.make(config, **hyper)
    _, env_params = built(env_spec)
    params = {k: np.asarray(v) for k, v in gains(c, float(env_params.action_scale)).items()}
    return evaluated_result("spgd", env_spec, c, params, seed, curve_episodes, progress_fn)


def search(
    grid: dict,
    modes=("easy", "medium", "hard"),
    stages: int = 5,
    episodes: int = 1024,
    seed: int = 1000,
):
    """Grid search: returns a list of (hyper, {mode: final mean}) sorted by the mean over modes.
    Jitted once per mode (gains are traced parameters)."""
    from tqdm import tqdm

    names = sorted(grid)
    combos = [dict(zip(names, vals)) for vals in itertools.product(*(grid[k] for k in names))]
    from agents.evaluation import evaluator, episode_ids

    runs = {}
    for m in modes:
        cfg = {"stages": stages, "mode": m, "model": "phasor"}
        env, env_params = built(cfg)
        runs[m] = (evaluator(env, make_policy(cfg), env.config.max_steps, 10), env_params)
    ids, key = episode_ids(episodes), jax.random.key(seed)
    rows = []
    for h in tqdm(combos, desc="spgd grid"):
        scores = {}
        for m, (run, env_params) in runs.items():  # compiled once per mode
            npow = run(gains(h, float(env_params.action_scale)), env_params, key, ids)[0]
            scores[m] = float(np.asarray(npow)[-1].mean())
        rows.append((h, scores))
    rows.sort(key=lambda r: -np.mean(list(r[1].values())))
    return rows


if __name__ == "__main__":
    from ops_jax.cli.progress import keep_ctrl_c

    keep_ctrl_c()
    ap = argparse.ArgumentParser(
        description="SPGD-PID search (the stall-escape grid of the module docstring)"
    )
    ap.add_argument("--search", action="store_true")
    ap.add_argument("--episodes", type=int, default=1024)
    a = ap.parse_args()
    if a.search:
        g = dict(patience=[6.0, 10.0, 14.0], margin=[0.002, 0.005, 0.01])
        for h, s in search(g, episodes=a.episodes)[:15]:
            print(h, {k: round(v, 4) for k, v in s.items()})
