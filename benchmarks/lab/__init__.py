"""Controllers on the simulated bench over real Channel Access (``python -m benchmarks.lab``; the
command's options and columns: benchmarks/lab/command.py): the processes (``processes``), the runs
on a fresh IOC (``runs``) and the command line (``command``)."""

from benchmarks.lab.command import main, parser, table
from benchmarks.lab.processes import (
    START_S,
    TICK_LOG,
    Process,
    ca_env,
    early_frames,
    free_port,
    start_ioc,
)
from benchmarks.lab.runs import (
    CONTROLLERS,
    FRAMES_ONLY,
    IOC_ARGS,
    LearnSettings,
    RunSettings,
    bench_env,
    ioc_args,
    kill_check,
    other_cores,
    run_controller,
    run_learning,
    unseen_args,
)

__all__ = [
    "CONTROLLERS",
    "FRAMES_ONLY",
    "IOC_ARGS",
    "START_S",
    "TICK_LOG",
    "LearnSettings",
    "Process",
    "RunSettings",
    "bench_env",
    "ca_env",
    "early_frames",
    "free_port",
    "ioc_args",
    "kill_check",
    "main",
    "other_cores",
    "parser",
    "run_controller",
    "run_learning",
    "start_ioc",
    "table",
    "unseen_args",
]
