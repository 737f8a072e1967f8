"""ops_jax.lock on signals of known spectrum: a sine, white noise, a step response, a trace that
never settles."""

import json
import math

import numpy as np
import pytest

from ops_jax.lock import LockFigures, lock_figures


def test_a_sine_peaks_at_its_frequency_with_rms_amplitude_over_root_two_over_mean():
    rate, steps, segment = 100.0, 4096, 256
    f0 = 25 * rate / segment  # on a frequency bin: 9.765625 Hz
    t = np.arange(steps) / rate
    mean, amplitude = 0.8, 0.008  # 1 % of the mean: inside the 2 % band from the start
    trace = mean + amplitude * np.sin(2 * np.pi * f0 * t)
    fig = lock_figures(trace, rate, segment=segment)
    assert isinstance(fig, LockFigures) and fig.lock_step == 1 and fig.lock_s == pytest.approx(0.01)
    # whole periods up to a last partial one: std / mean within 0.1 % of a / sqrt(2) / mean
    assert fig.rms_after_lock == pytest.approx(amplitude / math.sqrt(2) / mean, rel=1e-3)
    assert fig.frequency[np.argmax(fig.psd)] == pytest.approx(f0)
    assert fig.frequency[1] == pytest.approx(rate / segment)
    df = fig.frequency[1] - fig.frequency[0]
    assert fig.psd.sum() * df == pytest.approx((amplitude / mean) ** 2 / 2, rel=0.02)


