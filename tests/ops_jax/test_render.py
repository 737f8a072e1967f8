"""Pictures: oscilloscope frames (env.render), the episode GIF CLI, the objective landscape."""

import sys

import gymnasium
import numpy as np
import pytest
from PIL import Image

import ops_jax  # noqa: F401  (registers the gymnasium env)
from agents import episode
from ops_jax import physics, render


def _not_blank(frame):
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.shape[0] >= 200 and frame.shape[1] >= 300
    assert frame.std() > 10  # not a single colour
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 20


def test_oscilloscope_frame_depends_on_state():
    scope = render.Oscilloscope(3)
    stacked = scope.frame(np.zeros(3), step=0)
    _not_blank(stacked)
    scattered = scope.frame(np.array([0.25, 0.1, 0.0]), step=1)
    assert stacked.shape == scattered.shape
    assert np.mean(np.any(stacked != scattered, axis=-1)) > 0.005  # the curve and title changed


def test_measure_frames_normalisation():
    p, intensity = render.measure_frames(np.zeros((1, 4)), 4)
    np.testing.assert_allclose(p, 1.0, atol=1e-5)  # optimum: P = Pmax
    np.testing.assert_allclose(intensity.max(), 1.0, atol=1e-3)  # ideal stacked peak
    assert intensity.shape == (1, physics.grid(4).n)
    with pytest.raises(ValueError, match="deltas_wl"):
        render.measure_frames(np.zeros((2, 3)), 4)


def test_gym_render_rgb_array_and_headless_human(monkeypatch):
    env = gymnasium.make(
        "ops_jax/OPS-v0", stages=3, mode="easy", render_mode="rgb_array", model="phasor"
    )
    env.reset(seed=0)
    first = env.render()
    _not_blank(first)
    for _ in range(3):
        env.step(np.ones(3, np.float32))
    assert np.any(env.render() != first)  # the step number in the title at least
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    human = gymnasium.make(
        "ops_jax/OPS-v0", stages=3, mode="easy", render_mode="human", model="phasor"
    )
    human.reset(seed=0)
    assert human.render() is None
    human.step(np.zeros(3, np.float32))


def test_vector_render_one_frame_per_instance():
    envs = gymnasium.make_vec(
        "ops_jax/OPS-v0",
        num_envs=2,
        vectorization_mode="vector_entry_point",
        stages=2,
        render_mode="rgb_array",
        model="phasor",
    )
    envs.reset(seed=0)
    frames = envs.render()
    assert len(frames) == 2
    for f in frames:
        _not_blank(f)


def test_episode_gif_cli(tmp_path):
    out = tmp_path / "ep.gif"
    episode.main(
        ["--stages", "3", "--mode", "hard", "--policy", "random", "--steps", "5", "--out", str(out)]
    )
    im = Image.open(out)
    assert im.n_frames == 6  # reset + 5 steps
    im.seek(3)
    assert np.asarray(im.convert("RGB")).std() > 10


def test_frame_cli_and_zero_policy(tmp_path):
    out = tmp_path / "scope.png"
    episode.main(
        [
            "frame",
            "--stages",
            "3",
            "--mode",
            "easy",
            "--policy",
            "zero",
            "--steps",
            "2",
            "--out",
            str(out),
        ]
    )
    _not_blank(np.asarray(Image.open(out).convert("RGB")))
    policy, params, cfg = episode.get_policy(
        "zero", dict(stages=3, mode="easy", obs_noise=0.0, step_sigma=0.0)
    )
    ep = episode.run_episode(cfg, policy, params, steps=4)
    assert ep.deltas_wl.shape == (5, 3)
    np.testing.assert_allclose(
        ep.deltas_wl[1:], ep.deltas_wl[:1].repeat(4, 0), atol=1e-6
    )  # no noise, no action


def test_policy_errors(tmp_path):
    with pytest.raises(ValueError, match="checkpoint"):
        episode.get_policy(str(tmp_path / "missing"), dict(stages=3))


def test_landscape_periodic_and_peaked():
    x = np.linspace(-1.0, 1.0, 161)
    p = render.landscape(2, 1, x)
    np.testing.assert_allclose(p, render.landscape(2, 1, x + 0.5), atol=1e-4)  # period wl / 2
    assert abs(p[80] - 1.0) < 1e-5 and p.min() < 0.5  # optimum at 0, deep valleys
    np.testing.assert_allclose(p, p[::-1], atol=1e-4)  # symmetric about the optimum
    q = render.landscape(3, [1, 2], x[::8])
    assert q.shape == (21, 21)
    np.testing.assert_allclose(
        q[10], render.landscape(3, 1, x[::8]), atol=1e-6
    )  # row: stage 2 at 0
    np.testing.assert_allclose(q, render.landscape(3, [1, 2], x[::8] + 0.5), atol=1e-4)


def test_landscape_in_chunks_equals_one_call(monkeypatch):
    """The offsets computed a chunk at a time (the last one padded) give what one call gives, to
    float32 rounding."""
    x = np.linspace(-1.0, 1.0, 23)
    whole = render.landscape(3, [1, 2], x)
    landscape_module = sys.modules[render.landscape.__module__]  # where landscape reads the chunk
    monkeypatch.setattr(
        landscape_module, "LANDSCAPE_CHUNK", 50
    )  # 529 offsets: 10 chunks and a padded one
    np.testing.assert_allclose(
        render.landscape(3, [1, 2], x), whole, atol=1e-6
    )  # float32: batch size moves an ulp


def test_landscape_last_stage_needs_polariser():
    x = np.linspace(-0.5, 0.5, 11)
    total = render.landscape(2, [1, 2], x)
    assert np.ptp(total, axis=0).max() < 1e-4  # total detector: last stage's phase invisible
    pol = render.landscape(2, [1, 2], x, detector="polariser")
    assert np.ptp(pol, axis=0).max() > 0.5


def test_landscape_bad_input_and_png(tmp_path):
    with pytest.raises(ValueError, match="stage"):
        render.landscape(2, 3, np.zeros(3))
    with pytest.raises(ValueError, match="stage"):
        render.landscape(3, [1, 1], np.zeros(3))
    with pytest.raises(ValueError, match="span"):
        render.plot_landscape(2, 1, span=0.0)
    out = tmp_path / "l2.png"
    render.main(
        ["landscape", "--stages", "3", "--stage", "1", "2", "--points", "41", "--out", str(out)]
    )
    _not_blank(np.asarray(Image.open(out).convert("RGB")))


def test_episode_frames_progress_is_plain_lines_off_a_terminal(capsys):
    """Under pytest stderr is no terminal: the frame progress is plain lines, no carriage
    returns."""
    policy, params, cfg = episode.get_policy("zero", dict(stages=3, mode="easy"))
    ep = episode.run_episode(cfg, policy, params, steps=3)
    frames = render.episode_frames(ep)
    err = capsys.readouterr().err
    assert len(frames) == 4 and "\r" not in err
    assert err.strip().splitlines()[-1].startswith("frames: 4/4 frame (100%)")
