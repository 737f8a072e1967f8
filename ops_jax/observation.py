"""The layout of an observation (``OPSEnv.layout``): where each reading sits in a frame and its
scale.

A frame is, each entry mapped affinely to about [-1, 1]:

- ``2 P / P_max - 1``: the stacked energy (index 0);
- ``2 I_m / I_peak - 1``: the 2^N - 1 oscilloscope samples (I_peak: peak of the ideal pulse);
- ``x_i / window``: the N length readouts (wl; ``window`` the termination bound), unless ``lengths``
  is False (the environment's ``observe_lengths=False``: the detector's frames only);
- ``mu_i / 5e-4 wl``: the N entries of the noise state, with ``noise`` (``include_noise=True``).

An observation is ``frame_stack`` frames, oldest first. Every reader of an observation (the
environment, the controllers, the IOC, the bench runner) reads it through this record.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ops_jax import noise


@dataclasses.dataclass(frozen=True)
class ObservationLayout:
    """The frame of an N-stage environment: ``stages`` N, ``frame_stack`` frames per observation,
    ``lengths`` (the N length readouts present), ``noise`` (the N noise-state entries present)."""

    stages: int
    frame_stack: int = 1
    lengths: bool = True
    noise: bool = False

    # -- sizes and slices of one frame -------------------------------------------------------------
    @property
    def detector_size(self) -> int:
        """Entries read from the detector: P and the 2^N - 1 samples."""
        return 2**self.stages

    @property
    def frame_size(self) -> int:
        """Entries of one frame."""
        n = self.stages
        return 2**n + (n if self.lengths else 0) + (n if self.noise else 0)

    @property
    def size(self) -> int:
        """Entries of an observation: ``frame_size * frame_stack``."""
        return self.frame_size * self.frame_stack

    @property
    def samples_slice(self) -> slice:
        return slice(1, self.detector_size)

    @property
    def lengths_slice(self) -> slice | None:
        """The length readouts within a frame (None without them)."""
        m = self.detector_size
        return slice(m, m + self.stages) if self.lengths else None

    @property
    def noise_slice(self) -> slice | None:
        """The noise state within a frame (None without it)."""
        start = self.detector_size + (self.stages if self.lengths else 0)
        return slice(start, start + self.stages) if self.noise else None

    def describe(self) -> str:
        """The layout in words, e.g. for an error message."""
        return (
            f"stages={self.stages}, frame_stack={self.frame_stack}, "
            f"observe_lengths={self.lengths}, include_noise={self.noise} ({self.size} entries, "
            f"{self.stages} actions)"
        )

    # -- reading -----------------------------------------------------------------------------------
    def latest(self, obs):
        """The newest frame (..., frame_size) of observations (..., size)."""
        if obs.shape[-1] != self.size:
            raise ValueError(
                f"an observation of this environment has {self.size} entries ({self.describe()}), "
                f"got trailing shape {obs.shape[-1:]}"
            )
        return obs[..., obs.shape[-1] - self.frame_size :]

    def power(self, obs):
        """P / P_max of the newest frame (...,)."""
        return (self.latest(obs)[..., 0] + 1) / 2

    def detector(self, obs):
        """The newest frame's detector entries (..., 2^N): the encoded P and samples."""
        return self.latest(obs)[..., : self.detector_size]

    def length_readouts(self, obs, window):
        """The newest frame's length readouts (..., N) in wl; ``window`` (wl) their scale.
        ValueError without them."""
        if not self.lengths:
            raise ValueError("the observation has no length readouts (observe_lengths=False)")
        return self.latest(obs)[..., self.lengths_slice] * window

    # -- writing -----------------------------------------------------------------------------------
    def encode(self, power, samples, lengths=None, window=None, noise_state=None, xp=jnp):
        """One frame (frame_size,) from P / P_max, the samples / I_peak (2^N - 1,), the length
        readouts (N,) wl with their scale ``window`` (wl; both needed with ``lengths``) and the
        noise state (N,) wl (needed with ``noise``); ``xp``: ``jax.numpy`` or ``numpy``."""
        parts = [xp.reshape(2 * xp.asarray(power) - 1, (1,)), 2 * xp.asarray(samples) - 1]
        if self.lengths:
            if lengths is None or window is None:
                raise ValueError("this layout holds the length readouts: give lengths and window")
            parts.append(xp.asarray(lengths) / window)
        if self.noise:
            if noise_state is None:
                raise ValueError(
                    "this layout holds the noise state (include_noise=True): give noise_state"
                )
            parts.append(xp.asarray(noise_state) / noise.REFERENCE_SIGMA_WL)
        frame = xp.concatenate(parts)
        if frame.shape != (self.frame_size,):
            raise ValueError(
                f"a frame of this environment has {self.frame_size} entries ({self.describe()}), "
                f"got {frame.shape[0]}: {2**self.stages - 1} samples expected, got "
                f"{np.shape(samples)}"
            )
        return frame

    def decode(self, frame, window) -> dict:
        """A frame's readings (float64): ``power`` P / P_max, ``trace`` the samples / I_peak,
        ``length`` the readouts (wl; None without them)."""
        f = np.asarray(frame, np.float64)
        return {
            "power": (f[0] + 1) / 2,
            "trace": (f[self.samples_slice] + 1) / 2,
            "length": f[self.lengths_slice] * float(window) if self.lengths else None,
        }
