"""The learner's own thread on a bench (``GradientThread``): it stores the transitions the actor
hands over, takes gradient steps one at a time as the wall clock allows (at most the config's ratio
per env step after the warm-up), hands the actor its network every ``PUBLISH_STEPS`` env steps and
checkpoints; ``Invocation`` keeps this invocation's counts and update ratio."""

from __future__ import annotations

import dataclasses
import logging
import threading
import time

import jax
import numpy as np

from agents.bench.learning.actor import Handover
from agents.bench.learning.programs import Built, Programs, acting
from agents.bench.learning.state import Checkpoints, Counts, State
from ops_jax.cli.progress import progress

PUBLISH_STEPS = 10  # env steps between two hand-overs of the actor network
log = logging.getLogger("agents.bench")


class Invocation:
    """This invocation of the run: the counts it started from (``first``), its gradient steps while
    the loop ran (``in_loop_steps``), its (perf_counter time, gradient steps, env steps after the
    warm-up) at each hand-over (``ratio_rec``)."""

    def __init__(self, counts: Counts):
        self.counts, self.first = counts, dataclasses.replace(counts)
        self.in_loop_steps = 0
        self.ratio_rec: list = []

    def since(self, name: str) -> int:
        """The count ``name`` of this invocation."""
        return getattr(self.counts, name) - getattr(self.first, name)

    def update_ratio(self, learn_steps: int | None = None) -> float:
        """This invocation's gradient steps (``learn_steps``, default all so far) per env step after
        the warm-up."""
        steps = self.since("learning_env_steps")
        learn_steps = self.since("learn_steps") if learn_steps is None else learn_steps
        return learn_steps / steps if steps else 0.0

    def mark(self) -> None:
        """A hand-over: its time and counts, for the ratio's series."""
        since = (self.since("learn_steps"), self.since("learning_env_steps"))
        self.ratio_rec.append((time.perf_counter(), *since))


class GradientThread:
    """The learner's thread over ``state`` (which it alone changes while it runs), fed by
    ``handover``; ``error``: the exception it failed with, or None."""

    def __init__(self, parts: Built, programs: Programs, handover: Handover, state, checkpoints):
        self.parts, self.programs, self.handover = parts, programs, handover
        self.state: State = state
        self.checkpoints: Checkpoints = checkpoints
        self.invocation: Invocation | None = None
        self.error: Exception | None = None
        self._thread, self._bar, self._on_error = None, None, None
        self._ending, self._catch_up_s = False, 0.0

    @property
    def learning(self) -> bool:
        """Past the warm-up (``learning_starts`` transitions stored)."""
        return self.state.counts.transitions >= self.parts.config.learning_starts

    def begin(self, steps: int, on_error) -> None:
        """Start the thread for an invocation of ``steps`` env steps; ``on_error(exc)`` if it
        fails."""
        self._on_error, self.invocation = on_error, Invocation(self.state.counts)
        self.checkpoints.restart_clock()
        self.state.counts.sessions += 1
        self._bar = progress(total=steps, desc=f"learning {self.parts.learner.name}", unit="step")
        self._thread = threading.Thread(target=self._run, name="learner", daemon=True)
        self._thread.start()

    def end(self, catch_up_s: float = 0.0) -> None:
        """The loop has stopped: the thread stores what the loop handed over; then, for at most
        ``catch_up_s`` seconds, takes the gradient steps it fell behind the ratio; writes the last
        checkpoint and ends (``finish`` waits for it)."""
        self._catch_up_s, self._ending = catch_up_s, True
        self.handover.wake.set()

    def finish(self) -> None:
        """``end`` (unless called already: without a catch-up), and wait for the thread."""
        if not self._ending:
            self.end()
        self._thread.join()
        self._bar.close()

    def _run(self) -> None:
        steps, wake = self.handover.steps, self.handover.wake
        try:
            while not (self._ending and not steps):
                if steps:
                    self._take(*steps.popleft())
                elif self._may_update():
                    self._update()
                else:
                    wake.wait(0.005)
                    wake.clear()
            self.invocation.in_loop_steps = self.invocation.since("learn_steps")
            deadline = time.perf_counter() + self._catch_up_s
            while self._may_update() and time.perf_counter() < deadline:
                self._update()
            self.checkpoints.write(self.state)
        except Exception as exc:  # the loop stops (on_error), the last checkpoint stays
            self.error = exc
            log.error("the learner failed", exc_info=exc)
            self._on_error(exc)

    def _update(self) -> None:
        """One gradient step."""
        self.state.ts = self.programs.update(self.state.ts)
        jax.block_until_ready(self.state.ts.updates)
        self.state.counts.learn_steps += 1

    def _may_update(self) -> bool:
        done = self.invocation
        ratio = self.parts.ratio * done.since("learning_env_steps")
        return self.learning and done.since("learn_steps") < ratio

    def _take(self, obs, prev) -> None:
        """One env step: its transition stored, the warm-up ended, the actor handed its network, a
        checkpoint."""
        s, c, env = self.state, self.state.counts, self.parts.env
        power = float(env.layout.power(obs[: env.observation_size]))
        if c.p_init < 0:
            c.p_init = power * env.p_max
        if prev is not None:
            s.ts = self.programs.insert(s.ts, prev[0], prev[1], obs, np.float32(c.p_init))
            if s.warm_obs is not None:
                s.warm_obs.append(prev[0])
            c.transitions += 1
            if s.warm_obs is not None and self.learning:
                s.ts, s.warm_obs = self.programs.fit_norm(s.ts, np.stack(s.warm_obs)), None
                self.publish()
        c.learning_env_steps += int(self.learning)
        c.env_steps += 1
        self.checkpoints.read(power)
        self._bar.update(1)
        if c.env_steps % PUBLISH_STEPS == 0:
            self.publish()
        if c.env_steps % self.checkpoints.every == 0:
            self.checkpoints.write(s)

    def publish(self) -> None:
        """Hand the actor a copy of the actor network (and whether it still explores uniformly)."""
        s = self.state
        snap = jax.device_put(jax.tree.map(np.array, acting(s.ts)))
        self.handover.publish(snap, np.bool_(s.warm_obs is not None and not self.learning))
        if self._bar is not None:
            self.invocation.mark()
            c = s.counts
            self._bar.set_postfix_str(
                f"env steps {c.env_steps}, learn steps {c.learn_steps}, "
                f"updates per env step {self.invocation.update_ratio():.2f} of "
                f"{self.parts.ratio:g}"
            )
