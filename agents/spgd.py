"""SPGD with a PID loop: the optics community's classic model-free controller, batched and jitted,
with a gain schedule and an escape from the landscape's local maxima.

Each control step, per instance (B of them):
1. draw a perturbation d = amp * s, s in {-1, +1}^N (Bernoulli signs), d in wavelengths (wl);
2. P(tau) is read from the current observation (obs[:, 0] = 2 P/Pmax - 1 + obs noise, no extra
   measurement) and P(tau + d) is one counted ``probe``: 2 measurements per control step;
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

Stall escape (``jump`` > 0; ``jump = 0`` is plain SPGD-PID). The objective is periodic in each
line with period wl/2 and has local maxima with one or more stages at a pi phase error (offset
wl/4 = 0.25 wl): P/Pmax near 0.5, 0.44, 0.34, 0.24, from which no hill climber moves. After
``patience`` consecutive steps below ``p_stall``, the probe of the next steps (one per step, so
still 2 measurements per step) tests P at tau + jump * c for the candidates c in turn instead of the
dither: each line alone (c = e_k), then each pair of lines (c = e_k + e_l), N (N + 1) / 2 in all.
The first candidate that beats P(tau) by ``margin`` is committed: its lines are moved by ``jump``
at full action speed (0.25 wl: 25 steps at 0.01 wl per step) while the other lines keep climbing.
If none passes, the controller waits ``patience`` steps and tests again. Pairs matter: the most
common trap (P/Pmax ~0.24, lines 1 and 3 at pi, line 2 near wl/8) is left by no single-line jump.

``SPGDConfig``'s preset holds values chosen by a grid search (5-stage, phasor, tuning seed 1000; other
seeds for evaluation); ``python -m agents.spgd --search`` reruns the patience x margin grid. Measured
results: docs/results.md.
"""

from __future__ import annotations

import argparse
import itertools

import jax
import jax.numpy as jnp
import numpy as np

from agents.base import Policy, TrainResult, evaluated_result
from agents.config import SPGDConfig
from agents.envs import built, check_env_config

def gains(hyper: dict | SPGDConfig, action_scale: float = 0.01) -> dict:
    """The controller's parameters (float32 scalars) from hyperparameters (a ``SPGDConfig`` or
    overrides of its default preset), plus ``action_scale`` (wl per unit action of the environment
    it runs in; the escape's move needs it)."""
    c = hyper if isinstance(hyper, SPGDConfig) else SPGDConfig.from_hyper(hyper)
    if isinstance(action_scale, bool) or not isinstance(action_scale, (int, float, np.number)) or not action_scale > 0:
        raise ValueError(f"action_scale must be a number > 0 (wl per unit action), got {action_scale!r}")
    return {**{k: jnp.float32(v) for k, v in c.to_hyper().items()}, "action_scale": jnp.float32(action_scale)}


def params_template(env_config, hyper):
    del env_config, hyper
    return None


