"""The processes of ``benchmarks.lab``: Channel Access confined to free localhost ports,
``python -m`` subprocesses in their own process groups, the simulated bench (``ops_jax.ioc``) and
the check of its tick log."""

from __future__ import annotations

import json
import os
import random
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
START_S = 300  # an IOC or runner start-up on a loaded 2-core machine (JAX import and compile)
TICK_LOG = "ticks.jsonl"  # the IOC's --tick-log, beside its ioc.log


def free_port(other: int | None = None) -> int:
    """A localhost port free for both TCP and UDP (Channel Access serves both on one port), not
    ``other``, and outside the kernel's range for auto-bound ports (from 20,000 up: clear of the
    well-known ports and of Ray's worker ports, 10002-19999). caproto binds an IOC's UDP port with
    SO_REUSEADDR and SO_REUSEPORT, as it does its client sockets, so a client socket the kernel
    auto-binds to the IOC's port takes the IOC's search replies for itself and the client's search
    times out."""
    from ops_jax.ioc_server import ephemeral_ports

    first, last = ephemeral_ports()
    outside = [*range(20_000, first), *range(last + 1, 65_536)] or [*range(1024, first)]
    if not outside:
        raise RuntimeError(
            "no localhost port for Channel Access outside the kernel's auto-bound range "
            f"{first}-{last}"
        )
    rng = random.SystemRandom()
    for _ in range(200):
        port = rng.choice(outside)
        with (
            socket.socket(socket.AF_INET, socket.SOCK_STREAM) as tcp,
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp,
        ):
            try:
                tcp.bind(("127.0.0.1", port))
                udp.bind(("127.0.0.1", port))
            except OSError:
                continue
            if port != other:
                return port
    raise RuntimeError(f"no free localhost port for Channel Access outside {first}-{last}")


def ca_env() -> dict:
    """This process's environment with Channel Access confined to a fresh localhost port."""
    server = free_port()
    return {
        **os.environ,
        "EPICS_CA_SERVER_PORT": str(server),
        "EPICS_CA_REPEATER_PORT": str(free_port(server)),
        "EPICS_CA_ADDR_LIST": "127.0.0.1",
        "EPICS_CA_AUTO_ADDR_LIST": "NO",
    }


class Process:
    """A ``python -m MODULE ARGS`` subprocess in its own process group, output to ``log``; ``cpus``:
    on these CPU cores only (Linux; None: any)."""

    def __init__(self, module: str, args, env: dict, log: Path, cpus: set | None = None):
        self.env, self.log = env, Path(log)
        run = (
            ["-m", module]
            if cpus is None
            else [  # the child sets its cores before it starts a thread
                "-c",
                f"import os, runpy; os.sched_setaffinity(0, {sorted(cpus)}); "
                f"runpy.run_module({module!r}, run_name='__main__', alter_sys=True)",
            ]
        )
        with open(self.log, "w") as f:
            self.proc = subprocess.Popen(
                [sys.executable, *run, *map(str, args)],
                stdout=f,
                stderr=subprocess.STDOUT,
                cwd=ROOT,
                env=env,
                start_new_session=True,
            )

    def text(self) -> str:
        """The output so far."""
        return self.log.read_text()

    def wait_for(self, needle: str, timeout: float = START_S) -> "Process":
        """Wait until ``needle`` is in the output; raise (with the output) if it exits or times
        out."""
        deadline = time.monotonic() + timeout
        while needle not in self.text():
            if self.proc.poll() is not None:
                raise RuntimeError(
                    f"{self.log.name}: exited with {self.proc.returncode}:\n{self.text()}"
                )
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f"{self.log.name}: no {needle!r} within {timeout} s:\n{self.text()}"
                )
            time.sleep(0.1)
        return self

    def wait(self, timeout: float = START_S) -> int:
        """The exit status; killed (and TimeoutError) past ``timeout`` s."""
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            raise TimeoutError(
                f"{self.log.name}: still running after {timeout} s:\n{self.text()}"
            ) from None

    def kill(self) -> None:
        """SIGKILL the whole process group."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(30)


def start_ioc(out: Path, *args, cpus: set | None = None) -> Process:
    """A simulated bench serving on a fresh port (on CPU cores ``cpus``; None: any), once it serves;
    its ticks logged to ``out/TICK_LOG``."""
    return Process(
        "ops_jax.ioc", [*args, "--tick-log", out / TICK_LOG], ca_env(), out / "ioc.log", cpus
    ).wait_for("serving")


def early_frames(documents: Path, ticks: Path) -> tuple[int, int]:
    """(steps whose frame the IOC computed from other setpoints than the move of the step before,
    steps checked): each event's frame tick looked up in the IOC's tick log (``--tick-log``) and its
    setpoints compared with the previous event's move (within a run; a run resumed into the same
    documents starts afresh)."""
    applied = {}
    for line in ticks.read_text().split("\n")[:-1]:  # whole lines: the IOC may be writing the last
        tick = json.loads(line)
        applied[tick["tick"]] = tick["setpoints"]
    early = checked = 0
    sent = None
    for line in documents.read_text().splitlines():
        doc = json.loads(line)
        if doc["name"] == "start":
            sent = None
        elif doc["name"] == "event":
            data = doc["doc"]["data"]
            seen = applied.get(data["bench_detector_tick"])
            if sent is not None and seen is not None:
                checked += 1
                early += any(abs(a - b) > 1e-9 for a, b in zip(seen, sent, strict=True))
            sent = data["control_setpoint_wl"]
    return early, checked
