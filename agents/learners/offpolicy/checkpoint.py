"""Checkpoints of an off-policy run while it trains
(``agents.learners.offpolicy.driver.train_seeds``'s ``checkpoints``), and a run continued from one.

The folder (``Checkpoints.folder``, e.g. ``runs/td3/checkpoint``) is an ``agents.save`` checkpoint
of the policy trained so far (``agents.load`` reads it) plus ``training.npz`` (every leaf of the
training state between two training chunks: networks, targets, optimiser states, replay buffer,
environment states, PRNG keys, gradient step count; and the curve so far) and ``training.json`` (the
run's learner, env_config, hyperparameters and seeds, env steps and chunks done, seconds by part).
It is written every ``every`` env steps, rounded up to whole chunks, and when SIGINT or SIGTERM asks
the run to stop (at the end of the current chunk), into a temporary folder then renamed into place
(``agents.io.replace_dir``): a kill leaves the last whole one.

A call of ``train_seeds`` with the same learner, env_config, hyperparameters (``total_steps``
included) and seeds continues the stored run from it: the same chunks, so it ends with the same env
steps, curve and parameters as the run that was never stopped (bitwise on the same host and JAX
version; only the wall times differ).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import threading
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agents import api as base
from agents.io import kept_dir, replace_dir, temp_dir, write_json_atomic
from ops_jax.cli.progress import stop_signals

EVERY = 10_000  # env steps between two checkpoints (default)
STATE, META = "training.npz", "training.json"
FORMAT = 1
CURVE = ("step", "normalized_power", "final_normalized_power", "critic_loss", "actor_loss")


class Stopped(KeyboardInterrupt):
    """The run stopped on a signal (``signum``) after writing its checkpoint at env step
    ``step``."""

    def __init__(self, signum: int, step: int):
        super().__init__(f"stopped by signal {signum} at env step {step}, checkpoint written")
        self.signum, self.step = signum, step


@dataclasses.dataclass
class Run:
    """A run between two training chunks: the seed-batched training state ``ts``, env steps trained,
    training chunks done, the curve so far (``CURVE`` names -> one entry per point: the step, or
    per-seed arrays), seconds by part (``timing``) and the warm-up's simulation seconds per
    iteration."""

    ts: Any
    step: int
    chunks: int
    curve: dict
    timing: dict
    sim_per_iter: float


def is_key(x) -> bool:
    return jnp.issubdtype(x.dtype, jax.dtypes.prng_key)


def raw_keys(tree):
    """``tree`` with its PRNG keys as their raw data (serialisable)."""
    return jax.tree.map(lambda x: jax.random.key_data(x) if is_key(x) else x, tree)


def identity(algo: str, env_config: dict, hyper: dict, seeds) -> dict:
    """What a continued run must share with the stored one, in its stored (JSON) form."""
    return json.loads(
        json.dumps(
            dict(algo=algo, env_config=env_config, hyper=hyper, seeds=list(seeds)), default=float
        )
    )


def stored_meta(folder: Path) -> dict | None:
    """``training.json`` of the checkpoint in ``folder`` (or the ``.old`` one a kill left), None
    without one."""
    kept = kept_dir(folder)
    if kept is None or not (kept / META).exists() or not (kept / STATE).exists():
        return None
    try:
        return json.loads((kept / META).read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"the training state in {kept} cannot be read: {exc!r}") from exc


def differences(stored: dict, wanted: dict) -> list[str]:
    """Each setting in which ``wanted`` differs from ``stored`` (both ``identity``), with both
    values."""
    diffs = []
    for part, value in wanted.items():
        was = stored.get(part)
        if isinstance(value, dict) and isinstance(was, dict):
            diffs += [
                f"{part}.{k} (stored {was.get(k)!r}, now {value.get(k)!r})"
                for k in sorted({*value, *was})
                if value.get(k) != was.get(k)
            ]
        elif value != was:
            diffs.append(f"{part} (stored {was!r}, now {value!r})")
    return diffs


def check_fits(folder: Path, wanted: dict) -> dict | None:
    """The stored ``training.json`` in ``folder`` (None without one); ValueError naming each setting
    in which ``wanted`` (``identity``) differs from it."""
    meta = stored_meta(folder)
    if meta is None:
        return None
    diffs = differences(meta.get("run", {}), wanted)
    if diffs or meta.get("format") != FORMAT:
        raise ValueError(
            f"the training state in {folder} is of another run: {'; '.join(diffs) or 'its format'}"
        )
    return meta


class Checkpoints:
    """Where and how often a run checkpoints (module docstring); ``saved_step``: the env steps of
    the checkpoint on disk (restored or written by this run), None before one; ``stop_signal``: the
    signal that asked the run to stop, None before one."""

    def __init__(self, folder, every: int = EVERY):
        if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
            raise ValueError(f"checkpoint every must be an integer >= 1 env step, got {every!r}")
        self.folder, self.every = Path(folder), int(every)
        self.saved_step, self.stop_signal = None, None

    def due(self, step: int) -> bool:
        """Whether a checkpoint is due at env step ``step`` (``every`` steps or more since the last
        one)."""
        return step - (self.saved_step or 0) >= self.every

    def restore(self, template, wanted: dict) -> Run | None:
        """The stored run in the structure of the fresh training state ``template``, or None without
        one."""
        for stale in self.folder.parent.glob(
            f"{self.folder.name}.*.tmp"
        ):  # what a kill left half-written
            shutil.rmtree(stale, ignore_errors=True)
        meta = check_fits(self.folder, wanted)
        if meta is None:
            return None
        kept = kept_dir(self.folder)
        leaves, treedef = jax.tree.flatten(template)
        try:
            with np.load(kept / STATE) as saved:
                stored = [saved[f"leaf{i}"] for i in range(len(leaves))]
                curve = {k: list(saved[f"curve_{k}"]) for k in CURVE}
        except (OSError, ValueError, KeyError) as exc:
            raise ValueError(f"the training state in {kept} cannot be read: {exc!r}") from exc
        restored = []
        for fresh, value in zip(leaves, stored):
            shape = jax.random.key_data(fresh).shape if is_key(fresh) else fresh.shape
            if value.shape != shape:
                raise ValueError(f"the training state in {kept} does not fit this run's networks")
            restored.append(
                jax.random.wrap_key_data(value)
                if is_key(fresh)
                else jnp.asarray(value, fresh.dtype)
            )
        self.saved_step = meta["step"]
        return Run(
            jax.tree.unflatten(treedef, restored),
            meta["step"],
            meta["chunks"],
            {k: [int(v) for v in curve[k]] if k == "step" else curve[k] for k in CURVE},
            meta["timing"],
            meta["sim_per_iter"],
        )

    def write(self, run: Run, wanted: dict, result: base.TrainResult) -> None:
        """Write the checkpoint of ``run`` (its policy: ``result``) in place of the last one."""
        leaves = jax.tree.leaves(jax.device_get(raw_keys(run.ts)))
        arrays = {f"leaf{i}": np.asarray(x) for i, x in enumerate(leaves)}
        arrays.update({f"curve_{k}": np.asarray(run.curve[k]) for k in CURVE})
        staging = temp_dir(self.folder.parent, self.folder.name)
        base.save(staging, result)
        with open(staging / STATE, "wb") as f:
            np.savez(f, **arrays)
        meta = dict(format=FORMAT, run=wanted, step=run.step, chunks=run.chunks)
        write_json_atomic(
            staging / META, dict(meta, timing=run.timing, sim_per_iter=run.sim_per_iter)
        )
        replace_dir(staging, self.folder)
        self.saved_step = run.step

    @contextlib.contextmanager
    def stop_requests(self):
        """While the run trains (in the main thread): SIGINT or SIGTERM asks it to stop at the end
        of the current chunk (``stop_signal``; a line on stderr says so), a second one raises
        KeyboardInterrupt at once. The previous handlers are restored after."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return

        def ask(signum, frame):
            if self.stop_signal is not None:
                raise KeyboardInterrupt
            self.stop_signal = signum
            os.write(
                2,
                b"\nstopping at the end of the current chunk, with a checkpoint (again: at once)\n",
            )

        with stop_signals(ask):
            yield
