"""Every option of ``ops_jax.make`` and of the Gymnasium constructors, table-driven: values at the
edges of the accepted range construct; degenerate or malformed values raise naming the option and
the accepted range. A new option without a row fails ``test_every_option_has_a_row``."""

import dataclasses
import inspect
import math

import jax
import pytest

import ops_jax
from ops_jax import imperfections
from ops_jax.adapters.gymnasium.env import OPSGymEnv, OPSVectorEnv

INT32_MAX = 2**31 - 1
INT_RANGE = f"an integer in [1, {INT32_MAX}]"

# option: (accepted values, [(rejected value, exception, words of the message)])
ROWS = {
    "stages": (
        [1, 4],
        [(0, ValueError, "stages must be an integer >= 1"), (1.5, TypeError, "stages")],
    ),
    "mode": (["easy", "custom"], [("insane", ValueError, "mode")]),
    "model": (["field", "phasor"], [("ray", ValueError, "model")]),
    "detector": (["total", "polariser"], [("eye", ValueError, "detector")]),
    "reward": (["paper", "reference", "linear"], [("money", ValueError, "reward")]),
    "max_steps": (
        [1, INT32_MAX],
        [
            (0, ValueError, f"max_steps must be {INT_RANGE}"),
            (2**31, ValueError, INT_RANGE),
            (2.0, ValueError, INT_RANGE),
        ],
    ),
    "feedback_k": (
        [1, 100],
        [(0, ValueError, f"feedback_k must be {INT_RANGE}"), (True, ValueError, INT_RANGE)],
    ),
    "frame_stack": (
        [1, 4],
        [(0, ValueError, f"frame_stack must be {INT_RANGE}"), (-2, ValueError, INT_RANGE)],
    ),
    "include_noise": ([False, True], [(1, TypeError, "include_noise must be a bool")]),
    "observe_lengths": ([False, True], [(1, TypeError, "observe_lengths must be a bool")]),
    "probe": (["instant", "frame"], [("later", ValueError, "probe must be one of")]),
    "init_spread": (
        [0.0, 1.0],
        [
            (-0.1, ValueError, "init_spread must be a finite number in [0, 1] wl"),
            (1.5, ValueError, "[0, 1] wl"),
            (math.nan, ValueError, "[0, 1] wl"),
        ],
    ),
    "step_sigma": (
        [0.0, 0.1],
        [
            (-1e-4, ValueError, "step_sigma must be a finite number in [0, 0.1] wl"),
            (0.5, ValueError, "[0, 0.1] wl"),
        ],
    ),
    "drift_cap": (
        [0.0, 10.0],
        [
            (-1.0, ValueError, "drift_cap must be a finite number in [0, 10]"),
            (11.0, ValueError, "[0, 10]"),
        ],
    ),
    "drift_ramp": (
        [0.0, 1e3],
        [
            (-0.1, ValueError, "drift_ramp must be a finite number in [0, inf)"),
            (math.inf, ValueError, "[0, inf)"),
        ],
    ),
    "drift_amplitude": (
        [0.0, 0.1],
        [
            (-1e-3, ValueError, "drift_amplitude must be a finite number in [0, 0.1]"),
            (0.2, ValueError, "[0, 0.1]"),
        ],
    ),
    "drift_segment": (
        [1, 50.0],
        [
            (0, ValueError, f"drift_segment must be {INT_RANGE} steps"),
            (2.5, ValueError, INT_RANGE),
            (True, ValueError, INT_RANGE),
        ],
    ),
    "action_scale": (
        [1e-6, 1.0],
        [
            (0.0, ValueError, "action_scale must be a finite number in (0, 1] wl"),
            (-0.01, ValueError, "(0, 1]"),
            (1.5, ValueError, "(0, 1]"),
            (math.inf, ValueError, "(0, 1]"),
        ],
    ),
    "obs_noise": (
        [0.0, 1.0],
        [
            (-1e-4, ValueError, "obs_noise must be a finite number in [0, 1]"),
            (2.0, ValueError, "[0, 1]"),
            (math.nan, ValueError, "[0, 1]"),
        ],
    ),
    "window": (
        [0.16, 1e6],
        [
            (0.0, ValueError, "window must be a finite number in (0, inf) wl"),
            (math.inf, ValueError, "(0, inf) wl"),
            (0.15, ValueError, "window must be > init_spread"),
        ],
    ),  # hard: init_spread 0.15
    "imperfect": ([False, True], [(1, TypeError, "imperfect must be a bool")]),
    "imperfections": (["none", "lab"], [("space", ValueError, "imperfections must be one of")]),
    "imperfection_scale": (
        [0.0, 2.0],
        [(-1.0, ValueError, "imperfection_scale must be a finite number >= 0")],
    ),
    "waveplate_error_deg": (
        [-10.0, (0.1, -0.2, 0.3)],
        [
            (11.0, ValueError, "waveplate_error_deg must be a finite number in [-10, 10] deg"),
            ((0.1, 0.2), ValueError, "trailing shape (3,)"),
        ],
    ),
    "pbs_leakage": (
        [0.0, 0.5],
        [
            (-0.1, ValueError, "pbs_leakage must be a finite number in [0, 0.5]"),
            (0.6, ValueError, "[0, 0.5]"),
        ],
    ),
    "pulse_amplitude_noise": (
        [0.0, 0.5],
        [(0.6, ValueError, "pulse_amplitude_noise must be a finite number in [0, 0.5]")],
    ),
    "pulse_phase_noise": (
        [0.0, 3.0],
        [(4.0, ValueError, "pulse_phase_noise must be a finite number in [0, 3.14159] rad")],
    ),
    "readout_offset": (
        [-1.0, 1.0],
        [(2.0, ValueError, "readout_offset must be a finite number in [-1, 1] wl")],
    ),
    "readout_gain_error": (
        [-0.5, 0.5],
        [(0.6, ValueError, "readout_gain_error must be a finite number in [-0.5, 0.5]")],
    ),
    "actuator_gain_error": (
        [-0.5, 0.5],
        [(-0.6, ValueError, "actuator_gain_error must be a finite number in [-0.5, 0.5]")],
    ),
    "backlash_wl": (
        [0.0, 1.0],
        [(-0.01, ValueError, "backlash_wl must be a finite number in [0, 1] wl")],
    ),
    "lag_steps": (
        [0.0, 100.0],
        [(101.0, ValueError, "lag_steps must be a finite number in [0, 100] steps")],
    ),
    "dac_bits": ([0.0, 16.0], [(33.0, ValueError, "dac_bits must be a finite number in [0, 32]")]),
    "actuator_span_wl": (
        [1e-3, 1e4],
        [(0.0, ValueError, "actuator_span_wl must be a finite number in [0.001, 10000] wl")],
    ),
    "detector_offset": (
        [-1.0, 1.0],
        [(1.5, ValueError, "detector_offset must be a finite number in [-1, 1]")],
    ),
    "detector_gain_error": (
        [-0.5, 0.5],
        [(-0.6, ValueError, "detector_gain_error must be a finite number in [-0.5, 0.5]")],
    ),
    "detector_saturation": (
        [0.1, math.inf],
        [(0.05, ValueError, "detector_saturation must be a number in [0.1, inf]")],
    ),
    "adc_bits": (
        [0.0],
        [
            (33.0, ValueError, "adc_bits must be a finite number in [0, 32]"),
            (8.0, ValueError, "adc_bits > 0 needs a finite detector_saturation"),
        ],
    ),
    "vib_rms": ([0.0, 1.0], [(2.0, ValueError, "vib_rms must be a finite number in [0, 1] wl")]),
    "vib_alpha": ([0.0, 2.0], [(2.5, ValueError, "vib_alpha must be a finite number in [0, 2]")]),
    "resonance_freq": (
        [(0.01, 0.5)],
        [
            (
                (0.6, 0.1),
                ValueError,
                "resonance_freq must be a finite number in [0.0001, 0.5] cycles per step",
            ),
            ((0.1,), ValueError, "trailing shape (2,)"),
        ],
    ),
    "resonance_q": (
        [(0.5, 1e4)],
        [((0.1, 1.0), ValueError, "resonance_q must be a finite number in [0.5, 10000]")],
    ),
    "resonance_rms": (
        [(0.0, 0.01)],
        [((-1.0, 0.0), ValueError, "resonance_rms must be a finite number in [0, 1] wl")],
    ),
    "p_best": ([0.0, 1.0], [(-1.0, ValueError, "p_best must be a number in [0, inf]")]),
    "randomize": ([0.0, 1.0], [(1.5, ValueError, "randomize must be a finite number in [0, 1]")]),
    "randomize_layout": (
        [0.0, 1.0],
        [(-0.5, ValueError, "randomize_layout must be a finite number in [0, 1]")],
    ),
    "render_mode": (
        [None, "rgb_array"],
        [("ascii", ValueError, "render_mode must be None or one of")],
    ),
    "device": (
        [None, "cpu"],
        [
            (3, TypeError, "device must be None, a platform name"),
            ("no-such-platform", ValueError, "device 'no-such-platform' is not available"),
        ],
    ),
    "num_envs": (
        [1, 3],
        [
            (0, ValueError, "num_envs must be an integer >= 1"),
            (1.5, ValueError, "num_envs"),
            (True, ValueError, "num_envs"),
        ],
    ),
}

