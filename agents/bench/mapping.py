"""The mapping file that names an OPS bench's PVs, units and limits (``agents.bench`` reads it;
``agents.bench.devices`` builds the bench's ophyd devices from it).

The mapping (JSON) says which PV holds what and in which units; every key but ``lines`` and
``detector`` has a default. Positions in the PVs' own units (``units_per_wl`` of them per
wavelength); the safety limits in wavelengths::

    {"lines": [{"setpoint": "OPS:LINE1:SP", "readback": "OPS:LINE1:RBV",
                "length": "OPS:LINE1:LEN"}, ...],
     "detector": {"power": "OPS:DET:POWER", "trace": "OPS:SCOPE:TRACE", "tick": "OPS:TICK",
                  "power_full_scale": 1.0, "trace_peak": 1.0, "settle_s": 0.002},
     "evaluation": {"p_pmax": "OPS:EVAL:P_PMAX", "p_pbest": "OPS:EVAL:P_PBEST"},
     "advance": null, "units_per_wl": 1.0, "period_wl": 0.5,
     "safety": {"max_step_wl": 0.3, "soft_range_wl": [-3.0, 3.0], "stale_s": 0.5, "connect_s": 5.0,
                "wrap_wl": null}}

``length`` (a line's offset from the optimum as a calibrated sensor reads it) may be omitted: the
controller then sees 0 there. ``power_full_scale``: the detector reading at P_max; ``trace_peak``:
the scope reading of the ideal pulse peak; ``settle_s``: from a setpoint write until a frame
acquired later shows it (the write's transit and the actuator's settling; frames are told apart by
their time stamps, the acquisition's start). ``evaluation`` PVs (optional) are recorded, never shown
to a controller. ``advance`` (optional): a PV whose write advances a lockstep simulator by one tick.
``soft_range_wl`` is one [low, high] for every line or a list of one per line. ``period_wl``
(optional): the period of the optics in a line's position (wl / 2 for a folded delay line).
``wrap_wl``: with it a move that would come within ``wrap_wl`` of a soft limit is taken ``wrap_wl``
back towards the middle (a fringe jump when it is the period: the optics see the same state), so a
controller can follow a drift for as long as it lasts. Such a move may exceed ``max_step_wl`` by
``wrap_wl``: map it only where that is safe, and only for controllers that do not read the length
readouts (a readout jumps by the period). ``wrap_wl`` null (the default) leaves the choice to the
runner (``agents.bench.defaults``: the period, where the controller allows it), 0 turns the wrap
off. Keys that start with ``_`` are notes, ignored (``agents.bench.template`` writes them).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ops_jax import pvs

# The simulated bench's optics repeat when a line moves by half a wavelength: a delay of x wl turns
# the phase of its pulses by 4 pi x (ops_jax.physics, a folded delay line's round trip)
SIM_PERIOD_WL = 0.5

SETTLE_S = 0.002  # default detector.settle_s (s): a write's transit to a local IOC, with margin
SETTLE_RANGE_S = (0.0, 10.0)  # detector.settle_s's accepted range (s, both ends included)
SAFETY_DEFAULTS = {
    "max_step_wl": 0.3,
    "soft_range_wl": [-3.0, 3.0],
    "stale_s": 0.5,
    "connect_s": 5.0,
    "wrap_wl": None,
}
_KEYS = {
    "": {"lines", "detector", "evaluation", "advance", "units_per_wl", "period_wl", "safety"},
    "lines[]": {"setpoint", "readback", "length"},
    "detector": {"power", "trace", "tick", "power_full_scale", "trace_peak", "settle_s"},
    "evaluation": {"p_pmax", "p_pbest"},
    "safety": set(SAFETY_DEFAULTS),
}


class MappingError(ValueError):
    """A mapping file that cannot describe a bench; the message names the key."""


def sim_mapping(prefix: str, stages: int, lockstep: bool = False, lengths: bool = True) -> dict:
    """The mapping of the simulated bench ``python -m ops_jax.ioc --prefix PREFIX --stages N``
    (``lockstep``: started with ``--lockstep``; ``lengths=False``: without its length readouts), its
    PV names from ``ops_jax.pvs``."""
    return {
        "advance": prefix + pvs.ADVANCE if lockstep else None,
        "lines": [
            {
                "setpoint": prefix + pvs.line_pv(pvs.LINE_SETPOINT, i),
                "readback": prefix + pvs.line_pv(pvs.LINE_READBACK, i),
                **({"length": prefix + pvs.line_pv(pvs.LINE_LENGTH, i)} if lengths else {}),
            }
            for i in range(1, stages + 1)
        ],
        "detector": {
            "power": prefix + pvs.DETECTOR_POWER,
            "trace": prefix + pvs.SCOPE_TRACE,
            "tick": prefix + pvs.TICK,
        },
        "evaluation": {"p_pmax": prefix + pvs.EVAL_P_PMAX, "p_pbest": prefix + pvs.EVAL_P_PBEST},
        "period_wl": SIM_PERIOD_WL,
    }


def _check_keys(where: str, table, allowed: set, required=()) -> None:
    if not isinstance(table, dict):
        raise MappingError(
            f"mapping: {where or 'the top level'} must be an object, got {type(table).__name__}"
        )
    unknown = sorted(set(dict(_fields(table))) - allowed)
    if unknown:
        raise MappingError(
            f"mapping: unknown key(s) {unknown} in {where or 'the top level'}; accepted: "
            f"{sorted(allowed)}"
        )
    missing = [k for k in required if k not in table]
    if missing:
        raise MappingError(f"mapping: {where or 'the top level'} lacks {missing}")


def _fields(table: dict) -> list:
    """``table``'s (key, value) pairs but its notes (keys that start with ``_``)."""
    return [(k, v) for k, v in table.items() if not str(k).startswith("_")]


