"""What both Gymnasium adapters (``ops_jax.adapters.gymnasium.env``) share: their construction, the
observation bound, the reset's key and episode counter, the oscilloscope of ``render()``."""

from __future__ import annotations

import gymnasium
import jax
import numpy as np

from ops_jax import imperfections, noise
from ops_jax.adapters.gymnasium.devices import check_device, refuse_after_fork
from ops_jax.env import make

ENV_ID = "ops_jax/OPS-v0"
RENDER_FPS = 10


def observation_bounds(env, params) -> np.ndarray:
    """Per-entry bound B (obs in [-B, B]) of one frame, from the physics and the noise
    parameters."""
    p = {k: float(np.max(np.asarray(v))) for k, v in vars(params).items() if k != "lab"}
    margin = 10.0 * p["obs_noise"] + 1e-3
    k = env.config.feedback_k
    mu_max = p["drift_cap"] * p["step_sigma"] + p["drift_amplitude"]
    # Largest |offset| seen: a reset ((cap + 2) s0) or the step that leaves the window.
    x_max = max(
        (p["drift_cap"] + 2.0) * p["init_spread"],
        p["window"] + p["action_scale"] + k * (mu_max + 3.0 * p["step_sigma"]),
    )
    signal = 1.0
    if env.config.imperfect:
        signal, x_max = imperfections.observation_bounds(params.lab, x_max)
    layout = env.layout
    bound = np.full(layout.frame_size, signal + margin)  # the detector's entries
    if layout.lengths:
        bound[layout.lengths_slice] = x_max / p["window"] + margin
    if layout.noise:
        bound[layout.noise_slice] = mu_max / noise.REFERENCE_SIGMA_WL + margin
    return np.tile(bound, layout.frame_stack).astype(np.float32)


def reset_key(env, seed, options):
    """The episode counter after ``reset(seed, options)`` set on ``env``, its compiled functions
    started, and the reset's PRNG key drawn from ``env.np_random`` (on ``env.device``)."""
    if seed is not None:
        env._episode = 0
    if options:
        unknown = set(options) - {"episode"}
        if unknown:
            raise ValueError(f"reset options accept only 'episode', got {sorted(unknown)}")
        episode = options["episode"]
        if isinstance(episode, bool) or not isinstance(episode, (int, np.integer)) or episode < 0:
            raise ValueError(f"options['episode'] must be an integer >= 0, got {episode!r}")
        env._episode = int(episode)
    env._start()
    key = jax.random.key(int(env.np_random.integers(0, 2**32, dtype=np.uint64)))
    return key if env.device is None else jax.device_put(key, env.device)


def set_up_adapter(adapter, stages: int, mode: str, render_mode, device, options: dict):
    """What both adapters' constructors set: the environment and its options, render mode, device
    spec, sizes; returns the observation bound."""
    if render_mode is not None and render_mode not in adapter.metadata["render_modes"]:
        raise ValueError(
            f"render_mode must be None or one of {adapter.metadata['render_modes']}, got "
            f"{render_mode!r}"
        )
    adapter.env, adapter.params = make(stages, mode, **options)
    adapter.options = dict(stages=stages, mode=mode, **options)
    adapter.render_mode = render_mode
    adapter._device_spec = check_device(device)
    adapter.device = None  # resolved when JAX starts (first reset)
    adapter._n, adapter._d = adapter.env.num_actions, adapter.env.observation_size
    adapter.max_episode_steps = adapter.env.config.max_steps
    return observation_bounds(adapter.env, adapter.params)


def jax_options(adapter) -> dict:
    """The ``make`` options of a starting adapter's jitted functions (refused in a forked child)."""
    refuse_after_fork()
    return {k: v for k, v in adapter.options.items() if k not in ("stages", "mode")}


def render_scope(adapter, started: bool, scope, modes: str):
    """``(ops_jax.render, oscilloscope)`` for an adapter's ``render()`` (the scope made on first
    use), or ``(None, scope)`` with a warning naming ``modes`` without a render_mode; RuntimeError
    before reset."""
    if adapter.render_mode is None:
        gymnasium.logger.warn(f"render() called without a render_mode; pass render_mode={modes}")
        return None, scope
    if not started:
        raise RuntimeError("call reset() before render()")
    from ops_jax import render as _render

    return _render, scope if scope is not None else _render.Oscilloscope(
        adapter._n, detector=adapter.env.config.detector
    )
