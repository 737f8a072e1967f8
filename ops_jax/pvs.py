"""The PV names of the simulated bench, after its prefix: ``ops_jax.ioc`` serves them and
``agents.bench.mapping`` maps them (one table, read by both)."""

from __future__ import annotations

# per delay line i = 1..N: the setpoint (writable), the readback and the length readout (wl)
LINE_SETPOINT = "LINE{i}:SP"
LINE_READBACK = "LINE{i}:RBV"
LINE_LENGTH = "LINE{i}:LEN"
DETECTOR_POWER = "DET:POWER"  # the detector reading (P_max units)
SCOPE_TRACE = "SCOPE:TRACE"  # the oscilloscope samples (ideal pulse peak units)
EVAL_P_PMAX = "EVAL:P_PMAX"  # the true P / P_max, for evaluation only
EVAL_P_PBEST = "EVAL:P_PBEST"  # the true P / P_best, for evaluation only
TICK = "TICK"  # the frame counter: published last in a tick
STATUS = "STATUS"
OVERRUNS = "OVERRUNS"
RATE = "RATE"  # ticks per second (Hz; 0 in lockstep)
ADVANCE = "ADVANCE"  # lockstep: a write advances one tick
RESET = "RESET"  # a non-zero write starts the bench again


def line_pv(suffix: str, i: int) -> str:
    """Line ``i``'s (1..N) PV suffix of ``suffix`` (``LINE_SETPOINT``, ``LINE_READBACK``,
    ``LINE_LENGTH``)."""
    if not (isinstance(i, int) and i >= 1):
        raise ValueError(f"line i must be an integer >= 1, got {i!r}")
    return suffix.format(i=i)
