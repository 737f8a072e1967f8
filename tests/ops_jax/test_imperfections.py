"""Lab imperfections against independent calculations: hand-written Jones matrices, the ideal
system reproduced, vibration spectra, actuator and detector maps, batch independence, P_best."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import signal

import ops_jax
from ops_jax import hardware, imperfections, optics, physics, vibration


def _hand_stage(p, s, D, leak, wp_err_deg):
    """One folded delay-line stage written out port by port (docs/imperfections.md): a symmetric
    lossless PBS (each polarisation: transmission t, reflection r = i |r|, unitary) passed twice, a
    quarter-wave double pass swapping p and s in each arm, arm B delayed by D, then a half-wave
    plate (a mirror matrix) and the turning mirror (diag(1, -1)). Returns p', s' and the (p, s)
    fields that leave by the input port."""
    a, l = np.sqrt(1 - leak), np.sqrt(leak)
    t_p, r_p, t_s, r_s = a, 1j * l, l, 1j * a  # p is transmitted, s reflected, each leaking l
    # Split: port 1 -> arm A (transmitted) and arm B (reflected); each arm swaps p and s on its way
    # back.
    arm_a = (t_s * s, t_p * p)  # (p, s) back at the PBS from arm A
    arm_b = (D * r_s * s, D * r_p * p)  # from arm B, delayed
    # Recombination: arm A's light reflects into the output port, arm B's transmits; the rest
    # returns to port 1.
    out_p, out_s = r_p * arm_a[0] + t_p * arm_b[0], r_s * arm_a[1] + t_s * arm_b[1]
    back_p, back_s = t_p * arm_a[0] + r_p * arm_b[0], t_s * arm_a[1] + r_s * arm_b[1]
    # The merged stage output: "P" is the output's s (arm A's p), "S" its p (arm B's s); the common
    # phase i removed.
    P, S = -1j * out_s, -1j * out_p
    th = np.pi / 8 + np.deg2rad(wp_err_deg)
    hwp = np.array([[np.cos(2 * th), np.sin(2 * th)], [np.sin(2 * th), -np.cos(2 * th)]])
    p2, s2 = np.diag([1.0, -1.0]) @ hwp @ np.array([P, S])
    return p2, s2, np.array([back_p, back_s])


def _hand_power(x, wp_err_deg, leak, weights, N):
    """(P, energy in, energy out, energy lost) of N stages from the folded-stage model written out
    with explicit ports per stage, merging the train entries pairwise (no shortcuts), float64
    NumPy."""
    T, c, lam = 20.0, 0.299792458, 1030e-6
    n = 40 * 2**N
    W = 2**N * T
    dt = W / n
    t = -W / 2 + np.arange(n) * dt
    w = 2 * np.pi * c / lam + 2 * np.pi * (np.arange(n) - n / 2) / (n * dt)
    u = 1 / np.cosh(t / (4.0 / 1.76))
    a0 = np.sqrt(2e-10 / (dt * 1e-12 * np.trapezoid(u**2))) * u
    spec = lambda a: np.fft.ifftshift(np.fft.ifft(np.fft.fftshift(a)))
    field = lambda A: np.fft.ifftshift(np.fft.fft(np.fft.fftshift(A)))
    rule = {"p": ("p", "s"), "-p": ("-p", "-s"), "s": ("-p", "s"), "-s": ("p", "-s")}
    labels = ["-s"]
    for _ in range(N):
        labels = [y for lab in labels for y in rule[lab]]
    zero = np.zeros(n, complex)
    train = []
    for k, lab in enumerate(labels):
        A = (-1 if lab.startswith("-") else 1) * weights[k] * spec(a0) * np.exp(-1j * w * k * T / 2)
        train.append(np.array([A, zero]) if lab.endswith("p") else np.array([zero, A]))
    energy = lambda ps: float(np.sum(np.abs(ps) ** 2))
    e_in, lost = energy(sum(train)), 0.0
    for i in range(N):
        back = 0.0
        L = 2.0**i * (T / 2) * c / 2 + x[i] * lam
        D = np.exp(-1j * w * (-2 * L / c))  # the delay operator (diagonal in frequency)
        merged = []
        for m in range(len(train) // 2):
            p, s = train[2 * m] + train[2 * m + 1]
            p, s, returned = _hand_stage(p, s, D, leak[i], wp_err_deg[i])
            merged.append(np.array([p, s]))
            back = back + returned  # the pairs' returned light overlaps in time: summed as fields
        train, lost = merged, lost + energy(back)
    I = np.abs(field(train[0][0])) ** 2 + np.abs(field(train[0][1])) ** 2
    return 1e9 * dt * 1e-12 * np.trapezoid(I**2), e_in, energy(train[0]), lost


@pytest.mark.parametrize("N", [1, 2])
def test_field_model_matches_hand_written_folded_stages(N):
    """The optics model is the folded stage written port by port; that stage loses exactly the light
    that leaves by its input port (energy in = out + lost); leakage and wave plate errors change
    P."""
    rng = np.random.default_rng(N)
    x = rng.uniform(-0.2, 0.2, N)
    err = rng.uniform(-3, 3, N)
    leak = rng.uniform(0.01, 0.3, N)
    weights = (1 + 0.1 * rng.standard_normal(2**N)) * np.exp(0.3j * rng.standard_normal(2**N))
    want, e_in, e_out, lost = _hand_power(x, err, leak, weights, N)
    ideal, *_ = _hand_power(x, np.zeros(N), np.zeros(N), np.ones(2**N), N)
    with jax.enable_x64(True):
        got = optics.measure(
            jnp.asarray(x),
            optics.rotation(jnp.asarray(err)),
            jnp.asarray(leak),
            (jnp.asarray(weights.real), jnp.asarray(weights.imag)),
            stages=N,
        ).power
        ref = physics.measure(jnp.asarray(x), stages=N).power
    assert abs(float(got) - want) < 1e-9 * want
    assert abs(float(ref) - ideal) < 1e-9 * ideal  # the hand calculation is the spec's
    assert abs(want - ideal) > 1e-3 * ideal  # and the imperfections do change P
    assert e_out + lost == pytest.approx(e_in, rel=1e-12) and lost > 1e-3 * e_in
    lossless = _hand_power(x, err, np.zeros(N), weights, N)
    assert lossless[2] == pytest.approx(e_in, rel=1e-12) and lossless[3] == 0.0


def test_splitting_ratio_of_a_waveplate_error():
    """A wave plate eps off splits sin^2(45 deg + 2 eps): 0.5 deg -> 51.7:48.3 (N = 2, the first
    stage's plate sets the second stage's split); only stage 1's light arrives at stage 2."""
    phi = float(optics.rotation(0.5))
    assert np.sin(phi) ** 2 == pytest.approx(0.5174, abs=1e-4)


