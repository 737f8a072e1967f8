"""The bench: the simulator served as a caproto IOC, ophyd devices over it, the Bluesky runner.

Device tests use ophyd's fake signals; the end-to-end tests start real IOC and runner
subprocesses on free localhost ports (EPICS_CA_* set for both sides), each in its own process
group, killed on teardown, every wait bounded."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("caproto")
pytest.importorskip("ophyd")
pytest.importorskip("bluesky")

import jax  # noqa: E402
from ophyd.sim import make_fake_device  # noqa: E402

import agents  # noqa: E402
from agents.bench import cli, frozen, loop as bench_loop, prepare, runner  # noqa: E402
from agents.bench.mapping import MappingError, check_mapping, sim_mapping
from agents.bench.transport import SafetyStop
from agents.bench.devices import make_bench
from benchmarks import lab  # noqa: E402
from benchmarks.lab import Process, ca_env  # noqa: E402
import ops_jax  # noqa: E402
from ops_jax import ioc  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
START_S = 240  # an IOC or runner start-up on a loaded 2-core machine (JAX import and compile)


# -- mapping, devices, controller protocol (no Channel Access)
# --------------------------------------


@pytest.mark.parametrize(
    "edit, needle",
    [
        (lambda m: m.update(detectr={}), "detectr"),
        (lambda m: m["lines"][1].update(setpont="X"), "setpont"),
        (lambda m: m["detector"].pop("tick"), "tick"),
        (lambda m: m.update(safety={"soft_range_wl": [1.0, -1.0]}), "soft_range_wl"),
        (lambda m: m.update(safety={"max_step_wl": -0.1}), "max_step_wl"),
        (
            lambda m: m.update(safety={"wrap_wl": 2.5}),
            "wrap_wl",
        ),  # more than a third of the soft range
        (lambda m: m["lines"][0].update(readback="OPS: LINE1"), "lines[0].readback"),
    ],
)
def test_bad_mapping_fails_naming_the_key(edit, needle):
    m = sim_mapping("OPS:", 3)
    edit(m)
    with pytest.raises(MappingError, match=needle.replace("[", r"\[").replace("]", r"\]")):
        check_mapping(m)


def test_docs_mapping_example_is_the_simulated_benchs():
    """docs/lab.md's mapping file, every key written out, is what the runner builds for --prefix
    OPS:."""
    text = (ROOT / "docs" / "lab.md").read_text()
    example = json.loads(text.split("```json\n", 1)[1].split("```", 1)[0])
    assert check_mapping(example) == check_mapping(sim_mapping("OPS:", 2))


def fake_bench(stages=3, **safety):
    mapping = check_mapping({**sim_mapping("T:", stages), "safety": safety})
    bench, lines = make_bench(mapping, device_class=make_fake_device)
    for i in range(1, stages + 1):
        getattr(bench, f"line{i}").setpoint.sim_put(0.0)
    return bench, lines


def test_lines_clip_moves_to_the_limits_and_stop_after_the_watchdog(caplog):
    bench, lines = fake_bench(max_step_wl=0.1, soft_range_wl=[-0.15, 0.15])
    lines.set([0.05, 0.5, -0.5])  # line 2 and 3: beyond the step
    assert np.allclose(
        [bench.line1.setpoint.get(), bench.line2.setpoint.get(), bench.line3.setpoint.get()],
        [0.05, 0.1, -0.1],
    )
    lines.set([0.05, 0.3, -0.1])  # line 2: within the step, beyond the soft range
    assert bench.line2.setpoint.get() == pytest.approx(0.15)
    assert lines.clipped.get() == 3
    assert "clipped" in caplog.text
    lines.lock("lost connection to PV T:TICK")
    with pytest.raises(SafetyStop, match="T:TICK"):
        lines.set([0.0, 0.0, 0.0])
    assert bench.line1.setpoint.get() == pytest.approx(0.05)  # nothing written after the stop


def test_detector_trigger_waits_for_a_frame_not_used_before():
    bench, _ = fake_bench()
    det = bench.detector
    det.tick.sim_put(7)
    det.arm()
    first = det.trigger()  # the frame there at arm() counts as new
    first.wait(1)
    status = det.trigger()
    time.sleep(0.05)
    assert first.success and not status.done
    det.tick.sim_put(8)
    status.wait(1)
    assert status.success
    det.use()
    det.timeout = 0.05
    status = det.trigger()
    with pytest.raises(Exception):
        status.wait(1)  # no new frame: fails after the timeout


def test_detector_after_a_move_waits_for_a_frame_acquired_later():
    bench, _ = fake_bench()
    det = bench.detector
    det.tick.sim_put(1)
    det.arm()
    det.after(time.time() + 0.3)  # a move sent, showing from 0.3 s on
    status = det.trigger()
    det.tick.sim_put(2)  # acquired before: not usable
    time.sleep(0.05)
    assert not status.done
    time.sleep(0.3)
    det.tick.sim_put(3)
    status.wait(1)
    assert status.success and det._used == 3


def test_detector_wait_blocks_for_a_new_frame_and_fails_after_the_watchdog():
    bench, _ = fake_bench()
    det = bench.detector
    det.tick.sim_put(1)
    det.arm()
    assert det.wait(0.05) and not det.wait(0.05)  # the frame at arm(), then none new
    threading.Timer(0.05, det.tick.sim_put, (2,)).start()
    assert det.wait(5) and det._used == 2
    det.fail(SafetyStop("lost connection to PV T:TICK"))
    det.tick.sim_put(3)
    with pytest.raises(SafetyStop, match="T:TICK"):
        det.wait(1)


def run_flyer(flyer, callback):
    """Run ``flyer`` under ``fly`` in a fresh RunEngine, every document to
    ``callback(name, doc)``."""
    import bluesky.preprocessors as bpp
    from bluesky import RunEngine

    from agents.bench.flyer import fly

    RE = RunEngine({}, context_managers=[])
    RE.subscribe(callback)
    RE(bpp.run_wrapper(fly(flyer)))


def test_loop_flyer_runs_in_its_own_thread_and_hands_back_pages():
    """A RunEngine kicks the flyer off and collects while it runs: every step an event, in pages of
    plain values; a step that raises fails the run, every step before it kept."""
    from bluesky.utils import FailedStatus

    from agents.bench.flyer import LoopFlyer

    keys = {
        "x": {"source": "loop", "dtype": "number", "shape": []},
        "v": {"source": "loop", "dtype": "array", "shape": [2]},
    }
    for fail_at in (None, 12):
        threads = []

        def step():
            threads.append(threading.current_thread().name)
            if len(threads) == fail_at:
                raise SafetyStop("stop here")
            time.sleep(0.01)
            return {"x": np.float64(len(threads)), "v": np.arange(2.0)}, {
                "x": time.time(),
                "v": time.time(),
            }

        flyer = LoopFlyer("loop", keys, lambda: None, step, lambda: len(threads) >= 40, page_s=0.05)
        docs = []
        if fail_at is None:
            run_flyer(flyer, lambda name, doc: docs.append((name, doc)))
        else:
            with pytest.raises(FailedStatus):
                run_flyer(flyer, lambda name, doc: docs.append((name, doc)))
        pages = [d for name, d in docs if name == "event_page"]
        x = [v for page in pages for v in page["data"]["x"]]
        assert set(threads) == {"loop-loop"} and len(pages) > (
            fail_at is None
        )  # several while it runs
        assert x == list(range(1, 41) if fail_at is None else range(1, fail_at))
        assert all(type(v) is float for v in x) and all(
            type(v) is list for page in pages for v in page["data"]["v"]
        )
        assert docs[-1][1]["exit_status"] == ("success" if fail_at is None else "fail")


def test_pin_moves_every_thread_to_the_core_and_rejects_a_core_out_of_reach():
    """``--cpu``: the threads running before and those started after run on that core only."""
    core = sorted(os.sched_getaffinity(0))[-1]
    code = (
        "import os, threading; from agents.bench.prepare import pin\n"
        "e = threading.Event(); t = threading.Thread(target=e.wait); t.start()\n"
        f"pin({core})\n"
        "u = threading.Thread(target=e.wait); u.start()\n"
        "cores = {frozenset(os.sched_getaffinity(x.native_id)) for x in (t, u)}\n"
        "print(sorted(cores | {frozenset(os.sched_getaffinity(0))}, key=sorted))\n"
        "e.set()"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"[frozenset({{{core}}})]"
    with pytest.raises(ValueError, match=r"--cpu must be one of the cores .* got 100000"):
        prepare.pin(100_000)


def xla_pool_threads(pid) -> tuple[int, set]:
    """(threads of XLA's Eigen pool in process ``pid``, the distinct sets of cores its threads may
    run on) (Linux)."""
    tasks = Path(f"/proc/{pid}/task").iterdir()
    names_cores = [
        ((t / "comm").read_text().strip(), frozenset(os.sched_getaffinity(int(t.name))))
        for t in tasks
    ]
    return sum(name == "tf_XLAEigen" for name, _ in names_cores), {
        cores for _, cores in names_cores
    }


def test_single_threaded_start_gives_xla_one_pool_thread_and_leaves_the_cores_free():
    """``ops_jax.cli.runtime.start_single_threaded``: XLA's Eigen pool has one thread (several
    without it); every thread of the process may then run on all the cores it could before."""
    allowed = frozenset(os.sched_getaffinity(0))
    if len(allowed) < 2:
        pytest.skip("needs two CPU cores")
    code = (
        "import os, sys, jax; from ops_jax.cli import runtime\nstarted = "
        "runtime.start_single_threaded() if sys.argv[1] == 'single' else jax.devices() and "
        "None\njax.jit(lambda x: x @ x)(jax.numpy.ones((64, "
        "64))).block_until_ready()\nprint(started, sys.argv[1]); sys.stdout.flush(); "
        "sys.stdin.read()"
    )
    pools = {}
    for mode in ("usual", "single"):
        proc = subprocess.Popen(
            [sys.executable, "-c", code, mode],
            cwd=ROOT,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            started = proc.stdout.readline().split()
            pools[mode] = (started, *xla_pool_threads(proc.pid))
        finally:
            proc.communicate("", timeout=START_S)
    assert pools["usual"][1] > 1
    assert pools["single"][:3] == (["True", "single"], 1, {allowed})


def test_settle_s_sets_the_detectors_settle_and_is_checked(tmp_path):
    """``--settle-s``: the mapping's ``detector.settle_s`` for the run; out of [0, 10] s it fails
    naming it."""
    args = cli.parser().parse_args(
        ["--prefix", "X:", "--controller", "spgd", "--settle-s", "-0.001", "--out", str(tmp_path)]
    )
    with pytest.raises(ValueError, match=r"--settle-s must be in \[0, 10\] s, got -0.001"):
        prepare.setup(args)
    args.settle_s = 0.004
    assert prepare.setup(args).mapping["detector"]["settle_s"] == 0.004
    args.settle_s = None
    assert prepare.setup(args).mapping["detector"]["settle_s"] == 0.002


def test_loop_flyer_pages_are_collected_between_steps():
    """A page is due after the step that ends its period: the RunEngine collects it while the loop
    waits for its next frame, not while a step works."""
    from agents.bench.flyer import LoopFlyer

    keys = {"x": {"source": "loop", "dtype": "number", "shape": []}}
    working, steps, during = threading.Event(), [], []

    def step():
        time.sleep(0.04)  # waiting for a frame
        working.set()
        time.sleep(0.01)  # the step's work
        working.clear()
        steps.append(1)
        return {"x": float(len(steps))}, {"x": time.time()}

    flyer = LoopFlyer("loop", keys, lambda: None, step, lambda: len(steps) >= 30, page_s=0.04)
    collect = flyer.collect_pages

    def watched():
        during.append(working.is_set())
        yield from collect()

    flyer.collect_pages = watched
    pages = []
    run_flyer(flyer, lambda name, doc: pages.append(doc) if name == "event_page" else None)
    assert [x for page in pages for x in page["data"]["x"]] == list(range(1, 31))
    assert len(during) >= 20 and sum(during) <= 2, (
        during
    )  # a fifth of the time is work: a timer would hit it


def test_loop_flyer_keeps_the_steps_that_end_during_a_collection():
    """A loop that ends while the RunEngine still handles a page (a slow document callback): its
    last steps are collected too."""
    from agents.bench.flyer import LoopFlyer

    keys = {"x": {"source": "loop", "dtype": "number", "shape": []}}
    steps = []

    def step():
        time.sleep(0.01)
        steps.append(1)
        return {"x": float(len(steps))}, {"x": time.time()}

    flyer = LoopFlyer("loop", keys, lambda: None, step, lambda: len(steps) >= 6, page_s=0.025)
    pages = []

    def slow(name, doc):
        if name == "event_page":
            pages.append(doc)
            time.sleep(0.05)

    run_flyer(flyer, slow)
    assert [x for page in pages for x in page["data"]["x"]] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]


def test_lines_wrap_by_one_period_near_a_soft_limit_and_never_back_and_forth():
    """With wrap_wl a line following a drift stays within its soft range for ever: each time it
    would come within a period of a limit it is taken one period back (a move of up to max_step_wl +
    wrap_wl, not clipped)."""
    bench, lines = fake_bench(max_step_wl=0.3, soft_range_wl=[-3.0, 3.0], wrap_wl=0.5)
    sent, target = [], np.zeros(3)
    for _ in range(3000):  # line 1 drifts up, line 2 down, line 3 still: 30 wl in 0.01-wl moves
        target = lines.position + np.array([0.01, -0.01, 0.0])
        sent.append(lines.move(target))
    sent = np.array(sent)
    assert np.all(np.abs(sent[:, :2]) <= 2.5 + 1e-9) and np.all(sent[:, 2] == 0)
    jumps = np.abs(np.diff(sent, axis=0))
    assert np.all(
        (jumps < 0.011) | np.isclose(jumps, 0.49)
    )  # a move, or a move and one period back
    # 27.5 wl of drift past the band's edge per line, one wrap each 0.5 wl
    assert (
        lines.wraps.get() == np.sum(np.isclose(jumps, 0.49)) == 2 * 55 and lines.clipped.get() == 0
    )
    _, plain = fake_bench(max_step_wl=0.3, soft_range_wl=[-3.0, 3.0])
    for _ in range(400):
        plain.move(plain.position + 0.01)
    assert np.allclose(plain.position, 3.0) and plain.clipped.get() > 0 and plain.wraps.get() == 0


def test_closing_channel_access_drops_only_caprotos_network_errors():
    """While the circuits close, a caproto thread's send on the socket closed under it is dropped
    (it would print a traceback after the runner's one line); any other thread's error still reaches
    the hook before."""
    from agents.bench.lifecycle import closing_socket_hook

    seen = []
    hook = closing_socket_hook(seen.append)
    caproto_code = {"__name__": "caproto.threading.client"}
    exec(
        "def send():\n    raise OSError(9, 'Bad file descriptor')\n"
        "def parse():\n    raise ValueError('not a network error')\n",
        caproto_code,
    )

    def ours():
        raise OSError(9, "Bad file descriptor")

    for target in (caproto_code["send"], caproto_code["parse"], ours):
        previous, threading.excepthook = threading.excepthook, hook
        try:
            thread = threading.Thread(target=target)
            thread.start()
            thread.join(10)
        finally:
            threading.excepthook = previous
    assert [type(a.exc_value) for a in seen] == [ValueError, OSError]
    assert seen[1].thread.name != seen[0].thread.name


def test_pace_keeps_a_fixed_schedule_whatever_each_step_took():
    """The rate cap's deadlines are one period apart, so a late wake-up does not delay the next
    step; after a stall of more than a period the schedule starts again."""
    loop = bench_loop.Loop.__new__(bench_loop.Loop)
    loop.period, loop.deadline = 0.01, None
    start = time.perf_counter()
    loop.pace(start)
    first = loop.deadline
    assert first == pytest.approx(start + 0.01) and time.perf_counter() >= first
    time.sleep(0.004)  # a step that took 4 ms longer
    loop.pace(first + 0.004)
    assert loop.deadline == pytest.approx(first + 0.01)
    time.sleep(0.05)  # a stall
    late = time.perf_counter()
    loop.pace(late)
    assert loop.deadline == pytest.approx(late + 0.01)


def test_length_readouts_a_controller_reads_must_be_mapped():
    """Without length PVs, SPGD and the physics-informed controller without use_lengths run; a
    controller reading them fails before it is compiled, naming itself and the missing entries."""

    assert not frozen.reads_lengths("spgd", None) and frozen.reads_lengths("sac", {})
    assert frozen.reads_lengths("physics", None) and not frozen.reads_lengths(
        "physics", {"use_lengths": False}
    )
    env, _ = ops_jax.make(3, "hard")
    assert frozen.observes_lengths(env)
    mapping = check_mapping(sim_mapping("T:", 3, lengths=False))
    assert all("length" not in line for line in mapping["lines"])
    frozen.check_lengths("spgd", False, env, mapping)
    with pytest.raises(
        MappingError,
        match=r"controller physics .*lines\[0\].length, lines\[1\].length, lines\[2\].length",
    ):
        frozen.load_controller("physics", mapping, {}, {}, seed=0)
    partial = check_mapping(
        {
            **sim_mapping("T:", 3),
            "lines": [
                *sim_mapping("T:", 2)["lines"],
                {"setpoint": "T:LINE3:SP", "readback": "T:LINE3:RBV"},
            ],
        }
    )
    with pytest.raises(MappingError, match=r"lacks lines\[2\].length;"):
        frozen.check_lengths("DIR", True, env, partial)
    wrapping = check_mapping({**sim_mapping("T:", 3), "safety": {"wrap_wl": 0.5}})
    with pytest.raises(MappingError, match="jump by a period when a line wraps"):
        frozen.check_lengths("DIR", True, env, wrapping)
    frozen.check_lengths("spgd", False, env, wrapping)


def test_bench_reset_is_a_fresh_start():
    """Bench.reset: the lines back near the optimum (a new reset draw of their offsets), the tick
    count going on."""
    sim = ioc.Bench(3, "hard", {"action_scale": 1.0, "model": "phasor"}, seed=0)
    first = sim.frame
    for _ in range(3):
        wreck = sim.tick([1.25, -1.2, 1.3])
    assert np.all(np.abs(wreck["length"]) > 0.9) and np.allclose(sim.command, [1.25, -1.2, 1.3])
    again = sim.reset()
    assert (
        sim.t == 3
        and sim.resets == 1
        and np.all(sim.command == 0)
        and np.all(again["position"] == 0)
    )
    assert np.all(np.abs(again["length"]) < 0.5) and not np.array_equal(
        again["length"], first["length"]
    )


def test_bench_without_length_readouts_serves_no_length_pvs():
    """observe_lengths=False: the frame has no lengths, the PV group no LINEi:LEN, and a tick still
    publishes."""
    import asyncio

    sim = ioc.Bench(
        2, "hard", {"action_scale": 1.0, "model": "phasor", "observe_lengths": False}, seed=0
    )
    values = sim.tick([0.01, -0.01])
    assert values["length"] is None and values["trace"].shape == (3,)
    group = ioc.pv_group(sim, "NOLEN:", 100.0, lockstep=True)
    assert not any(name.endswith(":LEN") for name in group.pvdb) and "NOLEN:LINE1:SP" in group.pvdb
    asyncio.run(group.publish(values))
    assert group.tick.value == sim.t == 1


def test_the_benchs_mapping_names_pvs_the_ioc_serves():
    """Every PV the simulated bench's mapping names (``sim_mapping``, lengths and lockstep on) is
    one the IOC's PV group serves: both read ``ops_jax.pvs``."""
    from ops_jax import pvs

    sim = ioc.Bench(3, "hard", {"action_scale": 1.0, "model": "phasor"}, seed=0)
    served = set(ioc.pv_group(sim, "PT:", 100.0, lockstep=True).pvdb)
    mapping = check_mapping(sim_mapping("PT:", 3, lockstep=True))
    named = {mapping["advance"], *mapping["evaluation"].values()}
    named |= {mapping["detector"][k] for k in ("power", "trace", "tick")}
    named |= {pv for line in mapping["lines"] for pv in line.values()}
    assert named <= served and "PT:" + pvs.RESET in served
    with pytest.raises(ValueError, match="line i"):
        pvs.line_pv(pvs.LINE_SETPOINT, 0)


def test_ioc_reports_its_ticks_host_time(monkeypatch, capsys):
    """Every TICK_REPORT ticks the IOC prints one line: the ticks covered, the step's and the
    writes' median and 99th percentile (ms), and the overruns; the ticks are those of the bench."""
    import asyncio
    import re

    from ops_jax import ioc_group

    monkeypatch.setattr(ioc_group, "TICK_REPORT", 3)
    sim = ioc.Bench(2, "hard", {"action_scale": 1.0, "model": "phasor"}, seed=0)
    group = ioc.pv_group(sim, "TT:", 100.0, lockstep=True)

    async def ticks(n):
        for _ in range(n):
            await group.step()

    asyncio.run(ticks(7))
    lines = [line for line in capsys.readouterr().out.splitlines() if "ticks" in line]
    ms = r"([\d.]+) / ([\d.]+) ms"
    pattern = rf"ops_jax.ioc: ticks (\d+)-(\d+): step p50 / p99 {ms}, publish {ms}, overruns 0"
    found = [re.fullmatch(pattern, line) for line in lines]
    assert all(found) and [m.group(1, 2) for m in found] == [("1", "3"), ("4", "6")]
    assert all(
        float(m[3]) <= float(m[4]) and float(m[5]) <= float(m[6]) and float(m[3]) > 0 for m in found
    )
    assert sim.t == 7 and len(group.tick_ms) == 1


def test_ioc_tick_log_names_each_tick_and_the_setpoints_it_applied():
    """``--tick-log``: a JSON line per tick, its number, its time stamp (that of the tick's PVs) and
    the setpoints read at its start."""
    import asyncio
    import io

    sim = ioc.Bench(2, "hard", {"action_scale": 1.0, "model": "phasor"}, seed=0)
    log = io.StringIO()
    group = ioc.pv_group(sim, "TL:", 100.0, lockstep=True, tick_log=log)

    async def ticks():
        await group.step()
        await group.sp1.write(0.25)
        await group.step()

    asyncio.run(ticks())
    lines = [json.loads(line) for line in log.getvalue().splitlines()]
    assert [x["tick"] for x in lines] == [1, 2] and [x["setpoints"] for x in lines] == [
        [0.0, 0.0],
        [0.25, 0.0],
    ]
    assert (
        abs(lines[1]["stamp"] - group.tick.timestamp) < 1e-5
        and lines[0]["stamp"] < lines[1]["stamp"]
    )  # EPICS ns
    assert ioc.parser().parse_args(["--tick-log", "t.jsonl"]).tick_log == "t.jsonl"


def test_ioc_socket_sends_without_nagle_delay():
    """The IOC's server sets TCP_NODELAY on its listening socket (caproto's own leaves Nagle on),
    and a connection accepted on such a socket (protocol 0, as caproto binds it) inherits it."""
    import asyncio
    import socket

    from ops_jax import ioc_server

    def listening() -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)  # protocol 0, as caproto's
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        sock.setblocking(False)
        return sock

    async def nodelay():
        context = ioc_server.context_class()({}, ["127.0.0.1"])
        served = listening()
        await context.server_accept_loop(served)
        listener = served.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
        seen = asyncio.get_running_loop().create_future()

        def on_client(reader, writer):
            sock = writer.get_extra_info("socket")
            seen.set_result(sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))
            writer.close()

        plain = listening()
        plain.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        server = await asyncio.start_server(on_client, sock=plain)
        _, writer = await asyncio.open_connection("127.0.0.1", plain.getsockname()[1])
        accepted = await asyncio.wait_for(seen, 10)
        writer.close()
        server.close()
        served.close()
        return listener, accepted

    listener, accepted = asyncio.run(nodelay())
    assert listener != 0 and accepted != 0


