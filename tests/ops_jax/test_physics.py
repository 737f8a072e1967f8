"""The physics against the paper implementation's numbers, the phasor model against the field
model, gradients, both detectors, and bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ops_jax import physics

ALL_N = range(1, 8)


def enable_x64():
    """float64 inside a ``with`` block (``jax.enable_x64`` on current JAX, jax.experimental's
    before)."""
    if hasattr(jax, "enable_x64"):
        return jax.enable_x64(True)
    from jax.experimental import enable_x64 as experimental_enable_x64

    return experimental_enable_x64(True)


def _errors(m, phys, N):
    scale = phys[f"N{N}_pulse_I_full"].max()
    return (
        np.max(np.abs(np.asarray(m.power) / phys[f"N{N}_f2_power"] - 1)),
        np.max(np.abs(np.asarray(m.samples) - phys[f"N{N}_pulse_samples"])) / scale,
        np.max(np.abs(np.asarray(m.intensity) - phys[f"N{N}_pulse_I_full"])) / scale,
    )


@pytest.mark.parametrize("N", ALL_N)
def test_field_matches_reference_float32(reference, N):
    phys, _ = reference
    m = physics.measure(phys[f"N{N}_deltas_wl"].astype(np.float32), stages=N)
    assert m.power.dtype == jnp.float32
    assert max(_errors(m, phys, N)) <= 1e-4


@pytest.mark.parametrize("N", ALL_N)
def test_field_matches_reference_float64(reference, N):
    phys, _ = reference
    with enable_x64():
        m = physics.measure(phys[f"N{N}_deltas_wl"], stages=N)
        assert m.power.dtype == jnp.float64
        assert max(_errors(m, phys, N)) <= 1e-6


@pytest.mark.parametrize("N", ALL_N)
def test_grid_and_constants(reference, N):
    phys, const = reference
    g = physics.grid(N)
    np.testing.assert_allclose(g.t, phys[f"N{N}_T_ps"], atol=1e-12)
    np.testing.assert_allclose(g.w, phys[f"N{N}_W_THz"], rtol=1e-13)
    c = const[str(N)]
    assert abs(physics.p_max(N) / c["max_f2_power_unrounded"] - 1) < 1e-9
    assert abs(physics.p_orig(N) / c["orig_f2_power_unrounded"] - 1) < 1e-9
    assert abs(physics.peak_intensity(N) / c["max_avg_power"] - 1) < 1e-9
    np.testing.assert_allclose(physics.optimal_lengths_mm(N), c["optim_l0_mm"], rtol=1e-12)


@pytest.mark.parametrize("N", [1, 2])
def test_dense_sweep_matches_reference(reference, N):
    _, const = reference
    for k in range(1, N + 1):
        sweep = const[str(N)].get(f"sweep_stage{k}")
        if sweep is None:
            continue
        x = np.zeros((len(sweep["deltas_wl"]), N), np.float32)
        x[:, k - 1] = sweep["deltas_wl"]
        key = next(key for key in sweep if key != "deltas_wl" and "power" in key)
        got = np.asarray(physics.measure(x, stages=N).power)
        np.testing.assert_allclose(got, sweep[key], rtol=1e-4)


@pytest.mark.parametrize("N", range(2, 8))
@pytest.mark.parametrize("detector", physics.DETECTORS)
def test_phasor_agrees_with_field(N, detector):
    x = np.random.default_rng(N).uniform(-3, 3, (256, N))
    with enable_x64():
        f = physics.measure(x, stages=N, detector=detector)
        p = physics.measure(x, stages=N, model="phasor", detector=detector)
        assert p.intensity is None
        pmax = physics.p_max(N, detector)
        # total: relative in P; polariser (P can be ~0): relative to P_max.
        denom = np.asarray(f.power) if detector == "total" else pmax
        assert np.max(np.abs(np.asarray(p.power) - np.asarray(f.power)) / denom) <= 1e-3
        samples_err = np.abs(
            np.asarray(p.samples) - np.asarray(f.samples)
        ) / physics.peak_intensity(N)
        assert samples_err.max() <= 1e-3


def test_landscape_of_figure_2a():
    """N = 2, stage 1 swept: period wl/2, global maximum at 0, side maxima ~0.5 Pmax at +-wl/4."""
    x = np.zeros((201, 2), np.float32)
    x[:, 0] = np.linspace(-0.5, 0.5, 201)
    P = np.asarray(physics.measure(x, stages=2).power) / physics.p_max(2)
    assert P[100] == pytest.approx(1.0, abs=1e-5)
    np.testing.assert_allclose(P[:101], P[100:], atol=1e-3)  # period wl/2
    assert P[50] == pytest.approx(0.5, abs=0.01) and P[150] == pytest.approx(
        0.5, abs=0.01
    )  # +-wl/4
    assert 0.30 < P.min() < 0.36


def test_last_stage_phase_blind_with_total_detector_but_not_with_polariser():
    x = np.zeros((64, 3), np.float32)
    x[:, 2] = np.linspace(-0.5, 0.5, 64)
    total = np.asarray(physics.measure(x, stages=3).power)
    pol = np.asarray(physics.measure(x, stages=3, detector="polariser").power)
    assert np.ptp(total) / total.max() < 1e-3
    assert np.ptp(pol) / pol.max() > 0.5
    assert physics.p_max(3, "polariser") == pytest.approx(physics.p_max(3), rel=1e-9)


@pytest.mark.parametrize("model", physics.MODELS)
def test_grad_matches_finite_differences(model):
    N = 4
    x0 = np.random.default_rng(0).uniform(-0.3, 0.3, N)
    with enable_x64():
        f = lambda x: physics.measure(x, stages=N, model=model).power
        g = np.asarray(jax.grad(f)(jnp.asarray(x0)))
        h = 1e-6
        fd = np.array([(f(x0 + h * e) - f(x0 - h * e)) / (2 * h) for e in np.eye(N)])
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-6 * physics.p_max(N))
    assert np.abs(g[:-1]).max() > 1.0  # the interfering stages have a real gradient


def test_jit_vmap_and_leading_dims():
    x = np.random.default_rng(1).uniform(-1, 1, (3, 4, 5)).astype(np.float32)
    direct = physics.measure(x, stages=5)
    jitted = jax.jit(lambda x: physics.measure(x, stages=5))(x)
    vmapped = jax.vmap(jax.vmap(lambda x: physics.measure(x, stages=5)))(x)
    assert direct.power.shape == (3, 4) and direct.samples.shape == (3, 4, 31)
    assert direct.intensity.shape == (3, 4, 40 * 32)
    np.testing.assert_allclose(jitted.power, direct.power, rtol=1e-6)
    np.testing.assert_allclose(vmapped.power, direct.power, rtol=1e-6)


def test_ten_stages_construct_and_run():
    m = physics.measure(np.zeros(10, np.float32), stages=10)
    assert m.intensity.shape == (40 * 1024,)
    assert float(m.power) == pytest.approx(physics.p_max(10), rel=1e-4)
    assert physics.p_max(10) == pytest.approx(5.866667 * 4**10, rel=1e-5)


@pytest.mark.parametrize(
    "kwargs, exc, words",
    [
        (dict(stages=0), ValueError, "stages"),
        (dict(stages=2.5), TypeError, "stages"),
        (dict(stages=True), TypeError, "stages"),
        (dict(stages=2, model="ray"), ValueError, "model"),
        (dict(stages=2, detector="p"), ValueError, "detector"),
    ],
)
def test_bad_configuration(kwargs, exc, words):
    with pytest.raises(exc, match=words):
        physics.measure(np.zeros(2, np.float32), **kwargs)


def test_bad_shape():
    with pytest.raises(ValueError, match=r"deltas_wl must have shape \(\.\.\., 3\)"):
        physics.measure(np.zeros(2, np.float32), stages=3)