def test_phasor_matches_field_with_imperfections():
    N = 5
    x = jax.random.uniform(jax.random.key(1), (16, N), minval=-0.2, maxval=0.2)
    rot = optics.rotation(jnp.array([0.3, -0.2, 0.4, -0.3, 0.2]))
    leak = jnp.array([0.0, 1e-3, 2e-3, 1e-3, 1e-3])
    pulses = (
        1 + 0.01 * jax.random.normal(jax.random.key(2), (16, 2**N)),
        0.02 * jax.random.normal(jax.random.key(3), (16, 2**N)),
    )
    f = optics.measure(x, rot, leak, pulses, stages=N, model="field")
    p = optics.measure(x, rot, leak, pulses, stages=N, model="phasor")
    np.testing.assert_allclose(p.power, f.power, rtol=1e-3)
    np.testing.assert_allclose(p.samples, f.samples, atol=1e-3 * physics.peak_intensity(N))
    # Stage 1's leaked light falls between the phasor's slots: within the documented bound.
    leak1 = jnp.array([1e-3, 0, 0, 0, 0])
    f1 = optics.measure(x, rot, leak1, pulses, stages=N, model="field").power
    p1 = optics.measure(x, rot, leak1, pulses, stages=N, model="phasor").power
    assert float(jnp.max(jnp.abs(p1 - f1) / optics.phasor_error_bound(1e-3, pulses, stages=N))) < 1


@pytest.mark.parametrize("model", ["phasor", "field"])
def test_imperfect_path_with_zero_imperfections_is_the_ideal_system(model):
    env0, p0 = ops_jax.make(3, "hard", model=model, max_steps=20)
    env1, p1 = ops_jax.make(3, "hard", model=model, max_steps=20, imperfect=True)
    assert float(p1.lab.p_best) == pytest.approx(env1.p_max, rel=1e-6)
    assert float(p0.lab.p_best) == pytest.approx(
        env0.p_max, rel=1e-6
    )  # P_best is P_max without imperfections
    pol = lambda key, obs: jnp.tanh(-3.0 * obs[:, -3:])
    a = ops_jax.rollout(env0, p0, pol, jax.random.key(4), 8, 45)
    b = ops_jax.rollout(env1, p1, pol, jax.random.key(4), 8, 45)
    np.testing.assert_allclose(b.obs, a.obs, atol=2e-6)
    np.testing.assert_allclose(b.normalized_power, a.normalized_power, rtol=2e-6)


