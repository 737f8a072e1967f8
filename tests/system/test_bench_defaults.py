"""A lab's first hour on the bench: what the runner chooses on a bench without length readouts (and
says so in its first line), the template mapping and its check against a live IOC, a controller's
progress line and readable summary. The end-to-end tests start a real IOC (frames only: no length
readouts) on a free localhost port, and runner subprocesses against it, every wait bounded."""

import json
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("caproto")
pytest.importorskip("ophyd")
pytest.importorskip("bluesky")

from agents.bench import cli, defaults, runner, template  # noqa: E402
from agents.bench.mapping import MappingError, check_mapping, sim_mapping  # noqa: E402
from benchmarks.lab import Process, ca_env  # noqa: E402

START_S = 240  # an IOC or runner start-up on a loaded 2-core machine (JAX import and compile)
PREFIX = "FO:"


def chosen(argv: list, mapping: dict) -> tuple:
    """``defaults.choose`` of the runner's arguments ``argv`` on ``mapping``: (--set items, wrap
    (wl), line)."""
    args = cli.parser().parse_args([*argv, "--out", "unused"])
    if args.wrap is not None:
        mapping = {**mapping, "safety": {**mapping.get("safety", {}), "wrap_wl": args.wrap}}
    items, resolved, line = defaults.choose(args, check_mapping(mapping))
    return items, resolved["safety"]["wrap_wl"], line


# -- the defaults (no Channel Access)
# ---------------------------------------------------------------


def test_a_bench_without_length_readouts_chooses_the_frames_configurations_and_the_wrap():
    frames = sim_mapping("T:", 3, lengths=False)
    items, wrap, line = chosen(["--controller", "physics"], frames)
    assert items == ["config=frames"] and wrap == 0.5, (items, wrap)
    assert "config=frames" in line and "no length readouts" in line and "0.5 wl" in line, line
    items, wrap, line = chosen(["--learn", "droq", "--steps", "9"], frames)
    assert items == ["config=bench"] and wrap == 0.5 and "bench preset" in line, (items, line)
    items, _, line = chosen(["--learn", "td3", "--steps", "9"], frames)
    assert items == [] and "td3 has no bench preset" in line, (items, line)


def test_an_explicit_setting_or_wrap_wins_over_the_defaults():
    frames = sim_mapping("T:", 3, lengths=False)
    items, wrap, line = chosen(["--controller", "physics", "--set", "use_lengths=True"], frames)
    assert items == ["use_lengths=True"] and wrap is None and "reads the length readouts" in line
    items, _, _ = chosen(["--learn", "droq", "--steps", "9", "--set", "config=budget"], frames)
    assert items == ["config=budget"]
    items, wrap, line = chosen(["--controller", "physics", "--wrap", "0"], frames)
    assert items == ["config=frames"] and wrap is None and "0.5 wl" not in line, line
    _, wrap, line = chosen(["--controller", "spgd", "--wrap", "0.25"], frames)
    assert wrap == 0.25 and line is None
    _, wrap, line = chosen(["--controller", "spgd"], {**frames, "safety": {"wrap_wl": 0}})
    assert wrap is None and line is None


def test_the_wrap_is_left_out_where_it_would_not_be_safe():
    """With the length readouts a controller reads (they jump at a wrap), on a soft range under
    three periods, or without a declared period: no wrap, and the line says why (nothing to say
    without a period)."""
    lengths = sim_mapping("T:", 3)
    items, wrap, line = chosen(["--controller", "physics"], lengths)
    assert items == [] and wrap is None and "physics reads the length readouts" in line, line
    _, wrap, _ = chosen(["--controller", "spgd"], lengths)
    assert wrap == 0.5
    narrow = {**lengths, "safety": {"soft_range_wl": [-0.5, 0.5]}}
    _, wrap, line = chosen(["--controller", "spgd"], narrow)
    assert wrap is None and "under three periods" in line, line
    _, wrap, line = chosen(["--controller", "spgd"], {**lengths, "period_wl": None})
    assert wrap is None and line is None


