"""A work unit of the lab-budget section (``benchmarks.budget.plan``): ``Cell``, a frozen record,
one per (controller, environment, seed); ``to_dict`` is its stored form (the configuration of
``benchmarks.cells.CellStore`` and of budget.json, whose hash keys the stored results) and
``Cell.from_dict`` reads it back."""

from __future__ import annotations

import dataclasses

# "learner" / "reference": protocol (a), from scratch on a simulated target; "adapt" / "bench
# reference": protocol (b), on an unseen bench (a learner pretrained on the randomised simulator / a
# controller that needs no training)
KINDS = ("learner", "reference", "adapt", "bench reference")
# the fields of protocol (b)'s cells alone ("bench reference": ``bench_seed`` alone), left out of
# the stored form of the others
ADAPT_FIELDS = ("bench_seed", "pretrain_env", "pretrain_steps", "pretrain_hyper", "trim")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Cell:
    """One cell: ``kind`` (``KINDS``), the controller ``algo`` with its ``hyper`` (a preset under
    "config" and overrides) and ``settings`` (every field they resolve to; "adapt": [pretraining's,
    adapting's]), the environment's name ``env`` and options ``env_config``, the training ``seed``,
    the ``checkpoints`` (env steps), the test ``episodes`` and their ``eval_seed``; protocol (b):
    the unseen bench's ``bench_seed``; "adapt": the pretraining's ``pretrain_env``,
    ``pretrain_steps`` and ``pretrain_hyper``, the ``trim`` around the adapted policies (a
    ``TrimConfig`` hyper dict). The fields in their stored order."""

    kind: str
    algo: str
    hyper: dict
    env: str
    env_config: dict
    bench_seed: int | None = None
    seed: int
    checkpoints: tuple
    episodes: int
    eval_seed: int
    pretrain_env: dict | None = None
    pretrain_steps: int | None = None
    pretrain_hyper: dict | None = None
    trim: dict | None = None
    settings: dict | list

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {list(KINDS)}, got {self.kind!r}")
        allowed = {"adapt": set(ADAPT_FIELDS), "bench reference": {"bench_seed"}}.get(
            self.kind, set()
        )
        given = {f for f in ADAPT_FIELDS if getattr(self, f) is not None}
        if given != allowed:
            raise ValueError(
                f"a {self.kind!r} cell sets {sorted(allowed)} of {list(ADAPT_FIELDS)}, got "
                f"{sorted(given)}"
            )
        object.__setattr__(self, "checkpoints", tuple(self.checkpoints))

    def to_dict(self) -> dict:
        """The stored form: field -> value in the fields' order, ``checkpoints`` a list, without the
        protocol (b) fields a cell of another kind leaves unset."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name not in ADAPT_FIELDS or v is not None:
                out[f.name] = list(v) if f.name == "checkpoints" else v
        return out

    @classmethod
    def from_dict(cls, stored: dict) -> Cell:
        """The cell of a stored form (``to_dict``; TypeError naming a key that is not a field)."""
        return cls(**stored)