def test_preset_none_is_bit_identical_to_the_default():
    env0, p0 = ops_jax.make(3, "hard", max_steps=20)
    env1, p1 = ops_jax.make(3, "hard", max_steps=20, imperfections="none")
    assert env1.config == env0.config and not env1.config.imperfect
    pol = lambda key, obs: jax.random.uniform(key, (obs.shape[0], 3), minval=-1, maxval=1)
    a = ops_jax.rollout(env0, p0, pol, jax.random.key(5), 4, 45)
    b = ops_jax.rollout(env1, p1, pol, jax.random.key(5), 4, 45)
    for u, v in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(u, v)


def _simulate_vibration(steps, alpha, bg_rms, freq, q, res_rms, key=0):
    r = len(freq)
    freq, q, res_rms = (jnp.asarray(v, jnp.float32) for v in (freq, q, res_rms))
    k0, k1 = jax.random.split(jax.random.key(key))
    fir = jax.random.normal(k0, (vibration.FIR_TAPS, 1))
    osc = vibration.stationary_lags(jax.random.normal(k1, (2, r, 1)), freq, q)

    def body(carry, k):
        fir, osc = carry
        z = jax.random.normal(k, (1 + r, 1))
        fir, osc, x = vibration.step(fir, osc, z[0], z[1:], alpha, bg_rms, freq, q, res_rms)
        return (fir, osc), x[0]

    return np.asarray(
        jax.lax.scan(body, (fir, osc), jax.random.split(jax.random.key(key + 1), steps))[1]
    )


def test_resonance_peaks_at_its_frequency_with_its_rms():
    x = _simulate_vibration(2**15, 1.0, 0.0, [0.12, 0.3], [30.0, 30.0], [0.01, 0.0])
    f, psd = signal.welch(x, nperseg=4096)
    assert abs(f[np.argmax(psd)] - 0.12) < 1e-3
    assert np.std(x) == pytest.approx(0.01, rel=0.05)
    # Q: the -3 dB width of the peak is about f / Q.
    half = f[psd > psd.max() / 2]
    assert 0.5 * 0.12 / 30 < half.max() - half.min() + f[1] < 2 * 0.12 / 30


@pytest.mark.parametrize("alpha", [0.0, 1.0, 1.8])
def test_background_spectrum_slope_and_rms(alpha):
    x = _simulate_vibration(2**15, alpha, 0.02, [0.1, 0.2], [10.0, 10.0], [0.0, 0.0])
    f, psd = signal.welch(x, nperseg=2048)
    band = (f > 0.03) & (f < 0.25)
    slope = np.polyfit(np.log(f[band]), np.log(psd[band]), 1)[0]
    assert slope == pytest.approx(-alpha, abs=0.2)
    assert np.std(x) == pytest.approx(0.02, rel=0.1)


def test_backlash_lag_and_dac_on_simple_inputs():
    # Backlash of width 0.02: a ramp up by 0.01 per step, then down; the output trails by 0.01.
    play, out = jnp.zeros(()), []
    for cmd in [0.01, 0.02, 0.03, 0.02, 0.01, 0.0, -0.01]:
        play = hardware.backlash(play, jnp.float32(cmd), 0.02)
        out.append(float(play))
    np.testing.assert_allclose(out, [0.0, 0.01, 0.02, 0.02, 0.02, 0.01, 0.0], atol=1e-7)
    # Lag: a unit step reaches 1 - exp(-t / tau).
    pos, tau, trace = jnp.zeros(()), 3.0, []
    for _ in range(6):
        pos = hardware.lag(pos, 1.0, tau)
        trace.append(float(pos))
    np.testing.assert_allclose(trace, 1 - np.exp(-np.arange(1, 7) / tau), rtol=1e-6)
    assert float(hardware.lag(0.0, 1.0, 0.0)) == 1.0
    # DAC: 4 bits over a span of 16 wl move in whole wl; the chain with a gain error.
    cmd, play, pos = hardware.actuate(
        jnp.zeros(2),
        jnp.zeros(2),
        jnp.zeros(2),
        jnp.array([0.4, 0.6]),
        jnp.array([0.0, 0.1]),
        0.0,
        0.0,
        16.0,
        4.0,
    )
    np.testing.assert_allclose(cmd, [0.4, 0.6], rtol=1e-7)
    np.testing.assert_allclose(pos, [0.0, 1.1], rtol=1e-6)