def test_ioc_batch_window_is_a_tenth_of_the_tick(monkeypatch):
    monkeypatch.delenv(ioc.BATCH_WINDOW_ENV, raising=False)
    assert ioc.batch_window(100) == pytest.approx(0.001) and ioc.batch_window(5) == pytest.approx(
        0.01
    )
    monkeypatch.setenv(ioc.BATCH_WINDOW_ENV, "0.004")
    assert ioc.batch_window(100) == 0.004
    monkeypatch.delenv(ioc.BATCH_WINDOW_ENV)
    ioc.set_batch_window(200)  # caproto reads it from its environment variable
    assert float(os.environ[ioc.BATCH_WINDOW_ENV]) == pytest.approx(0.0005)


def test_ioc_sends_a_batch_once_no_update_is_queued():
    """The server's circuits take queued updates without waiting, answer None at once on an empty
    queue (the batch goes out), and wait for an update only where caproto asks for no timeout."""
    import asyncio

    from caproto.asyncio.server import VirtualCircuit

    from ops_jax import ioc_server

    async def takes():
        queue = asyncio.Queue()
        queue.put_nowait("update")
        first = await ioc_server.drained_get(queue, timeout=30)
        start = time.monotonic()
        empty = await ioc_server.drained_get(queue, timeout=30)
        waited = time.monotonic() - start
        later = asyncio.get_running_loop().call_later(0.05, queue.put_nowait, "next")
        blocking = await asyncio.wait_for(ioc_server.drained_get(queue, timeout=None), 30)
        later.cancel()
        return first, empty, waited, blocking

    first, empty, waited, blocking = asyncio.run(takes())
    assert (first, empty, blocking) == ("update", None, "next") and waited < 5
    circuit = ioc_server.context_class().CircuitClass
    assert issubclass(circuit, VirtualCircuit)
    assert circuit.get_from_sub_queue is not VirtualCircuit.get_from_sub_queue