def test_the_template_is_the_simulated_benchs_mapping_with_notes():
    written = template.template("OPS:", 5, lengths=False)
    assert all(key in written for key in ("_about", "_lines", "_safety", "period_wl"))
    assert check_mapping(written) == check_mapping(sim_mapping("OPS:", 5, lengths=False))
    assert check_mapping(json.loads(json.dumps(written)))["period_wl"] == 0.5
    with pytest.raises(MappingError, match="period_wl"):
        check_mapping({**written, "period_wl": -1})
    with pytest.raises(MappingError, match="perod_wl"):
        check_mapping({**written, "perod_wl": 0.5})


# -- a live bench
# ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ioc(tmp_path_factory):
    """A free-running simulated bench without length readouts (3 stages, 100 ticks per second)."""
    tmp = tmp_path_factory.mktemp("ioc")
    args = ["--prefix", PREFIX, "--stages", "3", "--mode", "hard", "--model", "phasor"]
    args += ["--rate", "100", "--observe-lengths", "False", "--tick-log", tmp / "ticks.jsonl"]
    proc = Process("ops_jax.ioc", args, ca_env(), tmp / "ioc.log")
    try:
        yield proc.wait_for("serving", START_S)
    finally:
        proc.kill()


def runner_lines(text: str) -> list:
    return [line for line in text.splitlines() if line.startswith("agents.bench.runner:")]


def test_physics_on_a_frames_only_bench_runs_its_frames_configuration_and_says_so(ioc, tmp_path):
    """No --set, no --wrap: the first line names the frames configuration and the wrap, the run's
    start document records them, a progress line shows the steps, and the run ends with a readable
    summary (no JSON dump)."""
    env = {**ioc.env, "OPS_JAX_PROGRESS_INTERVAL": "1"}
    args = ["--prefix", PREFIX, "--stages", "3", "--no-lengths", "--controller", "physics"]
    args += ["--set", "starts=2", "--seconds", "4", "--stale-s", "5", "--out", tmp_path / "out"]
    proc = Process("agents.bench", args, env, tmp_path / "runner.log")
    rc, log = proc.wait(START_S), proc.text()
    assert rc == 0, log
    first = runner_lines(log)[0]
    assert first.startswith(
        "agents.bench.runner: starting: chosen: physics with its frames configuration"
    ), log
    assert "no length readouts" in first and "wrapped at the optics' period, 0.5 wl" in first, first
    docs = [json.loads(line) for line in (tmp_path / "out" / "documents.jsonl").open()]
    start = next(d["doc"] for d in docs if d["name"] == "start")
    assert start["hyper"] == {"starts": 2, "config": "frames"}, start["hyper"]
    assert start["mapping"]["safety"]["wrap_wl"] == 0.5 and start["mapping"]["period_wl"] == 0.5
    progress = [
        line for line in log.splitlines() if line.startswith("physics: ") and " step/s" in line
    ]
    assert progress and "P / P_best" in progress[-1] and ", wrapped " in progress[-1], log
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    steps = f"physics: {summary['steps']:,} steps in"
    assert any(line.startswith(steps) for line in log.splitlines()), log
    assert f"P / P_best {summary['p_over_pbest_mean']:.4f}" in log and "written: " in log, log
    assert not any(line.startswith(("{", '"', "}")) for line in log.splitlines()), log


