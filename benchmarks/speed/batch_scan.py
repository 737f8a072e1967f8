"""Batch scans under a deadline, for ``benchmarks.speed.device``: the batch sizes, and per (model,
stages) configuration a doubling of the batch until its share of the time (seconds) or the device's
memory ends; XLA's out-of-memory errors told apart from the others."""

from __future__ import annotations

import time

# A (model, stages) configuration's weight in the split of a scan section's time (others: 1).
CONFIG_WEIGHTS = {("phasor", 5): 3.0}
MIN_SECTION_S = 5.0  # s: a section, or a scanned configuration, with less time left is skipped


def batches(tiny: bool, exps=None) -> list[int]:
    """The scanned batch sizes: 2^lo .. 2^hi in steps of 2^stride, ``exps`` = (lo, hi[, stride])
    (default 2^4 .. 2^6 with ``tiny``, else 2^10 .. 2^20)."""
    lo, hi, stride = (*(exps or ((4, 6) if tiny else (10, 20))), 1)[:3]
    return [2**k for k in range(lo, hi + 1, stride)]


def is_oom(err: BaseException) -> bool:
    """True for XLA's out-of-memory errors (RESOURCE_EXHAUSTED)."""
    text = f"{type(err).__name__}: {err}"
    return (
        "RESOURCE_EXHAUSTED" in text
        or "out of memory" in text.lower()
        or isinstance(err, MemoryError)
    )


def short_error(err: BaseException, limit: int = 600) -> str:
    """The first ``limit`` characters of ``type: message``."""
    text = f"{type(err).__name__}: {err}".strip()
    return text if len(text) <= limit else text[:limit] + " ..."


def _scan_batches(
    measure_one, model: str, n: int, batch_list, cfg_deadline: float, record, out: dict, s: dict
) -> None:
    """``measure_one(model, n, batch)`` over ``batch_list`` into ``out["rows"]`` and the config's
    summary ``s`` until the next batch would pass ``cfg_deadline`` or the device runs out of
    memory."""
    import gc

    for b in batch_list:
        t0 = time.monotonic()
        out["running"] = dict(model=model, stages=n, batch=b)
        try:
            row = measure_one(model, n, b)
        except Exception as err:  # noqa: BLE001 (out of memory ends the scan; anything else is recorded)
            out.pop("running", None)
            gc.collect()
            s["stopped"] = "oom" if is_oom(err) else "error"
            s["oom_at_batch" if is_oom(err) else "error"] = b if is_oom(err) else short_error(err)
            break
        out.pop("running", None)
        cost = time.monotonic() - t0
        row["wall_s"] = cost
        out["rows"].append(row)
        s["batches"].append(b)
        if s["best_steps_per_s"] is None or row["steps_per_s"] > s["best_steps_per_s"]:
            s["best_steps_per_s"], s["best_batch"] = row["steps_per_s"], b
        record(out)
        print(
            f"  {model} N={n} batch {b}: {row['steps_per_s']:,.0f} env-steps/s "
            f"(compile {row['compile_s']:.1f} s)",
            flush=True,
        )
        compile_s = min(row["compile_s"], cost)
        grow = 1.1 * (batch_list[batch_list.index(b) + 1] / b if b != batch_list[-1] else 1)
        if (
            b != batch_list[-1]
            and time.monotonic() + compile_s + grow * (cost - compile_s) > cfg_deadline
        ):
            s["stopped"] = "budget"
            break


def scan(measure_one, configs, batch_list, deadline: float, record, out: dict) -> None:
    """For each (model, stages) of ``configs``, ``measure_one(model, stages, batch) -> row`` over
    ``batch_list`` until the next batch would pass the config's share of the time to ``deadline`` or
    the device runs out of memory; rows and a summary per config go into ``out`` (saved by
    ``record``)."""
    out.setdefault("rows", [])
    summary = out.setdefault("configs", [])
    out["planned"] = [dict(model=m, stages=n) for m, n in configs]
    record(out)
    weights = [CONFIG_WEIGHTS.get(c, 1.0) for c in configs]
    for i, (model, n) in enumerate(configs):
        t_cfg = time.monotonic()
        if deadline - t_cfg < MIN_SECTION_S:
            break
        cfg_deadline = t_cfg + (deadline - t_cfg) * weights[i] / sum(weights[i:])
        s = dict(
            model=model,
            stages=n,
            batches=[],
            best_steps_per_s=None,
            best_batch=None,
            oom_at_batch=None,
            stopped="end",
            error=None,
        )
        summary.append(s)
        _scan_batches(measure_one, model, n, batch_list, cfg_deadline, record, out, s)
        record(out)