@pytest.mark.parametrize("segment", [128, 127])  # odd: no Nyquist bin, every bin but DC doubled
def test_white_noise_has_a_flat_psd_whose_integral_is_its_variance(segment):
    rng = np.random.default_rng(3)
    rate, steps, sigma = 50.0, 2**16, 0.004  # relative noise, well inside the band
    trace = 1.0 + sigma * rng.standard_normal(steps)
    fig = lock_figures(trace, rate, segment=segment)
    psd, df = fig.psd, fig.frequency[1]
    assert psd.sum() * df == pytest.approx(sigma**2, rel=0.03)  # the segment means remove ~1/128
    level = 2 * sigma**2 / rate  # one-sided white level (1/Hz)
    inner = psd[1 : segment // 2]  # DC (and an even segment's Nyquist bin) hold half
    assert np.all(np.abs(inner / level - 1) < 0.15)  # ~1000 averaged segments: ~3 % per bin
    halves = np.array_split(inner, 2)
    assert halves[0].mean() == pytest.approx(halves[1].mean(), rel=0.05)
    assert fig.rms_after_lock == pytest.approx(sigma, rel=0.02)


def test_without_a_rate_the_psd_is_per_step_and_there_are_no_seconds():
    rng = np.random.default_rng(4)
    trace = 1.0 + 0.003 * rng.standard_normal(2**14)
    per_step = lock_figures(trace, segment=64)
    at_rate = lock_figures(trace, 20.0, segment=64)
    assert per_step.lock_s is None and per_step.frequency[-1] == pytest.approx(0.5)
    assert at_rate.frequency[-1] == pytest.approx(10.0)
    np.testing.assert_allclose(per_step.psd, at_rate.psd * 20.0)  # same integral over either axis


def test_a_step_response_locks_at_the_step_it_settles():
    rng = np.random.default_rng(5)
    steps, settle = 400, 137  # index 137 is the first reading at the held level: lock step 138
    trace = np.where(np.arange(steps) < settle, 0.4, 0.95)
    trace = trace * (1 + 0.005 * rng.standard_normal(steps))  # within the 2 % band
    fig = lock_figures(trace, rate_hz=200.0)
    assert fig.lock_step == settle + 1 and fig.lock_s == pytest.approx((settle + 1) / 200.0)
    assert fig.held_level == pytest.approx(0.95, rel=0.003)
    assert fig.rms_after_lock == pytest.approx(0.005, rel=0.15)
    # a narrower band than the noise: the lock comes later or never
    assert not fig.lock_step <= lock_figures(trace, band=0.002).lock_step


def test_an_exponential_settle_locks_where_it_enters_the_band():
    tau, steps = 7.3, 300
    trace = 1.0 - 0.5 * np.exp(-np.arange(steps) / tau)
    # in the band once 0.5 exp(-k / tau) <= 0.02 (held level 1 to 1e-17): k >= tau ln 25 = 23.5
    first = math.ceil(tau * math.log(25))
    assert lock_figures(trace).lock_step == first + 1
    assert lock_figures(trace, band=0.1).lock_step == math.ceil(tau * math.log(5)) + 1


def test_a_trace_that_never_settles_has_no_lock_figures_and_says_why():
    t = np.arange(500)
    swinging = 0.6 + 0.2 * np.sin(2 * np.pi * t / 37)  # far wider than its 2 % band
    fig = lock_figures(swinging, rate_hz=10.0)
    assert not fig.locked and np.isnan(fig.lock_step) and np.isnan(fig.rms_after_lock)
    assert np.isnan(fig.lock_s) and np.isnan(fig.psd).all()
    written = json.dumps(fig.to_json(), allow_nan=False)  # no bare NaN
    back = json.loads(written)
    assert back["lock_step"] is None and back["lock_s"] is None and back["rms_after_lock"] is None
    assert "never stayed within 2%" in back["lock_reason"]
    # dark: a held level of zero is no lock
    assert not lock_figures(np.zeros(50)).locked
    # settled only in its last readings, fewer than hold (10 %) of the trace: not a lock
    late = np.where(t < 480, swinging, 0.6)
    assert not lock_figures(late).locked and lock_figures(late, hold=0.02).lock_step == 481


def test_a_batch_gives_figures_per_trace_and_its_episode_summary_skips_the_unlocked():
    steps = 200
    k = np.arange(steps)
    locked_at = [20, 60, 100]
    batch = np.stack([np.where(k < s, 0.3, 0.9) for s in locked_at] + [0.5 + 0.3 * (k % 2)])
    fig = lock_figures(batch.reshape(2, 2, steps), rate_hz=50.0)
    assert fig.lock_step.shape == (2, 2) and fig.psd.shape[:2] == (2, 2)
    np.testing.assert_array_equal(fig.lock_step.ravel()[:3], np.array(locked_at) + 1)
    assert fig.segment == 64  # the largest power of two the shortest lock (100 readings) fills
    summary = fig.episode_summary()
    assert summary["lock_step_median"] == 61 and summary["fraction_locked"] == 0.75
    assert (
        summary["rms_after_lock_median"] == pytest.approx(0, abs=1e-12)
        and summary["lock_reason"] is None
    )
    per_trace = fig.to_json()
    assert per_trace["lock_step"] == [[21, 61], [101, None]]
    assert per_trace["lock_reason"][0] == [None, None] and per_trace["lock_reason"][1][1]
    nothing = lock_figures(batch[3:]).episode_summary()
    assert nothing["lock_step_median"] is None and nothing["rms_after_lock_median"] is None
    assert nothing["lock_reason"].startswith("no episode locked")
    json.dumps(nothing, allow_nan=False)


def test_scaling_the_trace_changes_no_figure():
    rng = np.random.default_rng(6)
    trace = np.clip(1 - np.exp(-np.arange(300) / 9.0), 0, None) + 0.002 * rng.standard_normal(300)
    a, b = lock_figures(trace), lock_figures(trace * 1.37)
    assert a.lock_step == b.lock_step and a.rms_after_lock == pytest.approx(b.rms_after_lock)
    np.testing.assert_allclose(a.psd, b.psd)


@pytest.mark.parametrize(
    "args, kwargs, words",
    [
        ((np.float32(1.0),), {}, "trace must have shape (..., steps) with steps >= 4"),
        ((np.ones(3),), {}, "steps >= 4"),
        ((np.ones((0, 10)),), {}, "no empty axis"),
        ((np.ones(10),), {"band": 0.0}, "band must lie in (0, 1)"),
        ((np.ones(10),), {"band": 1.5}, "band must lie in (0, 1)"),
        ((np.ones(10), 0.0), {}, "rate_hz must be a finite number > 0"),
        ((np.ones(10), -5.0), {}, "rate_hz must be a finite number > 0"),
        ((np.ones(10), float("inf")), {}, "rate_hz must be a finite number > 0"),
        ((np.ones(10),), {"hold": 0.0}, "hold must lie in (0, 1]"),
        ((np.ones(10),), {"segment": 11}, "segment must be an integer in [4, steps = 10]"),
        ((np.ones(10),), {"segment": 2.5}, "segment must be an integer"),
    ],
)
def test_bad_input_names_the_parameter_and_its_range(args, kwargs, words):
    with pytest.raises(ValueError) as err:
        lock_figures(*args, **kwargs)
    assert words in str(err.value)


def test_non_finite_readings_count_as_out_of_the_band():
    trace = np.full(100, 0.9)
    trace[70] = np.nan
    fig = lock_figures(trace)
    assert fig.lock_step == 72 and fig.rms_after_lock == pytest.approx(0, abs=1e-12)


def test_a_run_too_short_to_score_gets_null_figures_that_say_why():
    from ops_jax.lock import episode_summary, trace_json

    for trace in (np.ones(3), np.ones(0)):
        run = json.loads(json.dumps(trace_json(trace, 100.0), allow_nan=False))
        assert run["lock_step"] is None and run["lock_s"] is None and run["rms_after_lock"] is None
        assert "too short to score" in run["lock_reason"]
    over = episode_summary(np.ones((5, 2)))
    assert over["lock_step_median"] is None and over["fraction_locked"] is None
    locked = trace_json(np.r_[np.zeros(10), np.ones(90)], 50.0)
    assert locked["lock_step"] == 11 and locked["lock_s"] == pytest.approx(0.22)
    assert locked["lock_reason"] is None and locked["held_level"] == 1.0
    with pytest.raises(ValueError, match="band must lie in"):
        trace_json(np.ones(10), band=2.0)


def test_the_module_imports_numpy_and_the_standard_library_only():
    import ast

    import ops_jax.lock

    tree = ast.parse(open(ops_jax.lock.__file__).read())
    names = {
        a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names
    }
    names |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert names == {"__future__", "dataclasses", "math", "warnings", "numpy"}
