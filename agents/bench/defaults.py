"""What a run on a bench chooses by itself, and what the runner's first line says of it.

On a bench whose mapping has no length readout for some line: the physics-informed controller runs
its ``frames`` configuration (``--set config=frames``: the detector's frames alone) and a learner
from scratch its ``bench`` preset (``--set config=bench``, where it has one: DroQ's correction to
the physics-informed fit's move). Where the mapping declares the optics' period (``period_wl``; the
simulated bench's 0.5 wl) and leaves ``safety.wrap_wl`` unset, the lines wrap at that period
(``agents.bench.mapping``), unless the controller reads the length readouts (which jump by the
period at a wrap) or the soft range is under three periods. An explicit ``--set config=...`` (for
the physics-informed controller also ``use_lengths`` or ``lengths_only``), ``--wrap WL`` (0: no
wrap) or ``safety.wrap_wl`` wins.
"""

from __future__ import annotations

from agents import api as base
from agents.bench.learning import off_policy_learner
from agents.bench.frozen import reads_lengths
from agents.bench.mapping import missing_lengths
from agents.cli import parse_set
from ops_jax import EnvSpec
from ops_jax.env import configure

# the physics-informed controller's settings that say whether it reads the length readouts
PHYSICS_LENGTH_KEYS = ("config", "use_lengths", "lengths_only")


def _why(missing: list, lines: int) -> str:
    if len(missing) == lines:
        return "the mapping has no length readouts (no lines[i].length)"
    return f"the mapping lacks {', '.join(missing)}"


def choose_settings(args, mapping: dict) -> tuple[list, str | None]:
    """(the ``--set`` items with the configuration chosen added, what was chosen and why, or
    None)."""
    items, missing = list(args.set or []), missing_lengths(mapping)
    hyper = parse_set(items)
    if not missing:
        return items, None
    why = _why(missing, len(mapping["lines"]))
    if args.controller == "physics" and not set(hyper) & set(PHYSICS_LENGTH_KEYS):
        return [*items, "config=frames"], (
            f"physics with its frames configuration (config=frames), as {why}"
        )
    if args.learn and not (args.from_ or args.resume) and "config" not in hyper:
        presets = off_policy_learner(args.learn).config_type.PRESETS
        if "bench" in presets:
            return [*items, "config=bench"], (
                f"{args.learn} with its bench preset (config=bench: a correction to the "
                f"physics-informed fit's move), as {why}"
            )
        preset = "budget" if "budget" in presets else "default"
        return items, f"{args.learn} with its {preset} preset ({args.learn} has no bench preset)"
    return items, None


def _observes_lengths(env_config: dict) -> bool:
    """Whether the observation of ``env_config`` (``ops_jax.make`` options) holds the length
    readouts."""
    return configure(**EnvSpec.from_options(env_config).as_dict())[0].observe_lengths


def run_reads_lengths(args, mapping: dict, items: list, checkpoint) -> bool:
    """Whether the run's controller or learner (``--set`` ``items``; ``checkpoint``: the one
    resumed) reads the length readouts, before it is built (as ``agents.bench.frozen.check_lengths``
    tells)."""
    env_options, stages = parse_set(args.env), len(mapping["lines"])
    if args.learn:
        start = checkpoint or args.from_
        lengths = not missing_lengths(mapping)
        env_config = base.load(start).env_spec.as_dict() if start else {"observe_lengths": lengths}
        return _observes_lengths({"stages": stages, **env_config, **env_options})
    if args.controller in ("spgd", "physics"):
        algo, hyper, env_config = args.controller, parse_set(items), {}
    else:
        saved = base.load(args.controller)
        algo, hyper, env_config = saved.algo, saved.config.to_hyper(), saved.env_spec.as_dict()
    observes = _observes_lengths({"stages": stages, **env_config, **env_options})
    return observes and reads_lengths(algo, hyper)


def choose_wrap(mapping: dict, reads: str | None) -> tuple[float | None, str | None]:
    """(the wrap (wl, None: none) of a checked ``mapping`` whose ``safety.wrap_wl`` has the
    ``--wrap`` in it, for a run whose controller ``reads`` the length readouts (its name; None: it
    does not); what was chosen and why, or None where it was given)."""
    given, period = mapping["safety"]["wrap_wl"], mapping["period_wl"]
    if given is not None:
        return (given or None), None
    if period is None:
        return None, None
    if reads:
        return None, (
            f"no wrap at the optics' period ({period:g} wl): {reads} reads the length readouts, "
            "which jump by the period at a wrap"
        )
    span = min(high - low for low, high in mapping["safety"]["soft_range_wl"])
    if period > span / 3:
        return None, f"no wrap: the soft range ({span:g} wl) is under three periods ({period:g} wl)"
    return period, (
        f"lines wrapped at the optics' period, {period:g} wl (the mapping's period_wl; --wrap 0: "
        "none)"
    )


def choose(args, mapping: dict, checkpoint=None) -> tuple[list, dict, str | None]:
    """(the ``--set`` items, the checked ``mapping`` with its wrap resolved, the line that says what
    was chosen and why, or None where nothing was)."""
    items, setting = choose_settings(args, mapping)
    name = f"--learn {args.learn}" if args.learn else args.controller
    reads = run_reads_lengths(args, mapping, items, checkpoint)
    wrap, wrapping = choose_wrap(mapping, name if reads else None)
    mapping = {**mapping, "safety": {**mapping["safety"], "wrap_wl": wrap}}
    chosen = [note for note in (setting, wrapping) if note]
    return items, mapping, "; ".join(chosen) or None