def test_agent_replays_a_controller_step_probe_by_probe():
    """Agent's probe protocol gives the policy's own offsets and, with the measured results, its
    action."""
    env_config = {"stages": 3, "model": "phasor"}
    policy = agents.api.algo_module("spgd").make_policy(env_config, None)
    env, _ = ops_jax.make(**env_config)
    agent = frozen.Agent(policy, None, env, seed=3)
    assert agent.probes == 1
    obs = np.linspace(-0.5, 0.5, env.observation_size)
    agent.start(obs)
    carry = agent.carry
    seen = []

    def probe(offsets):
        seen.append(offsets)
        return jax.numpy.full((1,), 0.42)

    key = jax.random.split(jax.random.fold_in(jax.random.split(jax.random.key(3), 3)[2], 0))[0]
    want, _ = policy.act(None, carry, jax.numpy.asarray(obs, "float32")[None], key, probe)
    offsets = agent.offsets(obs, np.zeros(1), 0)
    assert np.allclose(offsets, seen[0][0], atol=1e-7)
    assert np.allclose(agent.act(obs, np.array([0.42])), want[0], atol=1e-6)


def test_agent_leaves_out_the_probes_a_controller_leaves_out():
    """A probe made with ``active`` False is no probe on the bench: ``offsets`` gives None (no move,
    no frame)."""
    env_config = {"stages": 3, "model": "phasor", "imperfections": "lab"}
    from agents.controllers import trim

    env, _ = ops_jax.make(**env_config)
    wrapped = trim.trimmed(
        (agents.api.algo_module("spgd").make_policy(env_config, None), None),
        {"config": "guarded"},
        env_config,
    )
    agent = frozen.Agent(*wrapped, env, seed=3)
    assert agent.probes == 2  # SPGD's and the trim's
    dark, bright = (
        np.tile(
            env.layout.encode(
                p,
                np.zeros(env.frame_size - 1 - env.num_actions),
                np.zeros(env.num_actions),
                0.5,
                xp=np,
            ),
            env.observation_size // env.frame_size,
        )
        for p in (0.1, 0.9)
    )
    for obs, made in ((dark, False), (bright, True)):
        agent.start(obs)
        assert agent.offsets(obs, np.zeros(2), 0) is not None  # SPGD probes every step
        assert (
            agent.offsets(obs, np.zeros(2), 1) is not None
        ) == made  # the guarded trim only above its gate