def test_detector_gain_offset_saturation_and_adc():
    v = jnp.array([0.0, 0.5, 1.0, 2.0])
    np.testing.assert_allclose(
        hardware.detect(v, 0.1, 0.02, jnp.inf, 0.0), 1.1 * v + 0.02, rtol=1e-6
    )
    np.testing.assert_allclose(
        hardware.detect(v, 0.0, 0.0, 1.2, 0.0), [0.0, 0.5, 1.0, 1.2], rtol=1e-6
    )
    q = hardware.detect(jnp.linspace(0, 1, 101), 0.0, 0.0, 1.0, 3.0)
    assert set(np.round(np.asarray(q) * 8, 5)) <= set(float(i) for i in range(9))


def test_lab_batch_independence_and_reproducibility():
    env, params = ops_jax.make(3, "hard", imperfections="lab", model="phasor", max_steps=30)
    pol = lambda key, obs: jnp.tanh(-3.0 * obs[:, -3:])
    alone = ops_jax.rollout(env, params, pol, jax.random.key(7), 1, 40)
    again = ops_jax.rollout(env, params, pol, jax.random.key(7), 1, 40)
    batch = ops_jax.rollout(env, params, pol, jax.random.key(7), 64, 40)
    np.testing.assert_array_equal(alone.obs, again.obs)
    np.testing.assert_allclose(alone.obs[:, 0], batch.obs[:, 0], atol=1e-6)
    assert not np.allclose(batch.obs[:, 0], batch.obs[:, 1])


def test_domain_randomised_batch_uses_each_instances_values():
    env, pa = ops_jax.make(3, "hard", imperfections="lab", model="phasor", max_steps=30)
    _, pb = ops_jax.make(
        3,
        "hard",
        imperfections="lab",
        model="phasor",
        max_steps=30,
        waveplate_error_deg=[3.0, -3.0, 2.0],
        pbs_leakage=0.01,
    )
    assert float(pb.lab.p_best) < float(pa.lab.p_best)
    batched = dataclasses.replace(
        pa, lab=jax.tree.map(lambda a, b: np.stack([a, b]), pa.lab, pb.lab)
    )
    keys = jax.random.split(jax.random.key(0), 2)
    actions = jnp.array([[0.5, -0.5, 0.2], [-0.3, 0.1, 0.9]])
    obs, states = jax.jit(env.reset_batch)(keys, batched)
    obs2, _, rew, _, _, info = jax.jit(env.step_batch)(keys, states, actions, batched)
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    for i, p in enumerate((pa, pb)):
        o, s = reset(keys[i], p)
        np.testing.assert_allclose(o, obs[i], atol=1e-6)
        o2, _, r, _, _, inf = step(keys[i], s, actions[i], p)
        np.testing.assert_allclose(o2, obs2[i], atol=1e-6)
        np.testing.assert_allclose(
            inf["normalized_power_best"], info["normalized_power_best"][i], rtol=1e-6
        )


def test_p_best_is_a_local_maximum():
    env, params = ops_jax.make(
        3, "hard", imperfections="lab", imperfection_scale=4.0, model="phasor"
    )
    lab = params.lab
    f = lambda x: (
        optics.measure(
            x,
            optics.rotation(lab.waveplate_error_deg),
            lab.pbs_leakage,
            optics.ideal_pulses(3),
            stages=3,
            model="phasor",
        ).power
    )
    assert float(f(jnp.zeros(3))) <= float(lab.p_best) * (1 + 1e-6) < env.p_max
    probes = jax.random.uniform(jax.random.key(0), (400, 3), minval=-0.3, maxval=0.3)
    assert float(jnp.max(f(probes))) <= float(lab.p_best) * (1 + 1e-5)


def test_p_best_is_reached_at_its_offsets():
    env, params = ops_jax.make(
        3, "hard", imperfections="lab", imperfection_scale=4.0, model="phasor"
    )
    lab = params.lab
    x = imperfections.best_offsets(env.config, lab)
    p = optics.measure(
        jnp.asarray(x),
        optics.rotation(lab.waveplate_error_deg),
        lab.pbs_leakage,
        optics.ideal_pulses(3),
        stages=3,
        model="phasor",
    ).power
    assert x.shape == (3,) and np.any(
        x != 0
    )  # the wave plate errors move the optimum off the ideal one
    assert float(p) == pytest.approx(float(lab.p_best), rel=1e-6)


