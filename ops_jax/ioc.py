"""The simulator served as an EPICS Channel Access IOC (caproto): one OPS instance in wall-clock
time.

    python -m ops_jax.ioc --prefix OPS: --stages 5 --mode hard --imperfections lab --rate 100

Every ``ops_jax.make`` option is accepted as ``--option value`` (underscores or dashes; tuples as
Python literals, e.g. ``--waveplate-error-deg "(0.3, -0.2, 0.4, -0.3, 0.2)"``). At every tick of
``--rate`` Hz the simulation advances one control step whether or not a setpoint changed: vibration,
drift and pulse noise go on, so a slow controller pays for its latency as on a bench. A tick applies
the setpoints present at its start; a line moves at most ``--action-scale`` wl per tick towards its
setpoint (default here 1 wl: a piezo settles within a tick; the option is the lines' slew limit). A
tick that starts late is counted in ``OVERRUNS``; ticks missed by a stall are run back to back, so
the simulated time stays the wall-clock time. ``--lockstep`` instead
advances one tick per write to ``ADVANCE`` (reproducible runs, tests).

PVs (prefix first; lengths in wavelengths, wl):

- ``LINE{i}:SP`` (i = 1..N, writable): the commanded position of delay line i since start-up, within
  the actuator's span (writes outside it or non-finite are refused).
- ``LINE{i}:RBV``: where the line is, through the actuator model (gain, backlash, lag, DAC).
- ``LINE{i}:LEN``: the length readout: the line's offset from the optimum as its calibrated sensor
  reports it (the environment's observed length); not served with ``--observe-lengths False``.
- ``DET:POWER``: the detector reading in units of P_max; ``SCOPE:TRACE``: the 2^N - 1 oscilloscope
  samples in units of the ideal pulse peak (both as the detector reads them, with observation
  noise).
- ``EVAL:P_PMAX``, ``EVAL:P_PBEST``: the true P / P_max and P / P_best, for evaluation only.
- ``TICK`` (published last in a tick: a new value means a complete new frame), ``STATUS``,
  ``OVERRUNS``, ``RATE`` (Hz; 0 in lockstep), ``ADVANCE`` (lockstep only).
- ``RESET``: a non-zero write starts again: setpoints to 0, the lines' offsets from the optimum
  drawn afresh as at start-up (the k-th reset's key folded by k, the same ``--drift-episode``); the
  tick count goes on.

Every PV of a tick carries the tick's start as its time stamp: the moment its setpoints were read,
so a frame stamped after a setpoint write shows that write once the write has reached the IOC.
``--tick-log FILE`` appends one JSON line per tick, ``{"tick": t, "stamp": s, "setpoints": [...]}``
(the time stamp, time.time() s, and the setpoints the tick applied, wl): what a client's frames can
be checked against. Every 1,000 ticks the IOC prints one line of their host time (the simulator
step, then the PV writes: median and 99th percentile, ms) and the overruns so far.

Random draws follow ``agents.evaluate``'s episode 0 for ``--seed``: ``reset`` as the
``--drift-episode``-th episode (hard mode's drift fully on by default), step t with the key folded
by t. The IOC listens on 127.0.0.1 unless ``--interface`` is given; port and search settings follow
the standard ``EPICS_CA_*`` environment variables.
"""

from __future__ import annotations

import argparse
import ast
import math
import sys

import jax
import jax.numpy as jnp
import numpy as np

import ops_jax
from ops_jax.cli import runtime
from ops_jax.cli.parser import ArgumentParser
from ops_jax.cli.progress import exit_interrupted, keep_ctrl_c
from ops_jax.env import option_names
from ops_jax.adapters.gymnasium.codec import FlatCodec

# the PV group's and the server's names, as benchmarks.lab and the tests import them
from ops_jax.ioc_group import STATUS_OK, STATUS_OUTSIDE, TICK_REPORT, pv_group  # noqa: F401
from ops_jax.ioc_server import (  # noqa: F401
    BATCH_WINDOW_ENV,
    batch_window,
    ephemeral_ports,
    port_warning,
    serve,
    set_batch_window,
)


