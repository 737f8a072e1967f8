"""Physics-informed controller (algo "physics"): estimate the delay offsets by fitting the
differentiable simulator to what the detector shows, then step straight to the nearest optimum.

State estimation (every control step, batched over B instances, jitted, no learning):
- Measured vector y = [2 P/Pmax - 1, 2 I_m/I_peak - 1 (m = 1..2^N-1)], the observation's power
  and oscilloscope entries (latest frame). The model f(x) is the same map through
  ``ops_jax.physics.measure(x, model="phasor")`` for offsets x (wl).
- Unknowns: the offsets of the interferometric stages, modulo the wl/2 period (all N stages with
  detector "polariser"; stages 1..N-1 with "total", whose last stage's carrier phase is invisible:
  P does not depend on it, so the controller leaves it alone).
- Residual r(z) = [f(z) - y_t, w_hist (f(z - dx_{t-1}) - y_{t-1})], where dx_{t-1} is the move the
  controller itself commanded before y_t (carried). The second block resolves the ambiguities of a
  single snapshot (the intensity pattern is nearly invariant under x -> -x): no probe is needed, so
  the controller makes 1 measurement per step.
- Gauss-Newton / Levenberg-Marquardt from ``starts`` random points on the period torus plus the
  tracked prediction (last estimate + last move), ``iters`` iterations each (Jacobian by jacfwd);
  the start with the lowest residual wins.

Control: a = clip(-gain * wrap(z) / action_scale, -1, 1) on the fitted stages, 0 elsewhere
(``wrap`` maps to the nearest optimum, [-wl/4, wl/4)).

The length channel: the observation also holds the (noisy, normalised) delay-line lengths
x / window, which reveal the offsets directly (obs noise 1e-4 -> 3e-4 wl). ``use_lengths=True``
adds them as one more start of the fit (and, with ``lengths_only=True``, the controller just reads
them: legitimate but trivial, and useless when the channel is noisy or absent). The default
``use_lengths=False`` never looks at them: it is the physics-informed controller proper.
``drift_gain`` > 0 integrates the prediction innovation into a drift estimate (wl/step) that is
added to the prediction and pre-compensated in the action (off by default: it slows the approach at
feedback_k = 1 and helps only at long feedback delays).

Measured scores and costs: docs/results.md (the physics-informed controller).
"""

from __future__ import annotations


import jax
import jax.numpy as jnp
import numpy as np

import ops_jax
from ops_jax import physics
from agents.base import Policy, TrainResult, check_env_config, evaluated_result
from agents.config import PhysicsConfig

def params_template(env_config, hyper):
    del env_config, hyper
    return {"action_scale": np.float32(0), "window": np.float32(0)}


def policy_params(env_config: dict) -> dict:
    """The controller's numbers from its environment: ``action_scale`` (wl per action unit) and
    ``window`` (wl, the observation's length normalisation). Parameters, not constants of the
    program, so one compiled policy serves every mode (make_policy reads only the static config)."""
    _, env_params = ops_jax.make(**check_env_config(env_config))
    return {"action_scale": np.float32(env_params.action_scale), "window": np.float32(env_params.window)}


def wrap(x):
    """Offset from the nearest optimum (period wl/2), in [-0.25, 0.25) wl."""
    return x - 0.5 * jnp.round(x / 0.5)