def _held_bench(**values):
    """A 3-stage phasor bench with only ``values`` set."""
    return ops_jax.make(3, "hard", model="phasor", waveplate_error_deg=[2.0, -1.5, 1.0], **values)


def test_held_power_is_p_best_without_vibration_or_pulse_noise():
    env, params = _held_bench(backlash_wl=0.01, detector_gain_error=0.1, actuator_gain_error=0.2)
    for predict in (False, True):
        held = imperfections.held_power(
            env.config, params.lab, jax.random.key(0), 64, predict=predict
        )
        assert held == pytest.approx(float(params.lab.p_best), rel=1e-5)


def test_held_power_matches_lines_shaken_by_the_vibrations_law():
    """Held lines: P averaged over each line displaced by the vibration's stationary Gaussian law
    (total RMS); with the prediction taken off, by its one-step innovation alone (the background's
    first tap and each resonance's innovation)."""
    env, params = _held_bench(vib_rms=0.02, resonance_rms=[0.015, 0.01])
    lab = params.lab
    x = jnp.asarray(imperfections.best_offsets(env.config, lab))
    f = jax.vmap(
        lambda y: (
            optics.measure(
                y,
                optics.rotation(lab.waveplate_error_deg),
                lab.pbs_leakage,
                optics.ideal_pulses(3),
                stages=3,
                model="phasor",
            ).power
        )
    )
    z = jax.random.normal(jax.random.key(1), (20000, 3))
    _, _, gamma0, _ = vibration.ar2(jnp.asarray(lab.resonance_freq), jnp.asarray(lab.resonance_q))
    res = np.asarray(lab.resonance_rms)
    total = np.sqrt(float(lab.vib_rms) ** 2 + np.sum(res**2))
    innovation = np.sqrt(
        float(vibration.fir_taps(lab.vib_alpha, lab.vib_rms)[0]) ** 2
        + np.sum(res**2 / np.asarray(gamma0))
    )
    key = jax.random.key(2)
    held = imperfections.held_power(env.config, lab, key, 20000)
    predicted = imperfections.held_power(env.config, lab, key, 20000, predict=True)
    assert held == pytest.approx(float(jnp.mean(f(x + total * z))), rel=2e-3)
    assert predicted == pytest.approx(float(jnp.mean(f(x + innovation * z))), rel=2e-3)
    assert held < 0.97 * float(lab.p_best) and held < predicted < float(lab.p_best)


@pytest.mark.parametrize(
    "options, samples, match",
    [(dict(randomize=0.5), 8, "randomize"), (dict(), 0, "samples"), (dict(), 2.5, "samples")],
)
def test_held_power_refuses_what_it_cannot_hold(options, samples, match):
    env, params = _held_bench(vib_rms=0.01, **options)
    with pytest.raises(ValueError, match=match):
        imperfections.held_power(env.config, params.lab, jax.random.key(0), samples)


def test_held_power_refuses_a_batch_of_benches():
    env, params = _held_bench(vib_rms=0.01)
    batched = jax.tree.map(lambda v: np.stack([v, v]), params.lab)
    with pytest.raises(ValueError, match="one bench"):
        imperfections.held_power(env.config, batched, jax.random.key(0), 8)


HELD_BENCH = dict(stages=3, mode="hard", model="phasor", waveplate_error_deg=(2.0, -1.5, 1.0))
held_spec = lambda **options: ops_jax.EnvSpec(**{**HELD_BENCH, **options})


def test_ceilings_without_vibration_are_p_best():
    """No vibration, no pulse noise: lines held at the P_best offsets hold P_best, predicted or
    not (the other imperfections play no part)."""
    found = imperfections.ceilings(held_spec(backlash_wl=0.01), seed=0, samples=64)
    assert found.reason is None and found.samples == 64 and found.seed == 0
    assert found.held == pytest.approx(1.0, rel=1e-5)
    assert found.predicted == pytest.approx(1.0, rel=1e-5)