def _literal(text: str):
    """A command-line value as a Python literal (numbers, booleans, tuples), else the string."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def parser() -> argparse.ArgumentParser:
    """The IOC's options: its own, then ``stages``, ``mode`` and every ``ops_jax.make`` option."""
    ap = ArgumentParser(prog="python -m ops_jax.ioc", description=__doc__.split("\n")[0])
    ap.add_argument("--prefix", default="OPS:", help="PV name prefix (default OPS:)")
    ap.add_argument("--rate", type=float, default=100.0, help="ticks per second (Hz, default 100)")
    ap.add_argument(
        "--lockstep", action="store_true", help="advance one tick per write to ADVANCE instead"
    )
    ap.add_argument("--seed", type=int, default=0, help="seed of the simulated run")
    ap.add_argument(
        "--drift-episode", type=int, default=10, help="the reset's episode count (hard-mode drift)"
    )
    ap.add_argument(
        "--interface", default="127.0.0.1", help="address to serve on (default localhost only)"
    )
    ap.add_argument(
        "--tick-log",
        metavar="FILE",
        help="append each tick's time stamp and applied setpoints to FILE (JSON lines)",
    )
    env = ap.add_argument_group("simulator (ops_jax.make options)")
    env.add_argument("--stages", type=int, default=5)
    env.add_argument("--mode", default="hard")
    for name in option_names():
        env.add_argument(
            f"--{name.replace('_', '-')}", dest=name, type=_literal, default=None, metavar="VALUE"
        )
    return ap


def make_options(args: argparse.Namespace) -> dict:
    """The ``ops_jax.make`` keyword options given on the command line (``action_scale``, the largest
    move per tick, 1 wl unless given)."""
    return {
        "action_scale": 1.0,
        **{k: getattr(args, k) for k in option_names() if getattr(args, k) is not None},
    }


