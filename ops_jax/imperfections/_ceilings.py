"""The ceilings of a bench: P_best (the best P reachable with the static optics imperfections), its
offsets, ``held_power`` (the mean P of lines held there under the vibration, with or without its
prediction) and ``ceilings`` (both of an environment's, as fractions of P_best, cached per
``ops_jax.EnvSpec``)."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ops_jax import optics, physics, vibration
from ops_jax.imperfections._parameters import Imperfections
from ops_jax.imperfections._state import advance, reset, sense


P_BEST_STARTS = 4  # gradient-ascent starts: the ideal optimum and 3 draws within +-0.1 wl
P_BEST_ITERS = 300
CEILING_SAMPLES = 4096  # draws of ``ceilings``' held power
CEILING_SEED = 0  # the seed of ``ceilings``' key


def best_power(config, lab: Imperfections):
    """P_best (shape of lab's batch): max over offsets of P with the static optics imperfections
    (wave plates, leakage; identical pulses, no vibration), by Adam ascent on the differentiable
    model from P_BEST_STARTS starts, never below P at the ideal optimum."""
    batch = np.shape(lab.pbs_leakage)[:-1]
    return np.asarray(_best_power_and_offsets(config, lab)[0]).reshape(batch)


def best_offsets(config, lab: Imperfections):
    """The offsets (..., N) wl where ``best_power`` reaches P_best (the ideal optimum, zeros, where
    nothing beats it)."""
    return np.asarray(_best_power_and_offsets(config, lab)[1]).reshape(
        *np.shape(lab.pbs_leakage)[:-1], config.stages
    )


def _best_power_and_offsets(config, lab: Imperfections):
    """(P_best (B,), its offsets (B, N)) of ``lab``'s instances flattened to a batch B."""
    n = config.stages
    batch = np.shape(lab.pbs_leakage)[:-1]
    rot = jnp.broadcast_to(
        optics.rotation(jnp.asarray(lab.waveplate_error_deg)), (*batch, n)
    ).reshape(-1, n)
    leak = jnp.broadcast_to(jnp.asarray(lab.pbs_leakage), (*batch, n)).reshape(-1, n)
    return _best_power_fn(n, config.model, config.detector)(rot, leak)


def held_power(
    config, lab: Imperfections, key, samples: int = 4096, predict: bool = False
) -> float:
    """Mean P (units of P) with the lines held at the ``best_offsets``, over ``samples`` draws of
    the vibration and the input pulses from their stationary law: the most that a controller can
    hold which follows the drift exactly but not the vibration. ``predict``: the lines held at those
    offsets less the vibration's one-step prediction from its exact past, so that only its new
    innovation is left: the most that a controller can hold which also predicts the vibration
    perfectly. The lines sit where they are put (no actuator errors); the detector plays no part (P
    is the true stacked power). One bench: an unbatched ``lab`` without randomisation."""
    n = config.stages
    if np.shape(lab.pbs_leakage) != (n,):
        raise ValueError(
            f"lab must be one bench (per-stage leaves of shape ({n},)), got "
            f"{np.shape(lab.pbs_leakage)}"
        )
    if float(lab.randomize) or float(lab.randomize_layout):
        raise ValueError(
            "lab must not be randomised (randomize = randomize_layout = 0), got "
            f"randomize={float(lab.randomize)}, randomize_layout={float(lab.randomize_layout)}"
        )
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    offsets = jnp.asarray(best_offsets(config, lab))
    keys = jax.random.split(key, int(samples))
    return float(jnp.mean(_held_power_fn(config, bool(predict))(keys, lab, offsets)))


@functools.lru_cache(maxsize=None)
def _held_power_fn(config, predict):
    """The jitted P (samples,) of held lines over a batch of keys."""
    n = config.stages
    p_max, peak = physics.p_max(n, config.detector), physics.peak_intensity(n)

    def one(key, lab, offsets):
        state = reset(key, n, lab)
        if predict:
            zero = jnp.zeros((n,), jnp.float32)
            ahead = vibration.step(
                state.fir,
                state.osc,
                zero,
                jnp.zeros_like(state.osc[0]),
                lab.vib_alpha,
                lab.vib_rms,
                jnp.asarray(lab.resonance_freq),
                jnp.asarray(lab.resonance_q),
                jnp.asarray(lab.resonance_rms),
            )[2]
            state, _ = advance(jax.random.fold_in(key, 1), state, zero)
            offsets = offsets - ahead
        return sense(config, offsets, state, p_max, peak)[0].power

    return jax.jit(jax.vmap(one, in_axes=(0, None, None)))


@functools.lru_cache(maxsize=None)
def _best_power_fn(n, model, detector):
    """The jitted P_best search over a batch of (rotation, leakage) (B, N): (P_best (B,), its
    offsets (B, N))."""
    p_max = physics.p_max(n, detector)

    def one(rot, leak):
        f = lambda x: (
            optics.measure(
                x, rot, leak, optics.ideal_pulses(n), stages=n, model=model, detector=detector
            ).power
            / p_max
        )
        starts = jnp.concatenate(
            [
                jnp.zeros((1, n)),
                jax.random.uniform(
                    jax.random.key(0), (P_BEST_STARTS - 1, n), minval=-0.1, maxval=0.1
                ),
            ]
        )
        grad = jax.vmap(jax.grad(f))

        def body(carry, i):
            x, m, v = carry
            g = grad(x)
            m = 0.9 * m + 0.1 * g
            v = 0.999 * v + 0.001 * g**2
            lr = 3e-3 * jnp.minimum(1.0, 3.0 * (1 - i / P_BEST_ITERS))
            step = lr * (m / (1 - 0.9 ** (i + 1))) / (jnp.sqrt(v / (1 - 0.999 ** (i + 1))) + 1e-8)
            return (x + step, m, v), None

        zeros = jnp.zeros_like(starts)
        x, _, _ = jax.lax.scan(
            body, (starts, zeros, zeros), jnp.arange(P_BEST_ITERS, dtype=jnp.float32)
        )[0]
        ends = jax.vmap(f)(x)
        best = jnp.argmax(ends)
        beats_ideal = ends[best] > f(starts[0])
        return jnp.where(beats_ideal, ends[best], f(starts[0])) * p_max, jnp.where(
            beats_ideal, x[best], starts[0]
        )

    return jax.jit(jax.vmap(one))


@dataclasses.dataclass(frozen=True)
class Ceilings:
    """An environment's ceilings as fractions of P_best: ``held`` (``held_power``, lines held at the
    P_best offsets through the vibration), ``predicted`` (the same less the vibration's one-step
    prediction), both None with ``reason`` where the environment has no one bench to hold; the
    ``samples`` and ``seed`` they were drawn with."""

    held: float | None
    predicted: float | None
    reason: str | None
    samples: int
    seed: int

    def fractions(self, score) -> tuple:
        """(score / held, score / predicted) of a ``score`` in units of P_best (None where the
        ceiling or the score is missing)."""
        cut = lambda ceiling: None if ceiling is None or score is None else score / ceiling
        return cut(self.held), cut(self.predicted)

    def to_json(self) -> dict:
        """``held_power``, ``held_power_predicted`` (P / P_best, None where unknown) and
        ``held_power_reason`` (None where known)."""
        return dict(
            held_power=self.held, held_power_predicted=self.predicted, held_power_reason=self.reason
        )


def ceilings(spec, *, seed: int = CEILING_SEED, samples: int = CEILING_SAMPLES) -> Ceilings:
    """The ``Ceilings`` of the environment of ``spec`` (an ``ops_jax.EnvSpec``): ``held_power``
    without and with ``predict`` over ``samples`` draws from ``jax.random.key(seed)``, over P_best;
    None with the reason for an ideal environment (nothing to hold against) or a randomised one (a
    new bench each episode). Deterministic, and computed once per spec, seed and samples in a
    process."""
    if not (callable(getattr(spec, "make", None)) and callable(getattr(spec, "as_dict", None))):
        raise TypeError(
            "spec must be an ops_jax.EnvSpec (ops_jax.EnvSpec.from_options(options) for a dict of "
            f"ops_jax.make options), got {type(spec).__name__}"
        )
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    return _ceilings(spec, int(seed), int(samples))


@functools.lru_cache(maxsize=64)
def _ceilings(spec, seed: int, samples: int) -> Ceilings:
    """``ceilings`` of an ``EnvSpec``, cached."""
    env, params = spec.make()
    lab = params.lab
    reason = None
    if not env.config.imperfect:
        reason = "the ideal system: no imperfections, no vibration to hold against (P_best = P_max)"
    elif float(lab.randomize) or float(lab.randomize_layout):
        reason = "randomised imperfections: a new bench each episode, no one bench to hold"
    if reason is not None:
        return Ceilings(None, None, reason, samples, seed)
    key, p_best = jax.random.key(seed), float(lab.p_best)
    held, predicted = (
        held_power(env.config, lab, key, samples, predict=predict) / p_best
        for predict in (False, True)
    )
    return Ceilings(held, predicted, None, samples, seed)
