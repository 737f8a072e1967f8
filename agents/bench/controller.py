"""The controller protocol of the bench: what the control loop (``agents.bench.loop.Loop``) drives,
a frozen controller (``agents.bench.frozen.Agent``) or an online learner's actor
(``agents.bench.learning.actor.Actor``).

Per run the loop calls ``start`` with the first observation, then per control step ``offsets`` for
each of the ``probes`` probes in turn (their results filled in as they are measured), ``act`` for
the step's action and, where the bench's safety limits cut that action, ``tell`` with the one
really sent. Observations follow the layout of ``env`` (the simulator environment the controller is
built for); actions are (N,) in [-1, 1], offsets (N,) in wavelengths.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Controller(Protocol):
    """A controller on one bench instance (B = 1), driven by the control loop's thread."""

    env: Any  # the ops_jax environment whose observation layout the loop encodes the frames in
    probes: int  # probes per control step (0: none, ``offsets`` is never called)

    def start(self, obs: np.ndarray) -> None:
        """The controller's state from the run's first observation (D,)."""
        ...

    def offsets(self, obs: np.ndarray, results: np.ndarray, i: int) -> np.ndarray | None:
        """Probe ``i``'s offsets (N,) wl given the results of probes 0..i-1; None: left out."""
        ...

    def act(self, obs: np.ndarray, results: np.ndarray) -> np.ndarray:
        """The step's action (N,) in [-1, 1] at ``obs`` with the probes' ``results`` (K,)."""
        ...

    def tell(self, action: np.ndarray) -> bool:
        """The action (N,) really sent where the safety limits cut the step's; False: not read."""
        ...