class Bench:
    """One simulated instance: the jitted single-instance step and its wall-clock state (host side).
    The state is kept as one float32 vector and a tick's outputs come back as another
    (``gym_codec``): one argument in and one copy out per tick instead of one per leaf."""

    def __init__(
        self, stages: int, mode: str, options: dict, seed: int = 0, drift_episode: int = 10
    ):
        self.env, self.params = ops_jax.make(stages, mode, **options)
        self.n = self.env.num_actions
        self.scale = float(self.params.action_scale)
        self.span = (
            float(np.max(self.params.lab.actuator_span_wl))
            if self.env.config.imperfect
            else math.inf
        )
        self._k_reset, _, self._k_run = jax.random.split(jax.random.key(seed), 3)
        reset = jax.jit(self.env.reset, static_argnums=2)
        self._reset = lambda key: reset(key, self.params, drift_episode)
        self._codec = FlatCodec(jax.eval_shape(self._reset, self._k_reset)[1])
        self._pack = jax.jit(self._codec.flatten)
        self._step = jax.jit(self._advance)
        self.t, self.resets = 0, -1
        self.reset()
        # compile once, before serving (the result is discarded: the step is pure)
        jax.block_until_ready(self._step(self._packed, np.zeros(self.n, np.float32), 1))

    def reset(self) -> dict:
        """Start again: the lines drawn afresh as at start-up (the k-th reset folds its key by k),
        the setpoints applied back to 0; the tick count goes on. Returns the new PV values."""
        self.resets += 1
        obs, state = self._reset(jax.random.fold_in(self._k_reset, self.resets))
        self._packed = self._pack(state)
        self.command = np.zeros(self.n)  # what has been applied of the setpoints (wl)
        self.frame = self._decode(
            self.env.layout.latest(np.asarray(obs)),
            np.zeros(self.n),
            *self._true_power(state),
            False,
        )
        return self.frame

    def _true_power(self, state):
        """(P / P_max, P / P_best) of ``state`` as it truly is (the reset's evaluation values)."""
        power = self.env._sense(state.deltas, state.lab)[0].power
        best = float(np.max(self.params.lab.p_best)) if self.env.config.imperfect else 0.0
        return float(power / self.env.p_max), float(power / (best if best > 0 else self.env.p_max))

    def _advance(self, packed, action, t):
        """(packed state, [frame, position (N,) wl, P / P_max, P / P_best, outside]) after step
        ``t``."""
        k_env = jax.random.split(jax.random.fold_in(self._k_run, t - 1))[1]
        state = self._codec.unflatten(packed)
        obs, state, _, terminated, _, info = self.env.step_env(
            jax.random.fold_in(k_env, 0), state, action, self.params
        )
        position = state.lab.position if self.env.config.imperfect else jnp.zeros(self.n)
        out = [
            self.env.layout.latest(obs),
            position,
            info["normalized_power"],
            info["normalized_power_best"],
            terminated,
        ]
        return self._codec.flatten(state), jnp.concatenate(
            [jnp.ravel(jnp.asarray(x, jnp.float32)) for x in out]
        )

    def _decode(self, frame, position, npow, npow_best, outside) -> dict:
        """PV values of one observation frame (float64: the client re-encodes it exactly)."""
        return {
            **self.env.layout.decode(frame, self.params.window),
            "position": np.asarray(position, np.float64),
            "p_pmax": float(npow),
            "p_pbest": float(npow_best),
            "outside": bool(outside),
        }

    def tick(self, setpoints) -> dict:
        """Advance one control step towards ``setpoints`` (N,) wl; returns the new PV values."""
        action = np.clip((np.asarray(setpoints, np.float64) - self.command) / self.scale, -1.0, 1.0)
        action = np.where(np.isfinite(action), action, 0.0)
        self.command = self.command + action * self.scale
        self.t += 1
        self._packed, out = self._step(self._packed, action.astype(np.float32), self.t)
        out = np.asarray(out)
        frame, position, (npow, best, outside) = out[: -self.n - 3], out[-self.n - 3 : -3], out[-3:]
        if not self.env.config.imperfect:
            position = self.command
        self.frame = self._decode(frame, position, npow, best, outside != 0)
        return self.frame


def main(argv=None) -> None:
    """Serve the IOC until Ctrl-C (or SIGINT): then one line, exit status 130, while starting as
    well."""
    keep_ctrl_c()
    ap = parser()
    args = ap.parse_args(argv)
    if not (args.lockstep or (math.isfinite(args.rate) and 0 < args.rate <= 10_000)):
        ap.error(f"--rate must be a number in (0, 10000] Hz, got {args.rate}")
    try:
        group = _start(ap, args)
    except KeyboardInterrupt:
        exit_interrupted("stopped while starting; it served nothing")
    serve(group.pvdb, args.interface, group.start)  # returns on Ctrl-C
    exit_interrupted(f"the IOC {args.prefix} stopped; its PVs are gone")


def _start(ap, args):
    """The PV group of the IOC ``args`` describe: its simulator built and compiled, the server
    tuned."""
    runtime.start_single_threaded()  # a tick is one small call
    try:
        bench = Bench(
            args.stages,
            args.mode,
            make_options(args),
            seed=args.seed,
            drift_episode=args.drift_episode,
        )
    except (TypeError, ValueError) as exc:
        ap.error(str(exc))
    try:
        tick_log = (
            None if args.tick_log is None else open(args.tick_log, "a", buffering=1)
        )  # a line per write
    except OSError as exc:
        raise SystemExit(f"ops_jax.ioc: --tick-log: {exc}")
    set_batch_window(args.rate)  # before caproto's server is imported
    from caproto import get_environment_variables

    warning = port_warning(int(get_environment_variables()["EPICS_CA_SERVER_PORT"]))
    if warning:
        print(warning, file=sys.stderr, flush=True)
    return pv_group(bench, args.prefix, args.rate, args.lockstep, tick_log)


if __name__ == "__main__":
    main()
