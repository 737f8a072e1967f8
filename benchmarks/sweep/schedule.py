"""How the sweep's executor schedules its units and projects the time left: which unit an idle
worker takes, and a ledger of estimated against measured worker-seconds per kind of unit."""

from __future__ import annotations

import dataclasses
import time
from collections import Counter

from benchmarks.sweep.records import Unit

IN_FLIGHT_CAP = 0.9  # a running unit counts as done up to this fraction of its projected cost


def unit_kind(unit: Unit) -> str:
    """What a unit's cost is measured per: training per algorithm (its budget is the preset's),
    evaluation, or a section's own cells."""
    return {"train": f"train {unit.algo}", "eval": "eval"}.get(unit.kind, f"cell {unit.algo}")


def projected_seconds(est_left: Counter, est_done: Counter, spent: Counter) -> float:
    """Worker-seconds of the work left: each kind's estimate (``est_left``) scaled by that kind's
    measured seconds (``spent``) per estimated second of its finished units (``est_done``), or by
    all kinds' ratio for a kind not seen finish yet (1 before any)."""
    return sum(left * cost_ratio(k, est_done, spent) for k, left in est_left.items())


def cost_ratio(kind: str, est_done: Counter, spent: Counter) -> float:
    """Measured seconds per estimated second of ``kind``'s finished units (all kinds' if none, 1
    before any)."""
    if est_done[kind]:
        return spent[kind] / est_done[kind]
    return sum(spent.values()) / sum(est_done.values()) if sum(est_done.values()) else 1.0


class SmoothedTotal:
    """The progress line's total worker-seconds: each new projection moves it by ``weight`` of the
    way (an exponential moving average, so the remaining time does not jump with each finished
    unit's correction; exactly the projection when nothing is left), and it is cut where needed so
    that the fraction done never decreases."""

    def __init__(self, weight: float = 0.3):
        self.weight = weight
        self.total = None
        self.fraction = 0.0

    def __call__(self, done: float, projected: float) -> float:
        """The total to show for ``done`` worker-seconds out of a ``projected`` total."""
        if (
            self.total is None or projected <= done
        ):  # the first projection, or nothing left: as projected
            total = projected
        else:
            total = self.total + self.weight * (projected - self.total)
        total = max(total, done)
        if total > 0 and done / total < self.fraction:
            total = done / self.fraction
        self.total, self.fraction = total, (done / total if total > 0 else 0.0)
        return total


def _show(bar, smoothed: SmoothedTotal, spent: Counter, in_flight: float, left: float) -> None:
    """Progress in worker-seconds: finished units' measured seconds plus the running units' time so
    far, out of that plus the projected work left beyond what is running (``SmoothedTotal``)."""
    done = sum(spent.values()) + in_flight
    bar.total = round(smoothed(done, done + max(left - in_flight, 0.0)), 1)
    bar.update(round(done - bar.n, 1))


def pick(ready: list, last_algo, running_algos: Counter, remaining: dict):
    """The unit an idle worker takes from ``ready`` (in plan order): one of the algorithm it ran
    last (warm programs), else of the algorithm with the most remaining cost that no other worker
    runs, else of the one with the most remaining cost."""
    if not ready:
        return None
    same = [u for u in ready if u.algo == last_algo]
    if same:
        return same[0]
    free = [u for u in ready if not running_algos[u.algo]] or ready
    return max(free, key=lambda u: remaining[u.algo])  # max keeps the first of equals: plan order


@dataclasses.dataclass
class Ledger:
    """Estimated and measured worker-seconds of the units: ``remaining`` estimate per algorithm,
    ``est_left`` / ``est_done`` estimate per kind (``unit_kind``) not yet / already finished,
    ``spent`` measured seconds per kind."""

    remaining: Counter = dataclasses.field(default_factory=Counter)
    est_left: Counter = dataclasses.field(default_factory=Counter)
    est_done: Counter = dataclasses.field(default_factory=Counter)
    spent: Counter = dataclasses.field(default_factory=Counter)

    @classmethod
    def of(cls, units) -> "Ledger":
        """The ledger of ``units`` none of which has run."""
        ledger = cls()
        for u in units:
            ledger.remaining[u.algo] += u.cost
            ledger.est_left[unit_kind(u)] += u.cost
        return ledger

    def finished(self, unit: Unit, seconds: float) -> None:
        """Book ``unit`` as finished after ``seconds`` of work."""
        kind = unit_kind(unit)
        self.remaining[unit.algo] -= unit.cost
        self.est_left[kind] -= unit.cost
        self.est_done[kind] += unit.cost
        self.spent[kind] += seconds

    def projected(self) -> float:
        """Worker-seconds of the work left (``projected_seconds``)."""
        return projected_seconds(self.est_left, self.est_done, self.spent)

    def in_flight(self, unit: Unit, started: float, now: float) -> float:
        """The seconds ``unit``, started at ``started`` (monotonic s), counts as done at ``now``:
        its time so far, up to ``IN_FLIGHT_CAP`` of its projected cost (a unit running over its
        estimate holds the line back instead of showing nothing left)."""
        cap = IN_FLIGHT_CAP * unit.cost * cost_ratio(unit_kind(unit), self.est_done, self.spent)
        return min(now - started, cap)

    def show(self, bar, smoothed: SmoothedTotal, running) -> None:
        """The progress line for the units ``running`` ({ref: (worker, unit, start)})."""
        now = time.monotonic()
        in_flight = sum(self.in_flight(u, t, now) for _, u, t in running.values())
        _show(bar, smoothed, self.spent, in_flight, self.projected())
