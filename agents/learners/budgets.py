"""How much of a training budget trains: the env steps a learner runs before its first gradient step
(the off-policy warm-up, SAC's replay prefill), the least budget that takes one, and the share of a
budget left to training. ``check`` refuses a budget that trains nothing (naming the least one that
does) and words a warning for one whose warm-up takes most of it; ``agents.train`` and
``python -m agents`` ask it before any work starts."""

from __future__ import annotations


SMALL_SHARE = 0.5  # a budget training less than this share of its env steps is warned about


class BudgetWarning(UserWarning):
    """A training budget that a learner's warm-up takes most of (``check``)."""


def ceil_to(n: int, unit: int) -> int:
    """``n`` rounded up to a whole number of ``unit``."""
    return -(-n // unit) * unit


def brax_units(num_evals: int, units: int) -> int:
    """Training steps of ``units`` that brax's trainers run: whole epochs, one per evaluation but
    the first (``agents.learners.brax.training``)."""
    epochs = min(max(num_evals - 1, 1), units)
    return epochs * (units // epochs) if epochs else 0


def layout(config) -> tuple[int, int, str] | None:
    """(env steps before the first gradient step, env steps per training step, what the first ones
    are) of a learner's ``config`` (its ``budget_layout``); None for a controller's."""
    return config.budget_layout()


def trained_steps(config, total: int) -> int:
    """Env steps of a ``total``-step budget that train (the rest: the warm-up, and what whole
    training steps and evaluation chunks leave out)."""
    warm, unit, _ = layout(config)
    return config.trained_units(max(0, (total - warm) // unit)) * unit


def least_steps(config) -> int:
    """The least budget (env steps) that takes one gradient step."""
    warm, unit, _ = layout(config)
    return warm + unit


def useful_steps(config) -> int:
    """The least budget (env steps, whole training steps past the warm-up) of which at least
    ``SMALL_SHARE`` trains."""
    warm, unit, _ = layout(config)
    total = warm + max(unit, ceil_to(int(warm * SMALL_SHARE / (1 - SMALL_SHARE)), unit))
    while trained_steps(config, total) < SMALL_SHARE * total:
        total += unit
    return total


def check(config, total: int, option: str = "total_steps", sep: str = "=") -> str | None:
    """ValueError when a ``total``-step budget of ``config`` takes no gradient step (the least that
    does and the least that trains half of it named as ``{option}{sep}N``); a warning line when
    under ``SMALL_SHARE`` of it trains; else None."""
    if layout(config) is None:
        return None
    warm, unit, why = layout(config)
    trained = trained_steps(config, total)
    said = f"{option}{sep}{total}"
    if trained == 0:
        first = f"its first {warm:,} env steps are {why}, and " if warm else ""
        raise ValueError(
            f"{said} takes no gradient step: {first}one training step takes {unit:,} env steps; "
            f"try {option}{sep}{useful_steps(config)} ({option}{sep}{least_steps(config)} takes "
            "one)"
        )
    if trained < SMALL_SHARE * total:
        before = f"{warm:,} are {why}" if warm else ""
        rest = total - warm - trained
        left = f"{rest:,} are not run (whole training steps of {unit:,})" if rest else ""
        return (
            f"{said} trains {trained:,} env steps ({trained / total:.0%}): "
            f"{'; '.join(x for x in (before, left) if x)}; {option}{sep}{useful_steps(config)} "
            f"trains half, the {config.config} preset trains "
            f"{type(config).preset(config.config).total_steps:,}"
        )
    return None


def config_of(algo: str, hyper: dict):
    """The config ``hyper`` (a preset name under "config", overrides of its fields, other keywords
    ignored) resolves to for ``algo``; None when it does not resolve (the trainer then says why)."""
    from agents import registry

    config_type = registry.get(algo).config
    fields = {k: v for k, v in hyper.items() if k in config_type.names()}
    try:
        return config_type.make(hyper.get("config"), **fields)
    except (TypeError, ValueError):
        return None


def warn(algo: str, hyper: dict, total_steps: int | None) -> int | None:
    """Warn (``BudgetWarning``) when ``total_steps`` (None: the config's) of ``algo`` with ``hyper``
    trains nothing or under ``SMALL_SHARE`` of it; returns that budget (None for a controller)."""
    import warnings

    config = config_of(algo, hyper)
    total = total_steps if total_steps is not None else getattr(config, "total_steps", None)
    if config is None or total is None:
        return total
    try:
        line = check(config, total)
    except ValueError as exc:  # the trainer runs it, or refuses it itself (the warm-up's own check)
        line = str(exc)
    if line:
        warnings.warn(line, BudgetWarning, stacklevel=3)
    return total