def test_an_action_the_limits_cut_is_told_to_a_controller_that_reads_its_own_move():
    """The loop counts a step whose action the safety limits cut and tells the physics-informed fit
    the move sent (``Policy.sent``), less a wrap (a whole period); a move within the limits, or a
    wrap alone, tells nothing."""
    env_config = {"stages": 3, "model": "phasor", "imperfections": "lab"}
    env, params = ops_jax.make(**env_config)
    scale = float(params.action_scale)
    bench, lines = fake_bench(max_step_wl=0.5 * scale, soft_range_wl=[-3.0, 3.0], wrap_wl=0.5)
    for i in range(1, 4):
        getattr(bench, f"line{i}").setpoint.sim_put(2.6)  # within a wrap of the upper limit
    agent = frozen.Agent(
        agents.api.algo_module("physics").make_policy(
            env_config, agents.api.ALGOS["physics"].config.from_hyper({"config": "frames"})
        ),
        None,
        env,
        seed=1,
    )
    loop = bench_loop.Loop(
        bench, lines, sim_mapping("T:", 3), agent, scale, 1.0, seconds=1.0, rate=100.0
    )
    agent.start(np.zeros(env.observation_size))
    for action, told in (
        ([0.9, -0.2, 0.0], [0.5, -0.2, 0.0]),  # line 1 cut to the step limit, every line wrapped
        ([0.3, -0.2, 0.0], None),
    ):  # within the limits
        fit = agent.carry["dz_prev"].shape[1]  # the lines the fit moves
        agent.carry = dict(
            agent.carry, dz_prev=jax.numpy.full((1, fit), 7.0)
        )  # a mark: only a tell rewrites it
        base = lines.position
        loop.cut(
            np.array(action),
            (lines.move(base + np.array(action) * scale) - lines.shift - base) / scale,
        )
        want = np.full(fit, 7.0) if told is None else np.array(told[:fit]) * scale
        np.testing.assert_allclose(np.asarray(agent.carry["dz_prev"])[0], want, rtol=1e-6)
    assert loop.actions_cut == 1 and lines.wraps.get() == 3 and lines.clipped.get() == 1
    spgd = frozen.Agent(
        agents.api.algo_module("spgd").make_policy(env_config, None), None, env, seed=1
    )
    spgd.start(np.zeros(env.observation_size))
    assert not spgd.tell(np.zeros(3))  # SPGD reads no move of its own


