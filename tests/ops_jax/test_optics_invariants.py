"""Physical invariants of the imperfect optics over every accepted range (seeded draws that put each
parameter at its bounds a fifth of the time each): passive optics never create energy, P_best <=
P_max, the ideal system at zero imperfection, the phasor model within its documented bound."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ops_jax
from ops_jax import imperfections, optics, physics

R = imperfections.RANGES
WINDOW = (
    3.0  # wl: an episode ends when a line leaves it; vibration adds a little, so draws go to 1.5x
)


def _uniform_with_corners(rng, rng_range, shape):
    """Uniform in [lo, hi], each entry at lo or hi with probability 0.2 each."""
    u = rng.uniform(rng_range.lo, rng_range.hi, shape)
    corner = rng.random(shape)
    return np.where(corner < 0.2, rng_range.lo, np.where(corner < 0.4, rng_range.hi, u))


def _configs(rng, stages, batch):
    """Offsets (wl), rotations (rad), leakages and pulse weights (re, im) of ``batch`` random
    systems."""
    x = rng.uniform(-1.5 * WINDOW, 1.5 * WINDOW, (batch, stages))
    rot = np.asarray(
        optics.rotation(_uniform_with_corners(rng, R["waveplate_error_deg"], (batch, stages)))
    )
    leak = _uniform_with_corners(rng, R["pbs_leakage"], (batch, stages))
    amp = 1 + _uniform_with_corners(
        rng, R["pulse_amplitude_noise"], (batch, 1)
    ) * rng.standard_normal((batch, 2**stages))
    phase = _uniform_with_corners(rng, R["pulse_phase_noise"], (batch, 1)) * rng.standard_normal(
        (batch, 2**stages)
    )
    return x, rot, leak, (amp * np.cos(phase), amp * np.sin(phase))


def _field(stages):
    """The jitted field model (total detector) of N stages."""
    return jax.jit(lambda x, rot, leak, pulses: optics.measure(x, rot, leak, pulses, stages=stages))


def _energy(m):
    """Output energy (arbitrary units) from the field model's I(t) of the total detector."""
    return np.asarray(m.intensity).sum(-1)


@pytest.mark.parametrize("stages", range(1, 8))
def test_passive_optics_never_create_energy(stages):
    """10^4 systems over N = 1..7 in float64: energy out <= energy in, the output of the same train
    through lossless optics (which conserve it: test_imperfections' hand-written stage counts every
    port)."""
    rng = np.random.default_rng(100 + stages)
    x, rot, leak, pulses = _configs(rng, stages, 1430)
    with jax.enable_x64(True):
        out, lossless = (
            _field(stages)(x, r, l, pulses)
            for r, l in ((rot, leak), (np.full_like(rot, np.pi / 4), 0 * leak))
        )
    ratio = _energy(out) / _energy(lossless)
    assert ratio.max() <= 1 + 1e-12
    assert ratio.min() < 0.9  # the draws do include lossy systems


@pytest.mark.parametrize("model", physics.MODELS)
@pytest.mark.parametrize("detector", physics.DETECTORS)
def test_no_offset_beats_p_max(model, detector):
    """P <= P_max at every offset of every system with identical pulses (P_best is the max of P)."""
    rng = np.random.default_rng(3)
    for stages in (1, 2, 5) if detector == "total" else (1, 3):
        x, rot, leak, _ = _configs(rng, stages, 512)
        x[:64] = rng.uniform(-0.02, 0.02, (64, stages))  # near the ideal optimum, where P peaks
        p = optics.measure(
            x,
            rot,
            leak,
            optics.ideal_pulses(stages, (512,)),
            stages=stages,
            model=model,
            detector=detector,
        ).power
        assert float(jnp.max(p)) / physics.p_max(stages, detector) <= 1 + 2e-6  # float32 rounding


@pytest.mark.parametrize("detector", physics.DETECTORS)
def test_p_best_never_exceeds_p_max(detector):
    """The P_best search over random static optics (wave plates, leakage) in the accepted ranges, N
    = 1..5, and their corners: P_best / P_max <= 1 (float32 rounding), and < 1 with
    imperfections."""
    rng = np.random.default_rng(11)
    for stages in (1, 3, 5) if detector == "total" else (1, 2):
        _, rot, leak, _ = _configs(rng, stages, 24)
        wp = np.rad2deg(rot - np.pi / 4) / 2
        wp[0], leak[0] = 0.0, 0.0  # the ideal optics: P_best = P_max
        lab = imperfections.build(stages, waveplate_error_deg=wp, pbs_leakage=leak)
        env, _ = ops_jax.make(stages, "hard", model="phasor", detector=detector, imperfect=True)
        ratio = imperfections.best_power(env.config, lab) / env.p_max
        assert ratio.max() <= 1 + 2e-6
        assert ratio[0] == pytest.approx(1.0, abs=2e-6)
        assert np.all(ratio[1:][leak[1:].max(-1) > 0.01] < 0.999)


@pytest.mark.parametrize("model", physics.MODELS)
@pytest.mark.parametrize("detector", physics.DETECTORS)
def test_zero_imperfection_is_the_ideal_system(model, detector):
    """rot = pi/4, leak = 0, unit pulses: ``optics.measure`` is ``physics.measure`` (float64, N = 1,
    4, 7)."""
    rng = np.random.default_rng(5)
    for stages in (1, 4, 7):
        x = rng.uniform(-WINDOW, WINDOW, (8, stages))
        with jax.enable_x64(True):
            got = optics.measure(
                x,
                np.pi / 4,
                0.0,
                optics.ideal_pulses(stages, (8,)),
                stages=stages,
                model=model,
                detector=detector,
            )
            want = physics.measure(x, stages=stages, model=model, detector=detector)
        scale = physics.p_max(stages, detector)
        np.testing.assert_allclose(got.power, want.power, rtol=1e-12, atol=1e-12 * scale)
        np.testing.assert_allclose(
            got.samples, want.samples, atol=1e-12 * physics.peak_intensity(stages)
        )


@pytest.mark.parametrize("detector", physics.DETECTORS)
def test_phasor_within_its_documented_bound(detector):
    """Phasor against field over the accepted ranges, N = 1..7 (split between the detectors),
    float64: within ``optics.phasor_error_bound``, which the draws approach (the bound is not loose
    by orders of magnitude)."""
    rng = np.random.default_rng(17)
    worst = 0.0
    for stages in (1, 2, 3, 5, 7) if detector == "total" else (1, 2, 4, 6):
        x, rot, leak, pulses = _configs(rng, stages, 256 if stages < 6 else 64)
        x = x / 1.5  # the phasor model's envelope error is documented within the window
        with jax.enable_x64(True):
            f = optics.measure(
                x, rot, leak, pulses, stages=stages, model="field", detector=detector
            ).power
            p = optics.measure(
                x, rot, leak, pulses, stages=stages, model="phasor", detector=detector
            ).power
            bound = optics.phasor_error_bound(leak[:, 0], pulses, stages=stages, detector=detector)
        use = np.asarray(jnp.abs(p - f) / bound)
        print(f"{detector} N={stages}: largest error {use.max():.3f} of the bound")
        assert use.max() <= 1.0, (stages, use.max())
        worst = max(worst, use.max())
    assert worst > 0.2