def make_policy(env_config: dict, hyper: dict | PhysicsConfig | None = None) -> Policy:
    """The physics-informed policy; ``params``: ``policy_params(...)`` (None: those of ``env_config``)."""
    env_config = check_env_config(env_config)
    h = (hyper if isinstance(hyper, PhysicsConfig) else PhysicsConfig.from_hyper(hyper)).to_hyper()
    env, _ = ops_jax.make(**env_config)
    cfg = env.config
    n = cfg.stages
    frame = env.frame_size
    ny = 2**n  # P and the 2^n - 1 samples
    fit = n if cfg.detector == "polariser" else n - 1  # fitted (interferometric) stages
    default = policy_params(env_config)
    p_max = physics.p_max(n, cfg.detector)
    peak = physics.peak_intensity(n)

    def model(z):  # z (fit,) -> y (ny,)
        x = jnp.concatenate([z, jnp.zeros((n - fit,), z.dtype)])
        m = physics.measure(x, stages=n, model="phasor", detector=cfg.detector)
        return jnp.concatenate([(2 * m.power / p_max - 1)[None], 2 * m.samples / peak - 1])

    def residual(z, y, y_prev, dz_prev, w):
        return jnp.concatenate([model(z) - y, w * (model(z - dz_prev) - y_prev)])

    def lm(z, y, y_prev, dz_prev, w):
        def body(z, _):
            r = residual(z, y, y_prev, dz_prev, w)
            J = jax.jacfwd(residual)(z, y, y_prev, dz_prev, w)
            A = J.T @ J
            A = A + h["damping"] * (jnp.diag(jnp.diag(A)) + 1e-6 * jnp.eye(fit))
            step = -jnp.linalg.solve(A, J.T @ r)
            return z + jnp.clip(step, -0.05, 0.05), None

        z, _ = jax.lax.scan(body, z, None, length=h["iters"])
        r = residual(z, y, y_prev, dz_prev, w)
        return wrap(z), jnp.sum(r**2)

    def estimate_one(key, y, y_prev, dz_prev, w, z_pred, z_len):
        cands = [z_pred[None]]
        if h["starts"]:
            cands.append(jax.random.uniform(key, (h["starts"], fit), minval=-0.25, maxval=0.25))
        if h["use_lengths"]:
            cands.append(z_len[None])
        cands = jnp.concatenate(cands)
        zs, cost = jax.vmap(lm, in_axes=(0, None, None, None, None))(cands, y, y_prev, dz_prev, w)
        return zs[jnp.argmin(cost)]

    def init(key, obs):
        del key
        b = obs.shape[0]
        return {"y_prev": jnp.zeros((b, ny), jnp.float32), "dz_prev": jnp.zeros((b, fit), jnp.float32),
                "z": jnp.zeros((b, fit), jnp.float32), "v": jnp.zeros((b, fit), jnp.float32),
                "valid": jnp.zeros((b,), jnp.float32)}

    def act(params, carry, obs, key, probe):
        del probe
        p = default if params is None else params
        scale, window = p["action_scale"], p["window"]
        b = obs.shape[0]
        last = obs[:, obs.shape[1] - frame:]
        y = last[:, :ny]
        x_len = last[:, ny:ny + n] * window
        valid = carry["valid"][:, None]
        move = carry["dz_prev"] + carry["v"]  # commanded move + estimated drift since y_prev
        z_pred = wrap(carry["z"] + move)
        if h["lengths_only"] or fit == 0:
            z = wrap(x_len[:, :fit])
        else:
            w = h["w_hist"] * carry["valid"]
            keys = jax.random.split(key, b)
            z = jax.vmap(estimate_one)(keys, y, carry["y_prev"], move, w, z_pred, wrap(x_len[:, :fit]))
        # Drift (free-running mean, wl per step): integrate the innovation of the prediction.
        v = carry["v"] + h["drift_gain"] * valid * wrap(z - z_pred)
        a_fit = jnp.clip(-(h["gain"] * z + v) / scale, -1.0, 1.0)
        action = jnp.concatenate([a_fit, jnp.zeros((b, n - fit), jnp.float32)], axis=1)
        dz = a_fit * scale
        return action, {"y_prev": y, "dz_prev": dz, "z": z, "v": v, "valid": jnp.ones((b,), jnp.float32)}

    return Policy(init, act)


def train(env_config: dict, *, seed: int = 0, total_steps: int | None = None, progress_fn=None,
          curve_episodes: int = 32, config: PhysicsConfig | str | None = None, **hyper) -> TrainResult:
    """Nothing to learn (the model is the simulator): validates; the curve is
    ``agents.evaluate(result, env_config, episodes=curve_episodes, seed=seed)`` (served from memory
    when asked for again), reported once to ``progress_fn(0, metrics)``. ``total_steps`` is ignored."""
    env_config = check_env_config(env_config)
    h = PhysicsConfig.make(config, **hyper).to_hyper()
    return evaluated_result("physics", env_config, h, policy_params(env_config), seed, curve_episodes, progress_fn)