def make_policy(env_config: dict, hyper: dict | None = None) -> Policy:
    """SPGD-PID policy. ``params``: ``gains(hyper, action_scale)``; ``None`` uses ``hyper`` and
    the environment's default action scale."""
    env_config = check_env_config(env_config)
    env, env_params = built(env_config)
    n = env.num_actions
    frame = env.frame_size
    default = gains(hyper or {}, float(env_params.action_scale))
    # Escape candidates, in the order tested: each line alone, then each pair of lines.
    pairs = [np.eye(n)[i] + np.eye(n)[j] for i, j in itertools.combinations(range(n), 2)]
    candidates = jnp.asarray(np.concatenate([np.eye(n), np.reshape(pairs, (-1, n))]), jnp.float32)
    c = candidates.shape[0]

    def init(key, obs):
        del key
        b = obs.shape[0]
        z = jnp.zeros((b, n), jnp.float32)
        zb = jnp.zeros((b,), jnp.float32)
        # PID state; t: steps since init; stall: steps below p_stall; cand: next escape candidate;
        # move: what is left of a committed jump per line (wl)
        return {"i": z, "g_prev": z, "t": zb, "stall": zb, "cand": jnp.zeros((b,), jnp.int32), "move": z}

    def act(params, carry, obs, key, probe):
        p = default if params is None else params
        b = obs.shape[0]
        s = jnp.where(jax.random.bernoulli(key, 0.5, (b, n)), 1.0, -1.0).astype(jnp.float32)
        p0 = (obs[:, -frame] + 1) / 2  # latest frame's normalised power
        # Annealed amplitude: delta0 at t = 0 decaying to delta with time constant `anneal` steps.
        frac = jnp.exp(-carry["t"] / jnp.maximum(p["anneal"], 1e-6))[:, None]
        amp = p["delta"] + (p["delta0"] - p["delta"]) * frac
        moving = jnp.any(carry["move"] != 0, axis=1)
        testing = (carry["stall"] >= p["patience"]) & ~moving & (p["jump"] > 0)
        line = candidates[carry["cand"]]
        p1 = probe(jnp.where(testing[:, None], p["jump"] * line, amp * s))  # one probe either way
        g = jnp.where(testing[:, None], 0.0, (p1 - p0)[:, None] * s / amp).astype(jnp.float32)
        i = p["leak"] * carry["i"] + g
        kp = p["kp_min"] + (p["kp"] - p["kp_min"]) * jnp.clip(1 - p0, 0, 1)[:, None] ** p["kp_pow"]
        u = jnp.clip(kp * g + p["ki"] * i + p["kd"] * (g - carry["g_prev"]), -1.0, 1.0)
        # Escape: commit the tested line if it beats P(tau) by `margin`, then move it at full speed.
        commit = testing & (p1 > p0 + p["margin"])
        move = jnp.where(commit[:, None], p["jump"] * line, carry["move"])
        push = jnp.clip(move / p["action_scale"], -1.0, 1.0)
        action = jnp.where(move != 0, push, u)
        left = move - push * p["action_scale"]
        move = jnp.where(jnp.abs(left) < 1e-6, 0.0, left)
        stall = jnp.where((p0 < p["p_stall"]) & ~commit & ~moving, carry["stall"] + 1, 0.0)
        cand = jnp.where(testing & ~commit, (carry["cand"] + 1) % c, carry["cand"])
        stall = jnp.where(testing & ~commit & (cand == 0), 0.0, stall)  # all lines failed: wait again
        carry = {"i": i, "g_prev": g, "t": carry["t"] + 1, "stall": stall, "cand": cand, "move": move}
        return action, carry

    return Policy(init, act)


def train(env_config: dict, *, seed: int = 0, total_steps: int | None = None, progress_fn=None,
          curve_episodes: int = 32, config: SPGDConfig | str | None = None, **hyper) -> TrainResult:
    """No learning: the params are ``gains(config)`` (default: the searched preset) with the
    environment's action scale. The curve is
    ``agents.evaluate(result, env_config, episodes=curve_episodes, seed=seed)`` (served from memory
    when asked for again), reported once to ``progress_fn(0, metrics)``; ``total_steps`` is
    ignored (0 env steps used)."""
    env_config = check_env_config(env_config)
    c = SPGDConfig.make(config, **hyper)
    _, env_params = built(env_config)
    params = {k: np.asarray(v) for k, v in gains(c, float(env_params.action_scale)).items()}
    return evaluated_result("spgd", env_config, c.to_hyper(), params, seed, curve_episodes, progress_fn)


def search(grid: dict, modes=("easy", "medium", "hard"), stages: int = 5, episodes: int = 1024, seed: int = 1000):
    """Grid search: returns a list of (hyper, {mode: final mean}) sorted by the mean over modes.
    Jitted once per mode (gains are traced parameters)."""
    from tqdm import tqdm

    names = sorted(grid)
    combos = [dict(zip(names, vals)) for vals in itertools.product(*(grid[k] for k in names))]
    from agents.base import evaluator, episode_ids

    runs = {}
    for m in modes:
        cfg = {"stages": stages, "mode": m, "model": "phasor"}
        env, env_params = built(cfg)
        runs[m] = (evaluator(env, make_policy(cfg), env.config.max_steps, 10)[0], env_params)
    ids, key = episode_ids(episodes), jax.random.key(seed)
    rows = []
    for h in tqdm(combos, desc="spgd grid"):
        scores = {}
        for m, (run, env_params) in runs.items():  # compiled once per mode
            npow, _ = run(gains(h, float(env_params.action_scale)), env_params, key, ids)
            scores[m] = float(np.asarray(npow)[-1].mean())
        rows.append((h, scores))
    rows.sort(key=lambda r: -np.mean(list(r[1].values())))
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="SPGD-PID search (the stall-escape grid of the module docstring)")
    ap.add_argument("--search", action="store_true")
    ap.add_argument("--episodes", type=int, default=1024)
    a = ap.parse_args()
    if a.search:
        g = dict(patience=[6.0, 10.0, 14.0], margin=[0.002, 0.005, 0.01])
        for h, s in search(g, episodes=a.episodes)[:15]:
            print(h, {k: round(v, 4) for k, v in s.items()})
