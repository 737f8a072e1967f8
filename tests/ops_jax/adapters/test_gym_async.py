"""Gymnasium's async vector mode under each start method, each in its own Python process under a
watchdog: it steps, or (forked after JAX started in the parent) fails at once naming the fixes."""

import subprocess
import sys
import textwrap

import pytest

from ops_jax.adapters.gymnasium.env import FORK_ERROR

WATCHDOG_S = 240  # a hang fails the test here instead of stalling the suite

SCRIPT = textwrap.dedent("""
    import sys
    import gymnasium
    import numpy as np
    import ops_jax

    if __name__ == "__main__":
        context, jax_first = sys.argv[1], sys.argv[2] == "1"
        if jax_first:  # JAX running in the parent before the workers fork
            gymnasium.make("ops_jax/OPS-v0", stages=2, mode="easy", model="phasor").reset(seed=0)
        vector_kwargs = {} if context == "default" else {"context": context}
        envs = gymnasium.make_vec("ops_jax/OPS-v0", num_envs=2, stages=2, mode="easy",
                                  model="phasor", vectorization_mode="async",
                                  vector_kwargs=vector_kwargs)
        obs, _ = envs.reset(seed=0)
        for _ in range(2):
            obs, reward, *_ = envs.step(np.zeros((2, 2), np.float32))
        assert obs.shape == (2, 6) and np.all(np.isfinite(reward))
        envs.close()
        print("STEPPED")
""")


def _run(tmp_path, context: str, jax_first: bool):
    script = tmp_path / "async_vector.py"
    script.write_text(SCRIPT)
    try:
        return subprocess.run(
            [sys.executable, str(script), context, str(int(jax_first))],
            capture_output=True,
            text=True,
            timeout=WATCHDOG_S,
        )
    except subprocess.TimeoutExpired as exc:
        pytest.fail(
            f"async vector env (context={context}, JAX first={jax_first}) hung for {WATCHDOG_S} s: "
            f"{(exc.stderr or b'')[-2000:]!r}"
        )


@pytest.mark.parametrize("context", ["fork", "spawn", "forkserver"])
def test_async_steps_under_each_start_method(tmp_path, context):
    """Out of the box: the parent builds one env for the spaces without starting JAX, so even fork
    (Linux's default before Python 3.14) works."""
    out = _run(tmp_path, context, jax_first=False)
    assert out.returncode == 0 and "STEPPED" in out.stdout, out.stderr[-3000:]


@pytest.mark.parametrize("context, steps", [("fork", False), ("forkserver", True)])
def test_async_after_jax_started_fails_at_once_or_steps(tmp_path, context, steps):
    """JAX already running in the parent: fork refuses at once with the fixes; forkserver steps."""
    out = _run(tmp_path, context, jax_first=True)
    if steps:
        assert out.returncode == 0 and "STEPPED" in out.stdout, out.stderr[-3000:]
    else:
        assert out.returncode != 0 and "STEPPED" not in out.stdout
        assert FORK_ERROR in out.stderr
        assert 'vectorization_mode="vector_entry_point"' in FORK_ERROR
        assert 'vector_kwargs={"context": "forkserver"}' in FORK_ERROR