BASE = dict(stages=3, mode="hard", model="phasor")
CONSTRUCTORS = {
    "make": lambda **kw: ops_jax.make(**{**BASE, **kw}),
    "OPSGymEnv": lambda **kw: OPSGymEnv(**{**BASE, **kw}),
    "OPSVectorEnv": lambda **kw: OPSVectorEnv(**{"num_envs": 2, **BASE, **kw}),
}


def _options(constructor) -> set:
    """Named parameters of ``constructor`` plus, where it forwards ``**options`` to ``make``,
    make's."""
    sig = inspect.signature(constructor).parameters
    names = {n for n, p in sig.items() if p.kind is not p.VAR_KEYWORD and n != "self"}
    if any(p.kind is p.VAR_KEYWORD for p in sig.values()):
        names |= {
            f.name
            for cls in (ops_jax.EnvConfig, ops_jax.EnvParams)
            for f in dataclasses.fields(cls)
        }
        names |= set(imperfections.OPTIONS)
        names.discard("lab")  # built by make from the imperfection options, not an option itself
    return names


OPTIONS = {
    "make": _options(ops_jax.make),
    "OPSGymEnv": _options(OPSGymEnv),
    "OPSVectorEnv": _options(OPSVectorEnv),
}
CASES = [(c, o) for c in CONSTRUCTORS for o in sorted(OPTIONS[c])]


def test_every_option_has_a_row():
    assert set().union(*OPTIONS.values()) == set(ROWS)
    assert OPTIONS["make"] < OPTIONS["OPSGymEnv"] < OPTIONS["OPSVectorEnv"]


@pytest.mark.parametrize("constructor, option", CASES)
def test_option_range(constructor, option):
    jax.devices()  # the adapters check a device's availability at construction once JAX runs
    build = CONSTRUCTORS[constructor]
    good, bad = ROWS[option]
    for value in good:
        build(**{option: value})
    for value, exc, words in bad:
        with pytest.raises(exc) as err:
            build(**{option: value})
        assert option in str(err.value) and words in str(err.value), (value, str(err.value))
