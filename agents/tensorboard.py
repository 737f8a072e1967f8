"""TensorBoard scalars of a training curve: ``TensorBoardLogger(logdir)`` is a ``progress_fn`` that
writes each evaluation's metrics as scalars against env steps (tensorboardX's event-file writer, no
TensorFlow; needs ``pip install -e ".[tensorboard]"``)::

    log = agents.tensorboard.TensorBoardLogger("runs/td3/tb")
    agents.train("td3", env, progress_fn=log); log.close()
    # the same from the command line, then a look at them
    python -m agents --algo td3 --out runs/td3 --logdir runs/td3/tb
    tensorboard --logdir runs

Tags: ``eval/normalized_power`` (evaluation P/Pmax; with imperfections the learners evaluate P/Pmax
too), ``eval/normalized_power_best`` where reported (P/P_best), ``loss/<name>`` for every metric
whose name has "loss" (TD3 and DroQ: actor_loss, critic_loss; brax's PPO and SAC: their training
losses), ``train/update_ratio`` (gradient steps per env step, off-policy learners), ``train/reward``
(mean reward per step), ``time/elapsed_s`` (wall seconds since training started); the x axis (global
step) is env steps.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

from ops_jax.cli import extras


def tag(name: str) -> str:
    """The TensorBoard tag of a ``progress_fn`` metric."""
    if name.startswith("normalized_power"):
        return f"eval/{name}"
    if "loss" in name:
        return f"loss/{name}"
    if name == "elapsed_s":
        return "time/elapsed_s"
    return f"train/{name}"


class TensorBoardLogger:
    """A ``progress_fn(step, metrics)`` writing every finite numeric metric to ``logdir`` at global
    step ``step`` (env steps), flushed at each call; ``then`` (optional) is called after with the
    same arguments."""

    def __init__(self, logdir, then: Callable[[int, dict], None] | None = None):
        try:
            from tensorboardX import SummaryWriter
        except ModuleNotFoundError as e:
            raise ImportError(
                f"TensorBoard logging needs tensorboardX: {extras.install_command('tensorboard')}"
            ) from e
        self.logdir = Path(logdir)
        self.then = then
        self._writer = SummaryWriter(logdir=str(self.logdir))

    def __call__(self, step: int, metrics: dict) -> None:
        for name, value in metrics.items():
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not math.isfinite(value)
            ):
                continue
            self._writer.add_scalar(tag(name), float(value), global_step=int(step))
        self._writer.flush()
        if self.then is not None:
            self.then(step, metrics)

    def close(self) -> None:
        self._writer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
