"""A lab's first steps with the bench: a template mapping to start from, and a check of a mapping
against the live bench that moves nothing.

    python -m agents.bench template --out mapping.json \
        [--prefix OPS: --stages 5 --no-lengths --lockstep]
    python -m agents.bench check --mapping mapping.json

``template`` writes the simulated bench's mapping
(``python -m ops_jax.ioc --prefix OPS: --stages 5``), every key with its value and a note beside
each part (keys that start with ``_``, ignored by the runner): replace the PV names, units and
limits by the bench's. ``check`` connects to every PV the mapping names, reads each once and prints
what it found (value, units and limits where the IOC serves them), writing nothing; it says what
does not fit the mapping (a trace of another length than the lines' 2^N - 1 pulses, a soft range
outside a setpoint's limits, a reading that is not finite). Exit status 0 when everything answered
and fits, 1 when something does not fit, 2 for a bad mapping or PVs that do not answer (one line
naming them).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from agents.bench.lifecycle import connect, disconnect, signals
from agents.bench.devices import make_bench
from agents.bench.mapping import MappingError, check_mapping, load_mapping, sim_mapping

COMMANDS = ("template", "check")
NOTES = {
    "_about": "The PVs of an OPS bench for `python -m agents.bench --mapping FILE`, here the "
    "simulated bench's (`python -m ops_jax.ioc --prefix PREFIX --stages N`): on a real bench put "
    "its PV names, units and limits in their place. Keys that start with _ are notes (ignored). "
    "`python -m agents.bench check --mapping FILE` reads every PV once and writes nothing. Every "
    "key: docs/lab.md, 'A real bench: the mapping file'.",
    "_lines": "One per delay line, in the order of the stages: setpoint (written), readback, "
    "length (optional: a sensor of the line's offset from the optimum; leave it out where there "
    "is none, and the physics-informed controller runs on the detector's frames alone).",
    "_detector": "power: the stacked-power detector (power_full_scale: its reading at P_max); "
    "trace: the oscilloscope waveform, 2^N - 1 samples at the pulse positions (trace_peak: one "
    "ideal pulse's peak); tick: a counter that changes once per complete acquisition; settle_s: "
    "from a setpoint write until a frame acquired after it shows the move (s).",
    "_evaluation": "The simulator's true P / P_max and P / P_best, recorded, never shown to a "
    "controller: remove it on a real bench.",
    "_advance": "A PV whose write advances a lockstep simulator one tick; null on a free-running "
    "bench.",
    "_units_per_wl": "Setpoint units per wavelength (1.03 for micrometres at 1030 nm, volts per "
    "wavelength for an open-loop piezo).",
    "_period_wl": "The optics' period in a line's position (wl; 0.5 for a folded delay line); "
    "null where unknown.",
    "_safety": "max_step_wl: the largest move of a line in one step (wl); soft_range_wl: [low, "
    "high] (wl) inside the actuators' travel, or one per line; stale_s: the watchdog's limit on "
    "a reading's age (s); connect_s: the wait for every PV at start (s); wrap_wl: a line within "
    "it of a soft limit is taken back by it (null: the period_wl where the controller reads no "
    "length readouts, 0: never).",
}


def template(prefix: str, stages: int, lengths: bool = True, lockstep: bool = False) -> dict:
    """The simulated bench's mapping, every key written out, each part preceded by its note
    (``NOTES``)."""
    mapping = check_mapping(sim_mapping(prefix, stages, lockstep, lengths))
    out = {"_about": NOTES["_about"]}
    for key, value in mapping.items():
        out[f"_{key}"], out[key] = NOTES[f"_{key}"], value
    return out


def entries(mapping: dict) -> list:
    """(where in the mapping, PV name) of every PV a checked ``mapping`` names, in its order."""
    found = [
        (f"lines[{i}].{key}", pv)
        for i, line in enumerate(mapping["lines"])
        for key, pv in line.items()
    ]
    found += [(f"detector.{key}", mapping["detector"][key]) for key in ("power", "trace", "tick")]
    found += [(f"evaluation.{key}", pv) for key, pv in mapping["evaluation"].items()]
    return found + ([("advance", mapping["advance"])] if mapping["advance"] else [])


def _shown(value) -> str:
    """A reading in a few characters: a number, or a waveform's length and range."""
    array = np.atleast_1d(np.asarray(value))
    if array.size == 1:
        return str(array[0]) if array.dtype.kind in "US" else f"{float(array[0]):.6g}"
    return f"{array.size} samples in [{float(array.min()):.4g}, {float(array.max()):.4g}]"


def read(sig) -> dict:
    """One reading of ``sig`` (connected): its value, units and control limits where the IOC serves
    them."""
    value, meta = sig.get(), sig.metadata
    low, high = meta.get("lower_ctrl_limit"), meta.get("upper_ctrl_limit")
    return {
        "value": value,
        "units": meta.get("units") or "",
        "limits": (low, high) if low is not None and high is not None and low < high else None,
    }