def test_a_template_checked_against_the_live_bench_reads_every_pv_and_moves_nothing(ioc, tmp_path):
    mapping = tmp_path / "mapping.json"
    args = ["template", "--out", mapping, "--prefix", PREFIX, "--stages", "3", "--no-lengths"]
    assert runner.main(args) == 0 and check_mapping(json.loads(mapping.read_text()))
    assert runner.main(args) == 2  # never over a file that exists
    ticks = Path(ioc.log).parent / "ticks.jsonl"
    before = len(ticks.read_text().splitlines())
    proc = Process("agents.bench", ["check", "--mapping", mapping], ioc.env, tmp_path / "check.log")
    rc, log = proc.wait(START_S), proc.text()
    assert rc == 0, log
    for where, pv in template.entries(check_mapping(json.loads(mapping.read_text()))):
        line = next((x for x in log.splitlines() if x.startswith(where)), "")
        assert f"{pv}: " in line, log
    assert "FO:LINE1:SP: " in log and " wl, limits [" in log, log  # the IOC's units and limits
    assert "7 samples in [" in log and "11 PVs answered, 0 misfits; nothing was written" in log, log
    applied = [json.loads(x)["setpoints"] for x in ticks.read_text().splitlines()[before - 1 : -1]]
    assert len(applied) > 10 and all(s == applied[0] for s in applied), "a setpoint moved"


def test_the_check_names_the_pvs_that_do_not_answer_at_once(ioc, tmp_path, monkeypatch, capsys):
    """A mapping that names length readouts the bench does not serve: exit status 2 within its
    connect_s (1 s), one line naming each missing PV and no other."""
    for key in ("EPICS_CA_SERVER_PORT", "EPICS_CA_REPEATER_PORT", "EPICS_CA_ADDR_LIST"):
        monkeypatch.setenv(key, ioc.env[key])
    monkeypatch.setenv("EPICS_CA_AUTO_ADDR_LIST", "NO")
    # caproto's client reads them when it starts; libca read them when this process imported ophyd
    monkeypatch.setenv("OPS_BENCH_TRANSPORT", "caproto")
    mapping = tmp_path / "mapping.json"
    assert runner.main(["template", "--out", mapping, "--prefix", PREFIX, "--stages", "3"]) == 0
    capsys.readouterr()
    result, t0 = {}, time.monotonic()
    checking = threading.Thread(
        target=lambda: result.update(
            rc=template.main(["check", "--mapping", str(mapping), "--connect-s", "1"])
        ),
        daemon=True,
    )
    checking.start()
    checking.join(60)  # the watchdog: a check that hangs fails here
    assert not checking.is_alive() and time.monotonic() - t0 < 30, "the check hung"
    err = capsys.readouterr().err.strip().splitlines()
    assert result["rc"] == 2 and len(err) == 1, err
    missing = [f"{PREFIX}LINE{i}:LEN" for i in (1, 2, 3)]
    assert all(pv in err[0] for pv in missing) and f"{PREFIX}LINE1:SP" not in err[0], err
    assert err[0].startswith("agents.bench check: no answer from PV(s)"), err


def test_a_learner_from_scratch_on_a_frames_only_bench_takes_its_bench_preset(ioc, tmp_path):
    """``--learn droq`` alone: the bench preset (the fit's residual) and the wrap, said in the first
    line."""
    args = ["--prefix", PREFIX, "--stages", "3", "--no-lengths", "--learn", "droq", "--steps", "60"]
    args += ["--stale-s", "5", "--rate", "50", "--out", tmp_path / "out"]
    args += ["--set", "hidden=[16,16]", "--set", "critic_hidden=[16,16]", "--set", "batch_size=16"]
    args += ["--set", "learning_starts=20", "--set", "utd_ratio=1.0"]
    proc = Process("agents.bench", args, ioc.env, tmp_path / "runner.log")
    rc, log = proc.wait(START_S), proc.text()
    assert rc == 0, log
    first = runner_lines(log)[0]
    assert "droq with its bench preset (config=bench" in first and "0.5 wl" in first, first
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["env_steps_total"] == 60 and summary["learner_error"] is None, summary
    learned = json.loads((tmp_path / "out" / "checkpoint" / "meta.json").read_text())["hyper"]
    assert learned["config"] == "bench" and learned["observer"] == "fit-residual", learned
    assert "learning: 60 env steps" in log, log
