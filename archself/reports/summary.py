"""What an architecture file holds, at a glance (``archself info``).

Examples
--------
>>> from archself.model.loader import load_architecture
>>> from archself.resources import data_dir
>>> arch = load_architecture(data_dir("architectures") / "diffdrive.yaml").arch
>>> s = summarize(arch)
>>> s["counts"]
{'modules': 15, 'edges': 39, 'configurations': 4, 'actions': 7, 'scenarios': 8}
>>> print(summary_text(s).splitlines()[0][:58])
diffdrive: 15 modules (6 physical, 6 functional, 3 model),
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from archself.model.architecture import Architecture

__all__ = ["summarize", "summary_text"]


def summarize(arch: Architecture) -> dict[str, Any]:
    """A JSON-ready summary: counts, modules, configurations, actions, scenarios, runtime."""
    rt = arch.runtime
    chosen = next(k for k in ("threshold", "top_k", "hysteresis") if getattr(rt, k) is not None)
    value = rt.hysteresis.model_dump() if rt.hysteresis else getattr(rt, chosen)
    initial = arch.initial_configuration()
    return {
        "name": arch.name,
        "description": arch.description,
        "counts": {"modules": len(arch.modules), "edges": len(arch.edges),
                   "configurations": len(arch.configurations), "actions": len(arch.actions),
                   "scenarios": len(arch.scenarios)},
        "modules": [{"name": n, "kind": m.kind, "type": m.type,
                     "residual": m.residual.signal if m.residual else None}
                    for n, m in arch.modules.items()],
        "configurations": [{"name": n, "initial": n == initial, "modules": list(c.modules),
                            "description": c.description}
                           for n, c in arch.configurations.items()],
        "actions": [{"id": a.id, "module": a.module, "kind": a.kind, "to": a.to,
                     "set": dict(a.set) if a.set else None, "cost": a.cost}
                    for a in arch.actions],
        "scenarios": [{"name": n, "duration_s": s.duration_s,
                       "faults": [f"{f.kind} on {f.module} at {f.onset_s:g} s" for f in s.faults]}
                      for n, s in arch.scenarios.items()],
        # one shape whatever the selector: the two not chosen are null (io.jsondata.InfoDoc)
        "runtime": {"step_s": rt.step_s, "period_s": rt.period_s, "selector": chosen,
                    chosen: value, "warmup_steps": rt.warmup_steps,
                    "dwell_s": rt.dwell_s, "objective": rt.objective.model_dump()},
    }


def summary_text(s: dict[str, Any]) -> str:
    """The summary as a few aligned lines for a terminal."""
    c = s["counts"]
    kinds = Counter(m["kind"] for m in s["modules"])
    by_kind = ", ".join(f"{v} {k}" for k, v in kinds.items())
    lines = [f"{s['name']}: {c['modules']} modules ({by_kind}), {c['edges']} edges, "
             f"{c['configurations']} configurations, {c['actions']} actions, "
             f"{c['scenarios']} scenarios"]
    lines.append("configurations:")
    for conf in s["configurations"]:
        mark = " (initial)" if conf["initial"] else ""
        lines.append(f"  {conf['name']}{mark}: {', '.join(conf['modules'])}")
    if s["actions"]:
        lines.append("actions:")
        for a in s["actions"]:
            what = f"→ {a['to']}" if a["to"] else ", ".join(f"{k}={v}" for k, v in
                                                          (a["set"] or {}).items())
            lines.append(f"  {a['id']}: {a['kind']} on {a['module']} {what} (cost {a['cost']:g})")
    if s["scenarios"]:
        lines.append("scenarios:")
        for sc in s["scenarios"]:
            faults = "; ".join(sc["faults"]) or "no faults"
            lines.append(f"  {sc['name']} ({sc['duration_s']:g} s): {faults}")
    rt = s["runtime"]
    lines.append(f"runtime: {rt['selector']} {rt[rt['selector']]}, period {rt['period_s']:g} s, "
                 f"step {rt['step_s']:g} s, dwell {rt['dwell_s']:g} s")
    return "\n".join(lines)
