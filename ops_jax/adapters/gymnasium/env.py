"""Gymnasium adapters: ``OPSGymEnv`` (one instance) and ``OPSVectorEnv`` (a batch, one jitted call
per step), registered as ``"ops_jax/OPS-v0"`` by ``import ops_jax``::

    env = gymnasium.make("ops_jax/OPS-v0", stages=5, mode="hard", render_mode="rgb_array")
    envs = gymnasium.make_vec(
        "ops_jax/OPS-v0", num_envs=1024, vectorization_mode="vector_entry_point"
    )

Keywords: ``stages``, ``mode`` and every ``ops_jax.make`` option (``model``, ``reward``,
``max_steps``, ``obs_noise``, ...), plus ``render_mode`` and ``device`` (the JAX device the state
lives on: "cpu" by default for the single instance, whose per-step cost is dispatch-bound; the
default backend for the vector env).

Semantics (both adapters):
- observation: the ``OPSEnv`` observation (float32 NumPy), in a finite ``Box`` whose bounds are
  derived from the parameters (10 std of observation noise as margin); action: ``Box(-1, 1, (N,))``
  float32 (0.01 wl per unit by default).
- reward: the configured reward (``"paper"``: in [-1, 0]); ``terminated`` when a delay leaves the
  +-window; ``truncated`` after ``max_steps`` (the environment truncates itself, so the registered
  spec has no ``TimeLimit``; ``env.unwrapped.max_episode_steps`` is ``max_steps``).
- info: ``power``, ``normalized_power`` (P / P_max), ``normalized_power_best`` (P / P_best: the best
  P reachable with the configured static imperfections; P / P_max without them), ``deltas_wl`` (N,),
  ``action_nonfinite``.
- randomness: ``reset(seed=s)`` seeds ``np_random`` and restarts the episode counter (hard mode's
  drift ramps with it); the JAX key of the episode is drawn from ``np_random``. ``reset(options=
  {"episode": k})`` starts as the k-th episode (k >= 10: hard mode's drift fully on).
- JAX starts at the first ``reset`` (construction only validates and builds the spaces), so
  Gymnasium's ``"async"`` mode may fork its workers after building one env for the spaces. An
  adapter constructed in a process forked after JAX started (JAX is multithreaded: it would
  deadlock) raises ``RuntimeError`` at once, naming the fixes (``vectorization_mode=
  "vector_entry_point"``, or ``vector_kwargs={"context": "forkserver"}``).
- ``copy.deepcopy`` and ``pickle`` copy a live adapter (options, parameters, state, JAX key,
  ``np_random``, episode counter); the copy looks its jitted functions up again.
- the vector env auto-resets in the same step (``AutoresetMode.SAME_STEP``): the returned obs of a
  finished instance is its next episode's first; ``infos["final_obs"]`` (object array, ``None``
  where not finished) and ``infos["final_info"]`` hold the finished episode's last observation and
  info.
"""

import gymnasium

from ops_jax.adapters.gymnasium.devices import FORK_ERROR
from ops_jax.adapters.gymnasium.shared import ENV_ID
from ops_jax.adapters.gymnasium.single import OPSGymEnv
from ops_jax.adapters.gymnasium.vector import OPSVectorEnv

__all__ = ["ENV_ID", "FORK_ERROR", "OPSGymEnv", "OPSVectorEnv", "register"]


def register() -> None:
    """Register ``"ops_jax/OPS-v0"`` (entry point and vector entry point) with Gymnasium;
    idempotent."""
    if ENV_ID in gymnasium.registry:
        return
    gymnasium.register(
        id=ENV_ID,
        entry_point="ops_jax.adapters.gymnasium.env:OPSGymEnv",
        vector_entry_point="ops_jax.adapters.gymnasium.env:OPSVectorEnv",
        max_episode_steps=None,  # the environment truncates itself after its own max_steps
    )
