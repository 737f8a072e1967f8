"""``agents.bench.documents``: a run's Bluesky documents (start, descriptor, an event page, stop),
numbers that are not finite among them, written one a line, each line strict JSON (parsed with
``parse_constant`` refusing NaN and Infinity), the not-finite numbers null with a reason."""

import json
import math

import numpy as np
import pytest

pytest.importorskip("event_model")

import event_model  # noqa: E402

from agents.bench import documents  # noqa: E402


def reject(constant: str):
    raise ValueError(f"not strict JSON: {constant}")


def _run_documents():
    """(name, document) of a run whose metadata, descriptor and events hold NaN and infinities."""
    run = event_model.compose_run(metadata={"plan_name": "t", "hyper": {"gain": math.inf}})
    keys = {
        "power": {"source": "sim", "dtype": "number", "shape": [], "upper_ctrl_limit": math.nan},
        "probes": {"source": "sim", "dtype": "array", "shape": [2]},
    }
    desc = run.compose_descriptor(name="primary", data_keys=keys)
    page = desc.compose_event_page(
        data={
            "power": [0.5, math.nan],
            "probes": [np.array([0.1, np.nan]), np.array([-np.inf, 2])],
        },
        timestamps={"power": [1.0, 2.0], "probes": [1.0, 2.0]},
        seq_num=[1, 2],
        time=[1.0, 2.0],
    )
    stop = run.compose_stop(exit_status="abort", reason="watchdog")
    return [("start", run.start_doc), ("descriptor", desc.descriptor_doc)] + [
        ("event_page", page),
        ("stop", stop),
    ]


def test_every_line_of_the_documents_is_strict_json(tmp_path):
    write = documents.writer(tmp_path)
    for name, doc in _run_documents():
        write(name, doc)
    lines = (tmp_path / documents.NAME).read_text().splitlines()
    parsed = [json.loads(line, parse_constant=reject) for line in lines]
    assert [p["name"] for p in parsed] == ["start", "descriptor", "event", "event", "stop"]
    start, descriptor, first, second, _ = (p["doc"] for p in parsed)
    assert start["hyper"] == {"gain": None, "gain_reason": "+infinite"}, start
    power_key = descriptor["data_keys"]["power"]
    assert power_key["upper_ctrl_limit"] is None and "upper_ctrl_limit_reason" in power_key
    assert first["data"]["power"] == 0.5 and first["data"]["probes"] == [0.1, None]
    assert first["data"]["probes_reason"] == "its nulls: not a number (NaN)", first
    assert second["data"]["power"] is None and second["data"]["probes"] == [None, 2.0], second
    assert [first["seq_num"], second["seq_num"]] == [1, 2]


def test_a_resumed_run_appends_and_another_starts_afresh(tmp_path):
    path = tmp_path / documents.NAME
    path.write_text('{"name": "start"}\n{"name": "ev')  # a kill mid-line
    documents.begin(tmp_path, resume=True)
    assert path.read_text() == '{"name": "start"}\n'
    documents.writer(tmp_path)("stop", {"uid": "u", "time": 1.0, "run_start": "s"})
    assert len(path.read_text().splitlines()) == 2
    documents.begin(tmp_path, resume=False)
    assert not path.exists()
