"""benchmarks.speed.device at test sizes on the CPU: the JSON's keys and statuses, a failing section
recorded as failed while the others still write, sections skipped when the budget is spent, the
default output path per platform; the sweep's workers sharing one GPU by memory fraction."""

import json

import pytest

from benchmarks.speed import batch_scan, device
from benchmarks.sweep.executor import worker_env

TOP_KEYS = {
    "device",
    "jax",
    "date",
    "host",
    "command",
    "phasor_n5_steps_per_s",
    "sections",
    "budget_s",
    "finished",
}


def test_tiny_run_writes_every_section_with_its_status(tmp_path):
    out = tmp_path / "device.json"
    doc = device.main(
        [
            "--tiny",
            "--models",
            "phasor",
            "--batch-exp",
            "4",
            "4",
            "--repeats",
            "1",
            "--sections",
            "step_batch",
            "no_such_section",
            "--out",
            str(out),
        ]
    )
    stored = json.loads(out.read_text())
    assert stored == json.loads(json.dumps(doc, default=float))
    assert TOP_KEYS <= set(stored) and stored["finished"]
    assert stored["device"]["platform"] == "cpu" and stored["jax"]
    sb = stored["sections"]["step_batch"]
    assert sb["status"] == "ok" and sb["error"] is None and sb["wall_s"] > 0
    (row,) = sb["rows"]
    assert (row["model"], row["stages"], row["batch"]) == ("phasor", 5, 16)
    assert row["steps_per_s"] > 0 and row["compile_s"] >= 0
    assert sb["configs"][0]["oom_at_batch"] is None and sb["configs"][0]["stopped"] == "end"
    assert stored["phasor_n5_steps_per_s"] == row["steps_per_s"]
    bad = stored["sections"]["no_such_section"]
    assert bad["status"] == "failed" and "unknown section" in bad["error"]
    table = device.compare_table([stored, stored])
    assert (
        f"| step_batch, phasor N = 5: env-steps/s | {row['steps_per_s']:,.0f} (batch 16) |" in table
    )


def test_sections_past_the_budget_are_skipped_and_still_written(tmp_path):
    out = tmp_path / "device.json"
    device.main(["--tiny", "--budget-s", "1", "--sections", "rollout", "droq", "--out", str(out)])
    stored = json.loads(out.read_text())
    assert [s["status"] for s in stored["sections"].values()] == ["skipped", "skipped"]
    assert stored["phasor_n5_steps_per_s"] is None and stored["finished"]


def test_scan_records_where_memory_ends_and_keeps_the_rows_before():
    saved = []

    def fake(model, n, b):
        if b >= 64:
            raise RuntimeError(
                "RESOURCE_EXHAUSTED: Out of memory while trying to allocate 1 bytes."
            )
        return dict(model=model, stages=n, batch=b, compile_s=0.0, steps_per_s=float(b))

    out = {}
    batch_scan.scan(fake, [("phasor", 5)], batch_scan.batches(True), 1e18, saved.append, out)
    (cfg,) = out["configs"]
    assert cfg["batches"] == [16, 32] and cfg["oom_at_batch"] == 64 and cfg["stopped"] == "oom"
    assert cfg["best_batch"] == 32 and saved


def test_default_output_path_follows_the_platform(tmp_path):
    assert (
        device.default_out("cpu", tmp_path)
        == tmp_path / "benchmarks" / "measured" / "device-cpu.json"
    )
    assert (
        device.default_out("gpu", tmp_path) == tmp_path / "benchmarks" / "measured" / "device.json"
    )
    assert batch_scan.batches(False)[0] == 2**10 and batch_scan.batches(False)[-1] == 2**20
    assert batch_scan.batches(False, (10, 20, 2)) == [2**k for k in (10, 12, 14, 16, 18, 20)]


@pytest.mark.parametrize(
    "n, gpus, local, fraction",
    [
        (2, 0.0, True, "0.450"),
        (1, 0.0, True, "0.900"),
        (4, 0.25, False, "0.225"),
        (2, 1.0, False, None),
    ],
)
def test_sweep_workers_share_a_gpu_by_memory_fraction(n, gpus, local, fraction):
    env = worker_env(n, gpus, local, environ={"XLA_FLAGS": "--x"})
    assert env["XLA_PYTHON_CLIENT_PREALLOCATE"] == "false" and env["XLA_FLAGS"] == "--x"
    assert env.get("XLA_PYTHON_CLIENT_MEM_FRACTION") == fraction
    assert (
        worker_env(2, 0.0, True, environ={"XLA_PYTHON_CLIENT_MEM_FRACTION": "0.3"})[
            "XLA_PYTHON_CLIENT_MEM_FRACTION"
        ]
        == "0.3"
    )
