"""TensorBoard scalars of a training curve (agents.tensorboard): written by tensorboardX, read back
by tensorboard's own EventAccumulator with the values and env steps that went in."""

import sys

import numpy as np
import pytest

from agents.tensorboard import TensorBoardLogger, tag


def read_scalars(logdir) -> dict:
    """{tag: (steps, values)} of the event files in ``logdir``, read by tensorboard's
    EventAccumulator."""
    event_accumulator = pytest.importorskip(
        "tensorboard.backend.event_processing.event_accumulator"
    )
    acc = event_accumulator.EventAccumulator(str(logdir))
    acc.Reload()
    return {
        t: ([e.step for e in acc.Scalars(t)], [e.value for e in acc.Scalars(t)])
        for t in acc.Tags()["scalars"]
    }


def test_logger_writes_every_finite_metric_against_env_steps(tmp_path):
    pytest.importorskip("tensorboardX")
    seen = []
    curve = [(1024, 0.41, None), (2048, 0.63, 1.7), (4096, 0.88, 0.9)]
    with TensorBoardLogger(tmp_path / "tb", then=lambda s, m: seen.append(s)) as log:
        for step, power, loss in curve:
            metrics = {
                "normalized_power": power,
                "elapsed_s": step / 1000,
                "update_ratio": 0.25,
                "flag": True,
                "critic_loss": float("nan") if loss is None else loss,
            }
            log(step, metrics)
    assert seen == [1024, 2048, 4096]
    scalars = read_scalars(tmp_path / "tb")
    assert set(scalars) == {
        "eval/normalized_power",
        "time/elapsed_s",
        "train/update_ratio",
        "loss/critic_loss",
    }
    steps, values = scalars["eval/normalized_power"]
    assert steps == [1024, 2048, 4096]
    np.testing.assert_allclose(values, [0.41, 0.63, 0.88], rtol=1e-6)
    assert scalars["loss/critic_loss"][0] == [2048, 4096]  # NaN (no update yet) is left out


def test_tags_group_the_metrics():
    assert [
        tag(n)
        for n in ("normalized_power", "normalized_power_best", "policy_loss", "reward", "elapsed_s")
    ] == [
        "eval/normalized_power",
        "eval/normalized_power_best",
        "loss/policy_loss",
        "train/reward",
        "time/elapsed_s",
    ]


def test_missing_tensorboardx_names_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "tensorboardX", None)
    with pytest.raises(ImportError, match=r'pip install -e "\.\[tensorboard\]"'):
        TensorBoardLogger(tmp_path)


def test_cli_logdir_without_tensorboardx_is_one_line(tmp_path):
    """``python -m agents --logdir`` without the tensorboard extra stops before training, in one
    line."""
    import os
    import subprocess
    from pathlib import Path

    (tmp_path / "sitecustomize.py").write_text("import sys\nsys.modules['tensorboardX'] = None\n")
    repo = Path(__file__).resolve().parents[2]
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "agents",
            "--algo",
            "spgd",
            "--stages",
            "2",
            "--out",
            "run",
            "--logdir",
            "tb",
        ],
        capture_output=True,
        text=True,
        timeout=180,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": f"{tmp_path}{os.pathsep}{repo}"},
    )
    assert out.returncode == 1 and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert (
        out.stderr.strip().endswith('pip install -e ".[tensorboard]"')
        and not (tmp_path / "run").exists()
    )