def _pv(where: str, value) -> str:
    if not isinstance(value, str) or not value or any(c.isspace() for c in value):
        raise MappingError(
            f"mapping: {where} must be a PV name (a non-empty string without spaces), got {value!r}"
        )
    return value


def _number(
    where: str, value, low: float, high: float = np.inf, low_included: bool = False
) -> float:
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not (number and (low <= value if low_included else low < value) and value <= high):
        raise MappingError(
            f"mapping: {where} must be a number in {'[' if low_included else '('}{low:g}, "
            f"{high:g}], got {value!r}"
        )
    return float(value)


def check_mapping(m: dict) -> dict:
    """The validated mapping with defaults filled in; ``MappingError`` names the first bad key."""
    _check_keys("", m, _KEYS[""], required=("lines", "detector"))
    if not isinstance(m["lines"], list) or not m["lines"]:
        raise MappingError("mapping: lines must be a non-empty list of delay lines")
    lines = []
    for i, line in enumerate(m["lines"]):
        _check_keys(f"lines[{i}]", line, _KEYS["lines[]"], required=("setpoint", "readback"))
        lines.append({k: _pv(f"lines[{i}].{k}", v) for k, v in _fields(line) if v is not None})
    det = m["detector"]
    _check_keys("detector", det, _KEYS["detector"], required=("power", "trace", "tick"))
    detector = {k: _pv(f"detector.{k}", det[k]) for k in ("power", "trace", "tick")}
    for k in ("power_full_scale", "trace_peak"):
        detector[k] = _number(f"detector.{k}", det.get(k, 1.0), 0.0)
    detector["settle_s"] = _number(
        "detector.settle_s", det.get("settle_s", SETTLE_S), *SETTLE_RANGE_S, low_included=True
    )
    ev = m.get("evaluation") or {}
    _check_keys("evaluation", ev, _KEYS["evaluation"])
    safety = {**SAFETY_DEFAULTS, **(m.get("safety") or {})}
    _check_keys("safety", safety, _KEYS["safety"])
    safety = dict(_fields(safety))
    for k in ("max_step_wl", "stale_s", "connect_s"):
        safety[k] = _number(f"safety.{k}", safety[k], 0.0, 1e6)
    try:
        rng = np.broadcast_to(np.asarray(safety["soft_range_wl"], float), (len(lines), 2))
    except (TypeError, ValueError):
        raise MappingError(
            f"mapping: safety.soft_range_wl must be [low, high] or one per line "
            f"({len(lines)} lines), got {safety['soft_range_wl']!r}"
        ) from None
    if not np.all(np.isfinite(rng)) or np.any(rng[:, 0] >= rng[:, 1]):
        raise MappingError(
            f"mapping: safety.soft_range_wl needs finite low < high, got {rng.tolist()}"
        )
    safety["soft_range_wl"] = rng.tolist()
    if safety["wrap_wl"] is not None:
        third = (
            float(np.min(rng[:, 1] - rng[:, 0])) / 3
        )  # a wrapped line lands clear of the other limit's band
        safety["wrap_wl"] = _number(
            "safety.wrap_wl", safety["wrap_wl"], 0.0, third, low_included=True
        )
    advance, period = m.get("advance"), m.get("period_wl")
    return {
        "lines": lines,
        "detector": detector,
        "evaluation": {k: _pv(f"evaluation.{k}", v) for k, v in _fields(ev)},
        "advance": None if advance is None else _pv("advance", advance),
        "units_per_wl": _number("units_per_wl", m.get("units_per_wl", 1.0), 0.0),
        "period_wl": None if period is None else _number("period_wl", period, 0.0, 1e6),
        "safety": safety,
    }


def missing_lengths(mapping: dict) -> list:
    """The ``lines[i].length`` entries a checked ``mapping`` lacks."""
    return [f"lines[{i}].length" for i, line in enumerate(mapping["lines"]) if "length" not in line]


def read_mapping(path) -> dict:
    """A mapping file's JSON as written (not validated: ``check_mapping``)."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise MappingError(f"mapping: no file at {path}") from None
    except json.JSONDecodeError as exc:
        raise MappingError(f"mapping: {path} is not valid JSON ({exc})") from None


def load_mapping(path) -> dict:
    """Read and validate a mapping file (JSON)."""
    return check_mapping(read_mapping(path))