def test_ceilings_are_held_power_over_p_best_the_prediction_above_and_cached():
    """On a bench shaken by the 1/f background and two resonances (AR(2) processes): both ceilings
    are ``held_power`` over P_best from ``jax.random.key(seed)``, the prediction's above the held
    one; two equal specs give the one cached answer, another seed a close one."""
    options = dict(HELD_BENCH, vib_rms=0.02, resonance_rms=(0.015, 0.01))
    found = imperfections.ceilings(ops_jax.EnvSpec(**options), seed=3, samples=2048)
    env, params = ops_jax.make(**options)
    p_best, key = float(params.lab.p_best), jax.random.key(3)
    held = imperfections.held_power(env.config, params.lab, key, 2048) / p_best
    predicted = imperfections.held_power(env.config, params.lab, key, 2048, predict=True) / p_best
    assert found.held == pytest.approx(held, rel=1e-6)
    assert found.predicted == pytest.approx(predicted, rel=1e-6)
    assert found.held < 0.97 < found.predicted < 1.0
    again = imperfections.ceilings(ops_jax.EnvSpec.from_options(options), seed=3, samples=2048)
    assert again is found
    other = imperfections.ceilings(ops_jax.EnvSpec(**options), seed=4, samples=2048)
    assert other.held != found.held and other.held == pytest.approx(found.held, abs=0.02)
    assert found.fractions(0.95) == pytest.approx((0.95 / held, 0.95 / predicted))
    assert found.to_json() == dict(
        held_power=found.held, held_power_predicted=found.predicted, held_power_reason=None
    )


@pytest.mark.parametrize(
    "options, reason",
    [
        (ops_jax.EnvSpec(stages=3, mode="hard"), "the ideal system"),
        (held_spec(vib_rms=0.01, randomize=0.5), "randomised"),
    ],
)
def test_ceilings_of_no_one_imperfect_bench_are_none_with_the_reason(options, reason):
    found = imperfections.ceilings(options, seed=0, samples=8)
    assert found.held is None and found.predicted is None and reason in found.reason
    assert found.fractions(0.9) == (None, None)


@pytest.mark.parametrize(
    "kwargs, match",
    [(dict(seed=-1), "seed must be"), (dict(samples=0), "samples must"), (dict(seed=1.5), "seed")],
)
def test_ceilings_refuse_a_bad_seed_or_sample_count(kwargs, match):
    with pytest.raises(ValueError, match=match):
        imperfections.ceilings(held_spec(), **kwargs)


def test_ceilings_take_an_env_spec_not_a_dict():
    with pytest.raises(TypeError, match=r"spec must be an ops_jax.EnvSpec .*got dict"):
        imperfections.ceilings(HELD_BENCH)


@pytest.mark.parametrize(
    "bad, match",
    [
        (dict(pbs_leakage=0.7), "pbs_leakage"),
        (dict(vib_alpha=2.5), "vib_alpha"),
        (dict(waveplate_error_deg=[0.1, 0.2]), "waveplate_error_deg"),
        (dict(adc_bits=8.0), "adc_bits"),
        (dict(imperfections="mars"), "imperfections"),
        (dict(imperfection_scale=-1.0), "imperfection_scale"),
    ],
)
def test_bad_imperfections_fail_at_make(bad, match):
    with pytest.raises(ValueError, match=match):
        ops_jax.make(3, "hard", **bad)


def test_lab_info_reports_both_scores():
    env, params = ops_jax.make(3, "hard", imperfections="lab", model="phasor")
    assert env.config.imperfect
    obs, state = env.reset(jax.random.key(0), params)
    _, _, _, _, _, info = jax.jit(env.step)(jax.random.key(1), state, jnp.zeros(3), params)
    np.testing.assert_allclose(
        info["normalized_power_best"] * params.lab.p_best,
        info["normalized_power"] * env.p_max,
        rtol=1e-5,
    )


def test_options_pass_through_gymnasium_and_agents():
    import gymnasium

    import agents.api

    cfg = dict(stages=3, mode="hard", model="phasor", imperfections="lab", imperfection_scale=2.0)
    assert agents.api.check_env_config(cfg) == cfg
    env = gymnasium.make(
        "ops_jax/OPS-v0", stages=3, mode="hard", model="phasor", imperfections="lab"
    )
    assert env.unwrapped.env.config.imperfect
    obs, _ = env.reset(seed=0)
    obs2, reward, _, _, info = env.step(np.zeros(3, np.float32))
    assert obs2.shape == obs.shape and np.isfinite(reward)
    assert env.observation_space.contains(obs) and env.observation_space.contains(obs2)
    u = env.unwrapped
    p_best = float(u.params.lab.p_best)
    assert p_best < 0.999 * u.env.p_max  # the lab optics cannot reach P_max
    np.testing.assert_allclose(
        info["normalized_power_best"] * p_best, info["normalized_power"] * u.env.p_max, rtol=1e-5
    )
    venv = gymnasium.make_vec(
        "ops_jax/OPS-v0",
        num_envs=4,
        vectorization_mode="vector_entry_point",
        stages=3,
        mode="hard",
        model="phasor",
        imperfections="lab",
    )
    venv.reset(seed=0)
    infos = venv.step(np.zeros((4, 3), np.float32))[-1]
    assert infos["_normalized_power_best"].all()
    np.testing.assert_allclose(
        infos["normalized_power_best"] * p_best, infos["normalized_power"] * u.env.p_max, rtol=1e-5
    )
    with pytest.raises(ValueError, match="imperfections"):
        gymnasium.make("ops_jax/OPS-v0", stages=3, imperfections="moon")


