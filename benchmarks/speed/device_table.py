"""The side-by-side table of ``python -m benchmarks.speed.device --table``: runs' JSON as
markdown."""

from __future__ import annotations


def _scan_cell(section: dict, model: str, n: int) -> str:
    cfg = next(
        (c for c in section.get("configs", []) if c["model"] == model and c["stages"] == n), None
    )
    if cfg is None:
        return "not run"
    if cfg["best_steps_per_s"] is None:
        return f"none ({cfg['stopped']})"
    if cfg["stopped"] == "oom":
        end = f", out of memory at {cfg['oom_at_batch']:,}"
    elif cfg["stopped"] in ("end", "error"):
        end = "" if cfg["stopped"] == "end" else ", then an error"
    else:  # budget, deadline: the scan stopped for time
        end = f", stopped for time after {cfg['batches'][-1]:,}"
    return f"{cfg['best_steps_per_s']:,.0f} (batch {cfg['best_batch']:,}{end})"


def _train_cell(section: dict) -> str:
    if section.get("env_steps"):
        return (
            f"{section['env_steps']:,} steps in {section['wall_s_train']:.1f} s: "
            f"{section['steps_per_s']:,.0f}/s, {section['steps_per_s_excl_compile']:,.0f}/s "
            f"without {section['compile_s']:.0f} s compiling"
        )
    last = (section.get("progress") or [None])[-1]
    if last:
        return (
            f"{section['status']}: {last['step']:,} of {section['total_steps']:,} steps in "
            f"{last['elapsed_s']:.0f} s"
        )
    return f"{section.get('status', 'not run')}" + (
        f" ({section['error'][:60]})" if section.get("error") else ""
    )


def _as_list(value) -> list:
    """A JSON field that holds one value, or a list of them for a device measured in several
    calls."""
    return list(value) if isinstance(value, list) else [value]


def _listed(value) -> str:
    """The first of a field's values, as text."""
    return str(_as_list(value)[0])


def compare_table(docs: list) -> str:
    """A markdown table of device JSON files side by side (one column each)."""
    head = [
        f"{(d.get('device') or {}).get('kind', '?')} "
        f"({(d.get('device') or {}).get('platform', '?')})"
        for d in docs
    ]
    rows = [
        ("host, date", [f"{d.get('host')}, {_listed(d.get('date'))[:10]}" for d in docs]),
        ("JAX", [str(d.get("jax")) for d in docs]),
        ("command", [" then ".join(f"`{c}`" for c in _as_list(d.get("command"))) for d in docs]),
    ]
    sec = [d.get("sections", {}) for d in docs]
    for name, label in (("step_batch", "step_batch"), ("rollout", "ops_jax.rollout")):
        planned = [
            c
            for s in sec
            for c in s.get(name, {}).get("planned") or s.get(name, {}).get("configs", [])
        ]
        pairs = sorted(
            {(c["model"], c["stages"]) for c in planned}, key=lambda mn: (mn[0] != "phasor", mn[1])
        )
        for model, n in pairs:
            rows.append(
                (
                    f"{label}, {model} N = {n}: env-steps/s",
                    [_scan_cell(s.get(name, {}), model, n) for s in sec],
                )
            )
    for algo in ("droq", "td3", "sac"):
        rows.append((f"{algo} training", [_train_cell(s.get(algo, {})) for s in sec]))
    rows.append(
        (
            "quick sweep, table1: wall s",
            [
                f"{s['sweep']['wall_s_sweep']:.0f} ({s['sweep']['status']})"
                if s.get("sweep", {}).get("wall_s_sweep")
                else _train_cell(s.get("sweep", {}))
                for s in sec
            ],
        )
    )
    rows.append(("whole command: wall s", [f"{d.get('wall_s', 0):.0f}" for d in docs]))
    lines = ["| | " + " | ".join(head) + " |", "|---|" + "---|" * len(docs)]
    lines += [f"| {label} | " + " | ".join(cells) + " |" for label, cells in rows]
    return "\n".join(lines)


def best_phasor_n5(sections: dict):
    """The fastest phasor N = 5 rate of the step_batch section (env-steps/s), None if not
    measured."""
    s = sections.get("step_batch") or {}
    rates = [
        r["steps_per_s"] for r in s.get("rows", []) if r["model"] == "phasor" and r["stages"] == 5
    ]
    return max(rates) if rates else None
