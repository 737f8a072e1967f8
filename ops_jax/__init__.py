"""ops-jax: a JAX-vectorised simulator of optical pulse stacking (OPS) for control and RL.

``import ops_jax`` pulls in jax, numpy and Gymnasium (it registers the "ops_jax/OPS-v0"
environments); the Brax adapter, the agents and rendering import their own dependencies when used.
"""

from ops_jax.cli import extras

# first: a Ctrl-C or a missing extra while the rest imports is one line too
extras.install_excepthook()

from ops_jax import noise, physics  # noqa: E402
from ops_jax.env import MODES, REWARDS, OPSEnv, make  # noqa: E402
from ops_jax.records import EnvConfig, EnvParams, EnvState  # noqa: E402
from ops_jax.trajectories import Rollout, rollout  # noqa: E402
from ops_jax.spec import EnvSpec  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "MODES",
    "REWARDS",
    "EnvConfig",
    "EnvParams",
    "EnvSpec",
    "EnvState",
    "OPSEnv",
    "Rollout",
    "make",
    "noise",
    "physics",
    "rollout",
]


def _register_gymnasium() -> None:
    """Register "ops_jax/OPS-v0" with Gymnasium (a light dependency; brax/matplotlib not
    imported)."""
    from ops_jax.adapters.gymnasium.env import register

    register()


_register_gymnasium()
