"""The actor of a learner on a bench: the ``agents.bench.controller.Controller`` the control loop's
thread drives (``Actor``), and what it and the learner's thread pass each other (``Handover``)."""

from __future__ import annotations

import collections
import threading

import numpy as np

from agents.bench.controller import Controller
from agents.bench.learning.programs import Built, Programs


class Handover:
    """Between the loop's thread and the learner's: the steps queued for the learner (each the
    observation and the previous (observation, action), None at an invocation's first), the newest
    actor network with whether it still explores uniformly (swapped under a lock), the learner's
    wake-up."""

    def __init__(self):
        self.steps: collections.deque = collections.deque()
        self.wake = threading.Event()
        self._lock = threading.Lock()
        self._snapshot = None

    def hand(self, obs, prev) -> None:
        """A step for the learner; wakes it."""
        self.steps.append((obs, prev))
        self.wake.set()

    def publish(self, snapshot, random) -> None:
        """The actor's next network (``random``: a bool, explore uniformly)."""
        with self._lock:
            self._snapshot = (snapshot, random)

    def newest(self) -> tuple:
        """(the newest network handed over, whether it explores uniformly)."""
        with self._lock:
            return self._snapshot


class Actor(Controller):
    """A learner's actor for the loop's thread: no probes; each step's move is the exploration
    action of the newest network handed over (with the fit-residual observer, added to the fit's
    own move), its step handed to the learner. ``t``: the env step its draws are keyed by."""

    probes = 0

    def __init__(self, parts: Built, programs: Programs, handover: Handover):
        self.env, self.parts, self.programs, self.handover = parts.env, parts, programs, handover
        self.prev = None  # (observation, action) of the last step, None before an invocation's
        self.t = 0
        self.seen = None  # the observer's carry (None without one)

    def begin(self, env_steps: int) -> None:
        """An invocation starts after ``env_steps`` env steps (its draws keyed from there)."""
        self.prev, self.t = None, env_steps

    def start(self, obs) -> None:
        """An invocation's first frame: no transition before it (and the observer's fit without
        history)."""
        self.prev = None
        if self.parts.observer is not None:
            self.seen = self.programs.init_seen(np.asarray(obs, np.float32)[None])

    def offsets(self, obs, results, i: int) -> None:
        """The actor makes no probes (``probes`` 0): never asked."""
        raise IndexError(f"a learner's actor makes no probes, asked for probe {i}")

    def act(self, obs, results) -> np.ndarray:
        """The move sent (N,) in [-1, 1] at ``obs``: the exploration action (with the fit-residual
        observer, added to the fit's own move); the step (with the learner's action) handed to the
        learner."""
        del results
        obs = np.asarray(obs, np.float32)
        snap, random = self.handover.newest()
        if self.parts.observer is None:
            action = sent = np.asarray(self.programs.act(snap, np.int32(self.t), obs, random))
        else:
            obs, action, sent, self.seen = self.programs.act(
                self.seen, obs, np.int32(self.t), snap, random
            )
            obs, action = np.asarray(obs), np.asarray(action)
        self.handover.hand(obs, self.prev)
        self.prev, self.t = (obs, action), self.t + 1
        return np.asarray(sent, np.float64)

    def tell(self, action) -> bool:
        """The move (N,) really sent where the bench's limits cut this step's: the step stored with
        it where the learner's action is the move (no observer, or ``fit``; ``fit-residual`` keeps
        its correction), and the fit told it (``Policy.sent``)."""
        done = np.asarray(action, np.float32)
        if self.parts.observer is None or self.parts.config.observer == "fit":
            self.prev = (self.prev[0], done)
        if self.parts.observer is not None:
            self.seen = self.programs.moved(self.seen, done)
        return True