def misfits(mapping: dict, readings: dict) -> list:
    """What the readings (where -> ``read``) say does not fit ``mapping``: the trace's length, a
    soft range outside a setpoint's limits, a reading that is not finite."""
    found, n = [], len(mapping["lines"])
    samples = np.atleast_1d(readings["detector.trace"]["value"]).size
    if samples != 2**n - 1:
        found.append(f"detector.trace has {samples} samples; {n} lines make {2**n - 1} pulses")
    for i, (low, high) in enumerate(mapping["safety"]["soft_range_wl"]):
        limits = readings[f"lines[{i}].setpoint"]["limits"]
        span = np.multiply([low, high], mapping["units_per_wl"])
        if limits is not None and not (limits[0] <= span[0] and span[1] <= limits[1]):
            found.append(
                f"safety.soft_range_wl of line {i + 1}, {span.tolist()} in setpoint units, lies "
                f"outside lines[{i}].setpoint's limits {list(limits)}"
            )
    for where, r in readings.items():
        value = np.asarray(r["value"])
        if value.dtype.kind in "fiu" and not np.all(np.isfinite(value)):
            found.append(f"{where} reads {_shown(value)}, not finite")
    return found


def check(mapping: dict) -> int:
    """Connect to every PV of a checked ``mapping``, read each once, print what was found; writes
    nothing. The exit status (module docstring); ``MappingError`` names the PVs that did not
    answer."""
    bench, _ = make_bench(mapping)
    try:
        connect(bench, mapping["safety"]["connect_s"])
        by_name = signals(bench)
        readings = {where: read(by_name[pv]) for where, pv in entries(mapping)}
    finally:
        disconnect(bench)
    width = max(len(where) for where in readings)
    for (where, pv), r in zip(entries(mapping), readings.values()):
        limits = "" if r["limits"] is None else f", limits [{r['limits'][0]:g}, {r['limits'][1]:g}]"
        print(f"{where:<{width}}  {pv}: {_shown(r['value'])} {r['units']}{limits}".rstrip())
    problems = misfits(mapping, readings)
    for problem in problems:
        print(f"does not fit: {problem}")
    print(f"{len(readings)} PVs answered, {len(problems)} misfits; nothing was written", flush=True)
    return 1 if problems else 0


def _bench_options(ap: argparse.ArgumentParser) -> None:
    """The simulated bench's options, as the runner takes them."""
    ap.add_argument("--prefix", default="OPS:", help="PV prefix of the simulated bench")
    ap.add_argument("--stages", type=int, default=5, help="delay lines of the simulated bench")
    ap.add_argument(
        "--no-lengths", action="store_true", help="without its length readouts (LINEi:LEN)"
    )
    ap.add_argument("--lockstep", action="store_true", help="started with --lockstep (ADVANCE)")


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m agents.bench", description=__doc__.split("\n\n")[0]
    )
    commands = ap.add_subparsers(dest="command", required=True)
    written = commands.add_parser(
        "template", help="write the simulated bench's mapping, every key with a note, to start from"
    )
    written.add_argument(
        "--out", required=True, help="the mapping file to write (JSON; not there yet)"
    )
    _bench_options(written)
    checked = commands.add_parser(
        "check", help="read every PV of a mapping once and say what was found; writes nothing"
    )
    checked.add_argument("--mapping", help="the mapping file (default: the simulated bench's)")
    _bench_options(checked)
    checked.add_argument(
        "--connect-s",
        type=float,
        default=None,
        help="the wait for every PV (s; default: the mapping's)",
    )
    return ap


def main(argv) -> int:
    """``python -m agents.bench template|check ...``; the exit status."""
    args = parser().parse_args(argv)
    try:
        if args.stages < 1:
            raise ValueError(f"--stages must be >= 1, got {args.stages}")
        if args.command == "template":
            out = Path(args.out)
            if out.exists():
                raise ValueError(f"--out {out} exists already: give another file")
            out.write_text(
                json.dumps(
                    template(args.prefix, args.stages, not args.no_lengths, args.lockstep), indent=2
                )
                + "\n"
            )
            print(
                f"wrote {out}: edit its PV names, units and limits, then: python -m agents.bench "
                f"check --mapping {out}"
            )
            return 0
        mapping = (
            load_mapping(args.mapping)
            if args.mapping
            else check_mapping(
                sim_mapping(args.prefix, args.stages, args.lockstep, not args.no_lengths)
            )
        )
        if args.connect_s is not None:
            safety = {**mapping["safety"], "connect_s": args.connect_s}
            mapping = check_mapping({**mapping, "safety": safety})
        return check(mapping)
    except (MappingError, ValueError, OSError) as exc:
        print(f"agents.bench {args.command}: {exc}", file=sys.stderr, flush=True)
        return 2