def test_randomize_draws_each_episodes_imperfections():
    env, p0 = ops_jax.make(3, "hard", imperfections="lab", model="phasor")
    _, p1 = ops_jax.make(3, "hard", imperfections="lab", model="phasor", randomize=1.0)
    reset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    keys = jax.random.split(jax.random.key(0), 256)
    fixed = reset(keys, p0)[1].lab.values
    drawn = reset(keys, p1)[1].lab.values
    for name in imperfections.SCALED:
        v = np.asarray(getattr(p0.lab, name))
        np.testing.assert_array_equal(
            getattr(fixed, name), np.broadcast_to(v, getattr(fixed, name).shape)
        )
        d = np.asarray(getattr(drawn, name))
        assert np.all(np.abs(d) <= 2 * np.abs(v) * (1 + 1e-6)) and np.all(d * v >= 0)
        if np.any(v != 0):
            assert np.std(d, axis=0).max() > 0.3 * np.abs(v).max()  # U[-1, 1) spread: std 0.58 v
    with pytest.raises(ValueError, match="randomize"):
        ops_jax.make(3, "hard", imperfections="lab", randomize=1.5)


def test_randomize_layout_redraws_the_signed_per_stage_patterns():
    env, p0 = ops_jax.make(5, "hard", imperfections="lab", model="phasor")
    _, p1 = ops_jax.make(5, "hard", imperfections="lab", model="phasor", randomize_layout=1.0)
    _, p_half = ops_jax.make(5, "hard", imperfections="lab", model="phasor", randomize_layout=0.5)
    reset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    keys = jax.random.split(jax.random.key(0), 512)
    fixed, drawn, half = (reset(keys, p)[1].lab.values for p in (p0, p1, p_half))
    assert set(imperfections.LAYOUT) == {
        "waveplate_error_deg",
        "readout_offset",
        "readout_gain_error",
        "actuator_gain_error",
    }
    for name in imperfections.FIELDS:
        v = np.asarray(getattr(p0.lab, name))
        np.testing.assert_array_equal(
            getattr(fixed, name), np.broadcast_to(v, getattr(fixed, name).shape)
        )
        d = np.asarray(getattr(drawn, name))
        if name not in imperfections.LAYOUT:
            np.testing.assert_array_equal(d, np.broadcast_to(getattr(p1.lab, name), d.shape))
            continue
        np.testing.assert_allclose(
            np.sort(np.abs(d), axis=1), np.broadcast_to(np.sort(np.abs(v)), d.shape)
        )  # a layout
        assert np.mean(np.any(d != v, axis=1)) > 0.95 and np.mean(d < 0) == pytest.approx(
            0.5, abs=0.05
        )
        changed = np.mean(np.any(np.asarray(getattr(half, name)) != v, axis=1))
        assert 0.42 < changed < 0.58  # drawn in half the episodes
    with pytest.raises(ValueError, match=r"randomize_layout must be a finite number in \[0, 1\]"):
        ops_jax.make(3, "hard", imperfections="lab", randomize_layout=1.5)