def test_bench_ports_lie_outside_the_range_the_kernel_auto_binds_from():
    """The IOC's Channel Access port is never one the kernel can hand to a client's socket: caproto
    binds the IOC's UDP port and its client sockets with SO_REUSEADDR and SO_REUSEPORT, and a client
    socket auto-bound to the IOC's port takes the IOC's replies for itself, so its search times out.
    Each port is free for TCP and UDP when drawn; the IOC warns of a port inside that range."""
    import socket

    first, last = ioc.ephemeral_ports()
    ports = [lab.free_port() for _ in range(50)]
    assert all(1024 <= p < first or last < p < 65_536 for p in ports) and len(set(ports)) > 40, (
        ports
    )
    for family in (socket.SOCK_STREAM, socket.SOCK_DGRAM):
        with socket.socket(socket.AF_INET, family) as s:
            s.bind(("127.0.0.1", ports[0]))
    env = ca_env()
    server, repeater = int(env["EPICS_CA_SERVER_PORT"]), int(env["EPICS_CA_REPEATER_PORT"])
    assert server != repeater and not ioc.port_warning(server) and not ioc.port_warning(repeater)
    assert ioc.port_warning(ports[0]) is None and ioc.port_warning(first - 1) is None
    for inside in (first, (first + last) // 2, last):
        assert f"port {inside} lies in" in ioc.port_warning(
            inside
        ) and f"below {first}" in ioc.port_warning(inside)


def test_ioc_options_come_from_make():
    args = ioc.parser().parse_args(
        [
            "--stages",
            "3",
            "--imperfections",
            "lab",
            "--vib-rms",
            "0.01",
            "--waveplate-error-deg",
            "(0.1, 0.2, 0.3)",
            "--model",
            "phasor",
        ]
    )
    options = ioc.make_options(args)
    assert options == {
        "action_scale": 1.0,
        "imperfections": "lab",
        "vib_rms": 0.01,
        "waveplate_error_deg": (0.1, 0.2, 0.3),
        "model": "phasor",
    }
    with pytest.raises(SystemExit):
        ioc.parser().parse_args(["--not-an-option", "1"])


def test_summary_ceilings_are_the_benchs_and_the_score_over_each(tmp_path):
    """``agents.bench.report``: a summary's ceilings of a known bench (``ops_jax.imperfections
    .ceilings``) and its P / P_best over each, written into summary.json; unknown: null with the
    reason; a NaN score (no steps) gives no fraction."""
    from agents.bench import report

    options = dict(stages=3, mode="hard", model="phasor", imperfections="lab")
    known = ops_jax.imperfections.ceilings(ops_jax.EnvSpec(**options))
    (tmp_path / "summary.json").write_text(json.dumps({"p_over_pbest_mean": 0.9, "steps": 5}))
    summary = report.add_ceilings(tmp_path, options)
    assert json.loads((tmp_path / "summary.json").read_text()) == summary and summary["steps"] == 5
    assert summary["held_power"] == known.held and summary["held_power_reason"] is None
    assert summary["held_power_predicted"] == known.predicted > known.held
    assert summary["p_over_held_mean"] == pytest.approx(0.9 / known.held)
    assert summary["p_over_held_predicted_mean"] == pytest.approx(0.9 / known.predicted)
    unknown = report.ceilings({"p_over_pbest_mean": 0.9})
    assert unknown["held_power"] is None and unknown["p_over_held_predicted_mean"] is None
    assert unknown["held_power_reason"] == report.UNKNOWN_BENCH
    nan = report.ceilings({"p_over_pbest_mean": float("nan")}, options)
    assert nan["held_power"] == known.held and nan["p_over_held_mean"] is None


def test_lab_knows_its_benchs_options_as_the_ioc_reads_them():
    """``benchmarks.lab.bench_env``: the ``ops_jax.make`` options of the IOC its runs start (scale,
    unseen per-stage errors, frames only)."""
    run = lab.RunSettings(seconds=1, rate=100, stale_s=1, scale=2.0, unseen=True, seed=1011)
    env = lab.bench_env(run)
    ns = ioc.parser().parse_args([str(a) for a in lab.ioc_args(run)])
    assert env == {"stages": 5, "mode": "hard", **ioc.make_options(ns)}
    assert env["imperfection_scale"] == 2.0 and env["imperfections"] == "lab"
    assert "waveplate_error_deg" in env and env != lab.bench_env(
        lab.RunSettings(seconds=1, rate=100, stale_s=1, scale=2.0, unseen=True, seed=1012)
    )
    frames = lab.bench_env(lab.RunSettings(seconds=1, rate=100, stale_s=1, frames_only=True))
    assert frames["observe_lengths"] is False and frames["imperfection_scale"] == 1.0


def test_light_imports_stay_light():
    code = (
        "import sys, ops_jax, agents; heavy = [m for m in ('caproto', 'ophyd', 'bluesky') if m in "
        "sys.modules];assert not heavy, heavy"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=START_S, cwd=ROOT)


# -- real IOCs and runners -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def iocs(tmp_path_factory):
    """Simulated benches started together: lockstep (lab), free-running, one to kill, one to reset,
    one to read."""
    tmp = tmp_path_factory.mktemp("iocs")
    common = ["--stages", "3", "--mode", "hard", "--model", "phasor"]
    args = {
        "lockstep": ["--prefix", "LS:", "--imperfections", "lab", "--lockstep"],
        "free": ["--prefix", "FR:", "--rate", "100"],
        "victim": ["--prefix", "KV:", "--rate", "100"],
        "reset": ["--prefix", "RS:", "--imperfections", "lab", "--lockstep"],
        "raw": ["--prefix", "RW:", "--lockstep"],
    }
    started = {
        k: Process(
            "ops_jax.ioc",
            [*common, *a, "--tick-log", tmp / f"{k}.ticks.jsonl"],
            ca_env(),
            tmp / f"{k}.log",
        )
        for k, a in args.items()
    }
    try:
        yield {k: p.wait_for("serving", START_S) for k, p in started.items()}
    finally:
        for p in started.values():
            p.kill()


def bench_run(ioc_, tmp: Path, *args) -> Process:
    """``python -m agents.bench`` against ``ioc_`` in its own process group."""
    return Process("agents.bench", ["--out", tmp / "out", *args], ioc_.env, tmp / "runner.log")


def finish(proc: Process, timeout=START_S):
    """(exit status, output); the runner is killed past ``timeout`` s."""
    return proc.wait(timeout), proc.text()


def wait_for_events(proc: Process, tmp: Path, count: int) -> None:
    """Wait until the run has written ``count`` events (it must not end first)."""
    out, deadline = tmp / "out" / "documents.jsonl", time.monotonic() + START_S
    while not (out.exists() and out.read_text().count('"name": "event"') >= count):
        assert proc.proc.poll() is None and time.monotonic() < deadline, proc.text()
        time.sleep(0.1)


def tick_log(ioc_: Process) -> Path:
    """The IOC's ``--tick-log`` (``iocs``)."""
    return ioc_.log.with_suffix(".ticks.jsonl")


def documents(tmp: Path) -> list:
    return [json.loads(line) for line in (tmp / "out" / "documents.jsonl").read_text().splitlines()]


# The lockstep bench's simulator replaying the setpoints sent, tick by tick, in a process of the
# IOC's build.
REPLAY = """import json, sys
from ops_jax import ioc
sim = ioc.Bench(3, "hard", {"action_scale": 1.0, "model": "phasor", "imperfections": "lab"}, seed=0)
sent = json.load(open(sys.argv[1]))
print(json.dumps([float(sim.frame["p_pmax"])] + [float(sim.tick(s)["p_pmax"]) for s in sent]))
"""


def test_the_ioc_runs_xla_with_one_pool_thread(iocs):
    """The simulated bench's ticks are small calls: its XLA pool has one thread, its threads every
    core."""
    threads, cores = xla_pool_threads(iocs["free"].proc.pid)
    assert (threads, cores) == (1, {frozenset(os.sched_getaffinity(0))})


TRANSPORT = """
import json, sys
from agents.bench.lifecycle import arm, connect, disconnect
from agents.bench.mapping import check_mapping, sim_mapping
from agents.bench.devices import make_bench
from agents.bench.lifecycle import described

transport = sys.argv[1]
mapping = check_mapping({**sim_mapping("RW:", 3, lockstep=True), "safety": {"stale_s": 10.0}})
bench, lines = make_bench(mapping, transport=transport)
connect(bench, 60)
arm(bench, lines)
feed, det = bench.transport, bench.detector
tick = feed.value("RW:TICK")
det.use()
sent = lines.move([0.1, -0.05, 0.02])
bench.advance.put(1)
fresh = det.wait(30)
keys, reads = described(bench)
print(json.dumps({
    "name": feed.name, "fresh": fresh, "ticks": int(feed.value("RW:TICK")) - int(tick),
    "sent": sent.tolist(), "rbv": [getattr(bench, f"line{i}").readback.get() for i in (1, 2, 3)],
    "keys": sorted(keys), "reads": reads, "shape": keys["bench_detector_trace"]["shape"],
}))
disconnect(bench)
"""


@pytest.mark.parametrize("transport", ["pyepics", "pyepics-pv", "caproto", "ophyd"])
def test_every_transport_follows_the_frames_and_writes_the_setpoints(iocs, transport):
    """Each transport (``agents.bench.transport``) on a lockstep bench: after a move and one tick
    its frame counter has gone one on, the IOC's readbacks are the setpoints sent, and the event's
    readings are described alike."""
    pytest.importorskip("epics")
    out = subprocess.run(
        [sys.executable, "-c", TRANSPORT, transport],
        capture_output=True,
        text=True,
        env={**iocs["raw"].env, "PYTHONPATH": str(ROOT)},
        timeout=START_S,
        cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    assert seen["name"] == transport and seen["fresh"] and seen["ticks"] == 1
    np.testing.assert_allclose(seen["rbv"], seen["sent"], atol=1e-6)
    assert seen["shape"] == [7] and sorted(k for k, _ in seen["reads"]) == seen["keys"]
    assert "caRepeater" not in out.stderr, out.stderr


def test_lockstep_run_reproduces_the_simulated_trajectory(iocs, tmp_path):
    """Same seed, same timing (lockstep): replaying the setpoints the runner sent, tick by tick, on
    the simulator gives the bench's P / P_max exactly."""
    steps = 20
    rc, log = finish(
        bench_run(
            iocs["lockstep"],
            tmp_path,
            "--prefix",
            "LS:",
            "--stages",
            "3",
            "--lockstep",
            "--controller",
            "physics",
            "--set",
            "starts=2",
            "--steps",
            str(steps),
            "--stale-s",
            "30",
        )
    )
    assert rc == 0, log
    events = [d["doc"]["data"] for d in documents(tmp_path) if d["name"] == "event"]
    assert len(events) == steps
    bench_p = np.array([e["bench_evaluation_p_pmax"] for e in events])
    (tmp_path / "sent.json").write_text(json.dumps([e["control_setpoint_wl"] for e in events[:-1]]))
    replay = subprocess.run(
        [sys.executable, "-c", REPLAY, str(tmp_path / "sent.json")],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=START_S,
    )
    assert replay.returncode == 0, replay.stderr[-2000:]
    np.testing.assert_array_equal(
        bench_p, np.float32(json.loads(replay.stdout))
    )  # event t: the frame of tick t
    assert np.ptp(bench_p) > 0.01  # the controller moved the lines


def test_each_frame_is_checked_against_the_setpoints_its_tick_applied(iocs, tmp_path):
    """The IOC's ``--tick-log`` names each tick's setpoints; ``benchmarks.lab.early_frames`` finds
    no early frame in a lockstep run (each tick follows the step's writes) and, against a log one
    tick late, every moved step early."""
    from benchmarks import lab

    steps = 15
    rc, log = finish(
        bench_run(
            iocs["lockstep"],
            tmp_path,
            "--prefix",
            "LS:",
            "--stages",
            "3",
            "--lockstep",
            "--controller",
            "physics",
            "--set",
            "starts=2",
            "--steps",
            str(steps),
            "--stale-s",
            "30",
        )
    )
    assert rc == 0, log
    docs = tmp_path / "out" / "documents.jsonl"
    assert lab.early_frames(docs, tick_log(iocs["lockstep"])) == (0, steps - 1)
    writing = tmp_path / "writing.jsonl"  # a log read while the IOC writes its last line
    writing.write_text(tick_log(iocs["lockstep"]).read_text() + '{"tick": 10')
    assert lab.early_frames(docs, writing) == (0, steps - 1)
    ticks = [json.loads(line) for line in tick_log(iocs["lockstep"]).read_text().splitlines()]
    assert [t["tick"] for t in ticks] == list(range(1, len(ticks) + 1)) and all(
        len(t["setpoints"]) == 3 for t in ticks
    )
    late = tmp_path / "late.jsonl"
    before = [{"setpoints": [0.0] * 3}, *ticks]  # the setpoints at start-up, then each tick's
    late.write_text(
        "".join(
            json.dumps({**t, "setpoints": b["setpoints"]}) + "\n" for t, b in zip(ticks, before)
        )
    )
    sent = [
        d["doc"]["data"]["control_setpoint_wl"] for d in documents(tmp_path) if d["name"] == "event"
    ]
    # event k + 1's frame checked against the setpoints of the tick before it: step k - 1's move (k
    # >= 1)
    moved = sum(not np.allclose(a, b, rtol=0, atol=1e-9) for a, b in zip(sent[1:-1], sent[:-2]))
    early, checked = lab.early_frames(docs, late)
    assert moved >= steps // 2 and moved <= early <= moved + 1 and checked == steps - 1


def test_run_end_to_end_with_clipped_moves(iocs, tmp_path):
    """SPGD over Channel Access for a few seconds, with a soft range tight enough to clip its
    probes, the runner on one core; every document it wrote passes event_model's schema."""
    from event_model import DocumentNames, schema_validators

    mapping = {
        **sim_mapping("FR:", 3),
        "safety": {"soft_range_wl": [-0.2, 0.2], "max_step_wl": 0.03, "stale_s": 5.0},
    }
    (tmp_path / "map.json").write_text(json.dumps(mapping))
    rc, log = finish(
        bench_run(
            iocs["free"],
            tmp_path,
            "--mapping",
            str(tmp_path / "map.json"),
            "--controller",
            "spgd",
            "--seconds",
            "3",
            "--cpu",
            str(max(os.sched_getaffinity(0))),
        )
    )
    assert rc == 0, log
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["stopped_by"] == "time" and summary["steps"] > 10, summary
    assert summary["probes_per_step"] == 1 and summary["frames_per_step"] >= 2
    assert 0 < summary["p_over_pbest_mean"] <= 1.5 and summary["latency_ms_p50"] > 0
    assert summary["clipped_moves"] > 0 and "clipped" in log
    # the runner knows no bench's imperfections: its ceilings are null, and the reason says so
    assert summary["held_power"] is None and summary["p_over_held_mean"] is None
    assert "unknown to the runner" in summary["held_power_reason"]
    docs = documents(tmp_path)
    stamps = [d["doc"]["timestamps"] for d in docs if d["name"] == "event"]
    frame_at = np.array([t["bench_detector_tick"] for t in stamps[1:]])
    sent_at = np.array([t["control_setpoint_wl"] for t in stamps[:-1]])
    assert np.all(frame_at > sent_at), (
        "a step used a frame acquired before the last setpoints were sent"
    )
    assert [d["name"] for d in docs[:2]] == ["start", "descriptor"] and docs[-1]["name"] == "stop"
    for d in docs:
        schema_validators[DocumentNames[d["name"]]].validate(d["doc"])
    events = [d["doc"]["data"] for d in docs if d["name"] == "event"]
    sent = np.array([e["control_setpoint_wl"] for e in events])
    assert np.all(np.abs(sent) <= 0.2 + 1e-9) and np.all(
        np.abs(np.diff(sent, axis=0)) <= 2 * 0.03 + 1e-9
    )
    assert (tmp_path / "out" / "power.png").stat().st_size > 0
    # the lock figures of the run's P / P_best (ops_jax.lock) at its achieved rate; null with a
    # reason if unlocked
    assert summary["lock_band"] == 0.02 and 0 < summary["held_level"] <= 1.5
    if summary["lock_step"] is not None:
        assert 1 <= summary["lock_step"] <= summary["steps"] and summary["lock_reason"] is None
        assert summary["lock_s"] == pytest.approx(summary["lock_step"] / summary["rate_hz"])
        assert 0 <= summary["rms_after_lock"] < 0.02
    else:
        assert summary["lock_s"] is None and summary["rms_after_lock"] is None
        assert "never stayed within 2%" in summary["lock_reason"]
    width = int.from_bytes((tmp_path / "out" / "power.png").read_bytes()[16:20], "big")
    assert width == 11 * 120  # the trace and, beside it, the PSD after lock


# Each line of the bench under prefix argv[1] moved to 0.1 wl from its optimum (its length
# readout's).
OFF_OPTIMUM = """
import sys
from caproto.sync.client import read, write
get = lambda pv: read(sys.argv[1] + pv, timeout=20, repeater=False).data[0]
for i in (1, 2, 3):
    write(f"{sys.argv[1]}LINE{i}:SP", [get(f"LINE{i}:SP") - get(f"LINE{i}:LEN") + 0.1],
          notify=True, timeout=20, repeater=False)
"""


def test_a_cut_action_is_counted_and_told_over_channel_access(iocs, tmp_path):
    """The physics-informed controller, which reads its own last move, on a bench whose step limit
    its moves exceed: the run ends cleanly, counting as cut exactly the steps whose setpoints moved
    by less than asked."""
    _, params = ops_jax.make(stages=3, mode="hard", model="phasor")  # the free bench's
    scale = float(params.action_scale)  # wl per unit of action
    max_step = 0.5 * scale
    safety = {"max_step_wl": max_step, "stale_s": 5.0, "wrap_wl": 0}  # no wrap
    mapping = {**sim_mapping("FR:", 3), "safety": safety}
    (tmp_path / "map.json").write_text(json.dumps(mapping))
    # the run starts by acquiring, wherever the runs before it left the lines
    off = subprocess.run(
        [sys.executable, "-c", OFF_OPTIMUM, "FR:"],
        env=iocs["free"].env,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=START_S,
    )
    assert off.returncode == 0, off.stderr
    rc, log = finish(
        bench_run(
            iocs["free"],
            tmp_path,
            "--mapping",
            str(tmp_path / "map.json"),
            "--controller",
            "physics",
            "--set",
            "config=frames",
            "--set",
            "starts=2",
            "--seconds",
            "3",
        )
    )
    assert rc == 0, log
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    docs = documents(tmp_path)
    events = [d["doc"]["data"] for d in docs if d["name"] == "event"]
    asked = np.array([e["control_action"] for e in events[1:]]) * scale
    moved = np.diff(np.array([e["control_setpoint_wl"] for e in events]), axis=0)
    assert np.all(np.abs(moved) <= max_step + 1e-9)
    cut = ~np.all(
        np.isclose(moved, asked, rtol=0, atol=1e-9), axis=1
    )  # no wrap mapped: a move short of the ask
    assert 0 < cut.sum() < len(cut), (cut.sum(), len(cut))  # acquiring is cut, holding is not
    assert summary["actions_cut"] - int(cut.sum()) in (0, 1), (
        summary
    )  # the first step's base is in no event
    assert summary["clipped_moves"] >= cut.sum() and summary["steps"] == len(events)


def test_run_with_the_trim_probes_once_more_per_step(iocs, tmp_path):
    """SPGD wrapped in the extremum-seeking trim (agents.controllers.trim) over Channel Access: two
    probes per step."""
    rc, log = finish(
        bench_run(
            iocs["free"],
            tmp_path,
            "--prefix",
            "FR:",
            "--stages",
            "3",
            "--controller",
            "spgd",
            "--trim",
            "ki=0.003",
            "jump=0.25",
            "--seconds",
            "3",
            "--stale-s",
            "5",
        )
    )
    assert rc == 0, log
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["stopped_by"] == "time" and summary["steps"] > 10, summary
    assert summary["probes_per_step"] == 2
    start = next(d["doc"] for d in documents(tmp_path) if d["name"] == "start")
    assert start["trim"] == {"ki": 0.003, "jump": 0.25}
    rc, log = finish(
        bench_run(
            iocs["free"],
            tmp_path,
            "--prefix",
            "FR:",
            "--stages",
            "3",
            "--controller",
            "spgd",
            "--trim",
            "ki=5",
            "--seconds",
            "3",
        )
    )
    assert rc == 2 and "ki must be" in log, log


def test_unknown_pv_fails_at_once_naming_it(iocs, tmp_path):
    mapping = {**sim_mapping("FR:", 3), "safety": {"connect_s": 2.0}}
    mapping["lines"][1]["readback"] = "FR:LINE2:NOPE"
    (tmp_path / "map.json").write_text(json.dumps(mapping))
    rc, log = finish(
        bench_run(
            iocs["free"], tmp_path, "--mapping", tmp_path / "map.json", "--controller", "spgd"
        )
    )
    message = next((line for line in log.splitlines() if "no answer from PV" in line), "")
    assert rc == 2 and "FR:LINE2:NOPE" in message and "FR:LINE1:SP" not in message, log


def test_ioc_killed_mid_run_stops_the_runner(iocs, tmp_path):
    """SIGKILL the IOC: the watchdog names a lost PV at once, nothing is written after, data
    kept."""
    victim = iocs["victim"]
    proc = bench_run(
        victim,
        tmp_path,
        "--prefix",
        "KV:",
        "--stages",
        "3",
        "--controller",
        "physics",
        "--seconds",
        "120",
        "--stale-s",
        "5",
    )
    wait_for_events(proc, tmp_path, 20)
    killed_at = time.time()
    victim.kill()
    rc, log = finish(proc, timeout=60)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert rc == runner.EXIT_WATCHDOG, log
    assert summary["stopped_by"].startswith("lost connection to PV KV:"), summary
    said = [  # what the runner and the watchdog said: not the start's lines, progress or summary
        line
        for line in log.splitlines()
        if (line.startswith("agents.bench.runner:") or " agents.bench ERROR" in line)
        and not line.startswith(("agents.bench.runner: starting", "agents.bench.runner: running"))
    ]
    assert len(said) <= 2 and "Traceback" not in log and "Run aborted" not in log, log
    assert said[-1] == f"agents.bench.runner: stopped by the watchdog: {summary['stopped_by']}", log
    assert summary["watchdog_time"] - killed_at < 2.0, summary
    docs = documents(tmp_path)
    assert docs[-1]["name"] == "stop" and docs[-1]["doc"]["exit_status"] == "fail"
    events = [d["doc"] for d in docs if d["name"] == "event"]
    sent = [
        e["timestamps"]["control_setpoint_wl"] for e in events
    ]  # a step's time (its event's: the page's)
    assert len(events) >= 20 and all(t <= summary["watchdog_time"] for t in sent)


def test_ctrl_c_ends_the_run_cleanly(iocs, tmp_path):
    """SIGINT: the run ends after the current step, exit status 130 (the user's stop), everything
    written."""
    proc = bench_run(
        iocs["free"],
        tmp_path,
        "--prefix",
        "FR:",
        "--stages",
        "3",
        "--controller",
        "spgd",
        "--seconds",
        "120",
        "--stale-s",
        "5",
    )
    wait_for_events(proc, tmp_path, 10)
    proc.proc.send_signal(signal.SIGINT)
    try:
        proc.proc.wait(30)
    except subprocess.TimeoutExpired:  # Ctrl-C again: stop at once (docs/lab.md)
        proc.proc.send_signal(signal.SIGINT)
    rc, log = finish(proc, timeout=60)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert (rc, summary["stopped_by"]) == (130, "user"), log
    assert "stopping after the current step" in log and "watchdog:" not in log, log
    docs = documents(tmp_path)
    assert docs[-1]["name"] == "stop" and docs[-1]["doc"]["exit_status"] == "success"
    assert (tmp_path / "out" / "power.png").exists()


def test_a_burst_of_ctrl_c_stops_at_once_as_the_user_and_loses_nothing(iocs, tmp_path):
    """SIGINT every 50 ms: the first ends the run after its step, a second still within the run
    stops it at once, counted as the user's (exit 130, no watchdog line); those that land after the
    run ended, while its files are written, are ignored: the summary, the plot and the documents are
    all there, and no traceback."""
    proc = bench_run(
        iocs["free"],
        tmp_path,
        "--prefix",
        "FR:",
        "--stages",
        "3",
        "--controller",
        "spgd",
        "--seconds",
        "120",
        "--stale-s",
        "5",
    )
    wait_for_events(proc, tmp_path, 10)
    deadline = time.monotonic() + 60
    while proc.proc.poll() is None and time.monotonic() < deadline:
        proc.proc.send_signal(signal.SIGINT)
        time.sleep(0.05)
    rc, log = finish(proc, timeout=60)
    assert rc == 130 and "Traceback" not in log and "watchdog:" not in log, log
    assert "the run has ended; writing what it recorded" in log, (
        log
    )  # presses after the run were answered
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["stopped_by"] == "user", summary
    docs = documents(tmp_path)
    events = [d["doc"] for d in docs if d["name"] == "event"]
    assert docs[-1]["name"] == "stop" and len(events) == summary["steps"]
    assert (tmp_path / "out" / "power.png").stat().st_size > 0


def test_ctrl_c_while_the_runner_starts_prints_one_line_and_records_nothing(tmp_path):
    """SIGINT once the runner has said it is starting (building its controller, or waiting for PVs
    that never answer): exit 130, one line, no traceback, nothing written to --out."""
    mapping = {**sim_mapping("NOBODY:", 3, lengths=False), "safety": {"connect_s": 120.0}}
    (tmp_path / "map.json").write_text(json.dumps(mapping))
    proc = Process(
        "agents.bench",
        ["--mapping", tmp_path / "map.json", "--controller", "spgd", "--out", tmp_path / "out"],
        ca_env(),
        tmp_path / "runner.log",
    )
    proc.wait_for("agents.bench.runner: starting")
    time.sleep(1.0)
    proc.proc.send_signal(signal.SIGINT)
    rc, log = finish(proc, timeout=30)
    assert rc == 130 and "Traceback" not in log, log
    assert log.strip().splitlines()[1:] == [
        f"interrupted: stopped while starting; nothing recorded in {tmp_path / 'out'}"
    ]
    assert not (tmp_path / "out").exists()


INTERRUPTS = """
import json, os, random, signal, sys, threading, time
from pathlib import Path
from agents.bench import execute, frozen, loop as bench, report
from agents.bench.lifecycle import arm, connect, disconnect
from agents.bench.mapping import check_mapping, sim_mapping
from agents.bench.devices import make_bench

prefix, out, runs = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3])
mapping = check_mapping({**sim_mapping(prefix, 3, lengths=False), "safety": {"stale_s": 5.0}})
agent, _, scale, window = frozen.load_controller("spgd", mapping, {}, {}, seed=0)
device, lines = make_bench(mapping)
connect(device, 30)
arm(device, lines)
rng = random.Random(0)
for k in range(runs):
    loop = bench.Loop(device, lines, mapping, agent, scale, window, seconds=60, rate=100)
    loop.watch()
    sent = []
    def interrupt(loop=loop, delay=rng.uniform(0, 0.3),
                  signum=(signal.SIGINT, signal.SIGTERM)[k % 2]):
        while loop.t0 is None:
            time.sleep(0.001)
        time.sleep(delay)
        sent.append(time.perf_counter())
        os.kill(os.getpid(), signum)
    threading.Thread(target=interrupt, daemon=True).start()
    (out / str(k)).mkdir(parents=True)
    elapsed = execute.run_plan(loop, {"plan_name": "interrupts"}, out / str(k))
    s = report.summarize(loop, "spgd", elapsed)
    print(json.dumps({"stopped_by": s["stopped_by"], "steps": s["steps"],
                      "after_s": time.perf_counter() - sent[0]}), flush=True)
disconnect(device)
sys.stdout.flush()
os._exit(0)
"""


def test_one_interrupt_ends_the_run_after_the_step_20_times_in_a_row(iocs, tmp_path):
    """20 runs in one process on a bench without length readouts (SPGD), each ended by one SIGINT or
    SIGTERM at a random moment of the run: each stops by the user within a step and a flush, its
    documents complete."""
    runs = 20
    out = subprocess.run(
        [sys.executable, "-c", INTERRUPTS, "FR:", str(tmp_path), str(runs)],
        env=iocs["free"].env,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=START_S,
    )
    assert out.returncode == 0, out.stderr
    results = [json.loads(line) for line in out.stdout.splitlines()]
    assert len(results) == runs, out.stdout + out.stderr
    for k, r in enumerate(results):
        assert r["stopped_by"] == "user" and r["steps"] >= 1 and r["after_s"] < 2.0, (k, r)
        docs = [
            json.loads(line)
            for line in (tmp_path / str(k) / "documents.jsonl").read_text().splitlines()
        ]
        events = [d["doc"] for d in docs if d["name"] == "event"]
        assert docs[-1]["name"] == "stop" and docs[-1]["doc"]["exit_status"] == "success", (
            k,
            docs[-1],
        )
        assert len(events) == r["steps"] and [e["seq_num"] for e in events] == list(
            range(1, r["steps"] + 1)
        )
        assert not any(key.startswith("bench_length") for key in events[0]["data"]), events[0][
            "data"
        ]


def test_controller_reading_lengths_fails_at_start_without_them(iocs, tmp_path):
    rc, log = finish(
        bench_run(
            iocs["free"],
            tmp_path,
            "--prefix",
            "FR:",
            "--stages",
            "3",
            "--no-lengths",
            "--controller",
            "physics",
            "--set",
            "use_lengths=True",  # explicit: the frames configuration is not chosen for it
            "--set",
            "starts=2",
        )
    )
    said = [line for line in log.splitlines() if line.startswith("agents.bench.runner:")][
        1:
    ]  # after "starting"
    assert rc == 2 and len(said) == 1 and "physics" in said[0] and "lines[2].length" in said[0], log


def test_lab_benchmark_runs_frames_only_with_the_wrap_on_a_seeded_bench(tmp_path):
    """``benchmarks.lab --frames-only --wrap --idle-s --seeds --cpu --trims``: a bench serving no
    length readouts, a runner mapping none, started after the idle time, on a core of its own, its
    controller wrapped in the trim; the row names the bench's seed, the trim and the tick of the
    first step."""
    from benchmarks import lab

    result = lab.main(
        [
            "--seconds",
            "3",
            "--controllers",
            "spgd",
            "--frames-only",
            "--wrap",
            "0.5",
            "--idle-s",
            "2",
            "--seeds",
            "3",
            "--no-kill",
            "--stale-s",
            "5",
            "--cpu",
            str(max(os.sched_getaffinity(0))),
            "--trims",
            "bench",
            "--settle-s",
            "0.003",
            "--out",
            str(tmp_path),
        ]
    )
    (row,) = result["rows"]
    assert row["stopped_by"] == "time" and row["bench_seed"] == 3 and row["steps"] > 10, row
    assert (
        row["first_tick"] >= 150 and "wrapped_moves" in row
    )  # at least the 2 s of idling at 100 ticks/s
    run = tmp_path / "spgd-trim-bench-100hz-settle3ms-seed3" / "run"
    summary = json.loads((run / "summary.json").read_text())
    assert (
        summary["controller"] == "spgd" and summary["probes_per_step"] == 2
    )  # SPGD's probe and the trim's
    # the ceilings of the bench the lab started, written into the run's summary.json
    bench = lab.bench_env(lab.RunSettings(1, 100, 5, frames_only=True, seed=3))
    ceilings = ops_jax.imperfections.ceilings(ops_jax.EnvSpec.from_options(bench))
    assert summary["held_power"] == ceilings.held and row["held_power"] == ceilings.held
    assert summary["p_over_held_mean"] == pytest.approx(
        summary["p_over_pbest_mean"] / ceilings.held
    )
    assert f"| {summary['p_over_held_mean']:.4f} / " in lab.table(result["rows"])
    start = json.loads((run / "documents.jsonl").read_text().splitlines()[0])["doc"]
    assert start["mapping"]["safety"]["wrap_wl"] == 0.5 and all(
        "length" not in x for x in start["mapping"]["lines"]
    )
    assert start["mapping"]["detector"]["settle_s"] == 0.003 and row["settle_s"] == 0.003
    assert "--observe-lengths False" in " ".join(result["ioc"])
    assert "LEN" not in (tmp_path / "spgd-trim-bench-100hz-settle3ms-seed3" / "run.log").read_text()
    assert (
        "| spgd + trim bench (settle 3 ms) | 3 |" in lab.table(result["rows"])
        and row["trim"] == "bench"
    )
    # each step's frame checked against the IOC's tick log (free-running: some may come before the
    # move)
    assert (tmp_path / "spgd-trim-bench-100hz-settle3ms-seed3" / lab.TICK_LOG).exists()
    assert (
        row["early_frames_checked"] >= row["steps"] - 2
        and 0 <= row["early_frames"] <= row["early_frames_checked"]
    )


def test_lab_puts_the_bench_on_the_cores_the_runner_leaves(tmp_path):
    """``benchmarks.lab --cpu CORE``: a started process (the IOC) runs on the other cores; a core
    out of reach fails naming ``--cpu``."""
    from benchmarks import lab

    cores = os.sched_getaffinity(0)
    core = max(cores)
    assert lab.other_cores(None) is None
    others = lab.other_cores(core)
    assert others == ((cores - {core}) or None)
    with pytest.raises(ValueError, match=r"--cpu must be one of the cores .* got 100000"):
        lab.other_cores(100_000)
    proc = lab.Process(
        "http.server",
        ["0", "--bind", "127.0.0.1"],
        dict(os.environ),
        tmp_path / "http.log",
        cpus={core},
    )
    try:
        proc.wait_for("Serving", 60)
        assert os.sched_getaffinity(proc.proc.pid) == {core}
    finally:
        proc.kill()


def test_unseen_bench_reaches_the_ioc_as_the_budget_section_draws_it():
    """``benchmarks.lab --unseen``: the IOC's options give the bench of
    ``benchmarks.budget.plan.unseen_bench``."""
    from benchmarks.budget.plan import unseen_bench
    from benchmarks.lab import IOC_ARGS, unseen_args

    ns = ioc.parser().parse_args(
        [*IOC_ARGS, "--imperfection-scale", "2.0", *unseen_args(1011, 2.0)]
    )
    got = ioc.make_options(ns)
    want = unseen_bench({"stages": 5, "mode": "hard"}, 1011, 2.0)
    assert got["imperfections"] == "lab" and got["imperfection_scale"] == 2.0
    drawn = [k for k, v in want.items() if isinstance(v, list)]
    assert len(drawn) >= 3 and all(np.allclose(got[k], want[k]) for k in drawn)
    assert unseen_args(1011, 2.0) != unseen_args(1012, 2.0)