def test_reality_report_writes_table_csv_and_figure(tmp_path):
    from benchmarks.sweep import reality

    results = {
        "spgd/ideal": {"none": [0.99, 0.98], "lab": [0.97, 0.96], "2x lab": [0.9, 0.91]},
        "ppo/randomised": {"none": [0.9, 0.7], "lab": [0.5, 0.6], "2x lab": [0.4, 0.45]},
    }
    ideal = imperfections.Ceilings(None, None, "the ideal system", 64, 0)
    ceilings = {
        "none": ideal,
        "lab": imperfections.Ceilings(0.98, 0.99, None, 64, 0),
        "2x lab": imperfections.Ceilings(0.95, 0.98, None, 64, 0),
    }
    reality.report(
        tmp_path,
        results,
        dict(seeds=2, episodes=8),
        "python -m benchmarks.sweep --only reality",
        60.0,
        ceilings=ceilings,
    )
    md = (tmp_path / "reality.md").read_text()
    assert "| SPGD (ideal) | 0.9850 ± 0.0050 |" in md and "PPO (randomised)" in md
    assert "**" not in md and "No bold: 2 seeds" in md  # too few seeds to tell values apart
    # against the ceilings: SPGD's lab mean 0.965 over 0.98 and 0.99; none at the ideal level
    assert "| SPGD (ideal) | lab | 0.9650 | 0.9800 | 0.9900 | 0.9847 | 0.9747 |" in md
    assert "| PPO (randomised) | 2x lab | 0.4250 | 0.9500 | 0.9800 | 0.4474 | 0.4337 |" in md
    assert "| SPGD (ideal) | none | 0.9850 | – | – | – | – |" in md
    assert "none: the ideal system" in md and "64 draws from seed 0" in md
    rows = (tmp_path / "reality.csv").read_text().splitlines()
    assert (
        rows[0]
        == "controller,trained,level,mean,std,seeds,iqm,iqm_ci_lo,iqm_ci_hi,held,predicted,"
        "mean_over_held,mean_over_predicted"
        and len(rows) == 7
    )
    assert rows[1].endswith(",,,,") and rows[2].endswith(",0.980000,0.990000,0.984694,0.974747")
    assert (tmp_path / "reality.png").stat().st_size > 1000


def test_imperfection_levels_share_one_compiled_step():
    env, p1 = ops_jax.make(3, "hard", imperfections="lab", model="phasor")
    _, p2 = ops_jax.make(
        3, "hard", imperfections="lab", imperfection_scale=2.0, model="phasor", randomize=0.5
    )
    traces = []

    @jax.jit
    def step(key, state, params):
        traces.append(1)
        return env.step(key, state, jnp.zeros(3), params)

    for p in (p1, p2, p1):
        _, state = env.reset(jax.random.key(0), p)
        step(jax.random.key(1), state, p)
    assert len(traces) == 1


def test_imperfection_groups_cover_every_scaled_error_and_remove_only_their_own():
    """``benchmarks.imperfection_groups``: every error magnitude of the lab preset belongs to a
    group, and a bench without a group has that group's fields at their ideal values and every other
    field as before."""
    from benchmarks.imperfection_groups import GROUPS, bench, without

    grouped = {k for fields in GROUPS.values() for k in fields}
    lab = imperfections.preset("lab", 5)
    assert {k for k in lab if k in imperfections.SCALED} <= grouped
    env = bench(1011, 2.0, unseen=True, lengths=False)
    assert env["probe"] == "instant" and bench(1011, 2.0, True, False, "frame") == dict(
        env, probe="frame"
    )
    for group, fields in GROUPS.items():
        changed = without(env, group)
        built = ops_jax.make(**changed)[1].lab
        for k in fields:
            assert np.all(
                np.asarray(getattr(built, k))
                == np.asarray(getattr(imperfections.Imperfections(), k))
            ), k
        kept = ops_jax.make(**env)[1].lab
        for k in imperfections.SCALED:
            if k not in fields:
                np.testing.assert_array_equal(
                    np.asarray(getattr(built, k)), np.asarray(getattr(kept, k)), err_msg=k
                )


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--scale", "0"], "--scale"),
        (["--episodes", "0"], "--episodes"),
        (["--set", "starts"], "key=value"),
        (["--policy", "/nonexistent"], "--policy"),
        (["--set", "nonsense=1"], "nonsense"),
        (["--probe", "later"], "--probe"),
    ],
)
def test_imperfection_groups_refuses_bad_arguments_naming_them(argv, needle, capsys):
    from benchmarks import imperfection_groups

    with pytest.raises(SystemExit):
        imperfection_groups.main(argv)
    assert needle in capsys.readouterr().err


def test_imperfection_groups_ceiling_columns(tmp_path, capsys):
    """``--ceiling``: each bench's held and predicted ceilings, in its row and in the table."""
    from benchmarks import imperfection_groups

    result = imperfection_groups.main(
        [
            "--algo",
            "spgd",
            "--benches",
            "1011",
            "--episodes",
            "1",
            "--groups",
            "--ceiling",
            "--out",
            str(tmp_path),
        ]
    )
    (row,) = result["rows"]
    assert 0.9 < row["held"] < row["predicted"] < 1.0
    assert "| bench | all | held | predicted |" in capsys.readouterr().out
    assert (tmp_path / "imperfection_groups.json").is_file()
