"""The decision log for a person: :func:`explain` (text) and :func:`explain_data` (JSON).

:func:`explain` answers "why did it switch?": every cycle that switched, rejected an
action or saw a candidate, with J, the largest z (or ê) and each evaluation's Δ,
score and reason; quiet cycles are folded. :func:`explain_data` is the same as
segments of plain data. Both read :class:`~archself.runtime.knowledge.DecisionRecord`
objects or their JSON form (a trace's log); importing this module costs
neither scipy nor networkx.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import is_dataclass
from typing import Any

from archself.errors import TraceError
from archself.io.jsondata import (
    DecisionLog,
    DecisionRecordDoc,
    document,
    json_kind,
    jsonable,
    problem,
)

__all__ = ["explain", "explain_data"]


def _fmt(x: Any, spec: str = ".3g") -> str:
    """A number for the text (``n/a`` for None)."""
    if x is None:
        return "n/a"
    try:
        return format(float(x), spec)
    except (TypeError, ValueError):
        return str(x)


def _as_dict(d: Any) -> dict[str, Any]:
    """A record as plain data."""

    return dict(d) if isinstance(d, Mapping) else dict(document(DecisionRecordDoc, d))


def decision_log_problem(decisions: Any) -> str | None:
    """What makes ``decisions`` not a decision log (``decisions[3].z: expected …``), or None.

    A log is a list of records (:class:`~archself.runtime.knowledge.DecisionRecord` or
    their JSON form, as a trace stores them), checked by the model
    :data:`archself.io.jsondata.DecisionLog`: a field may be missing, but one that is
    there has its type.
    """

    if isinstance(decisions, str | bytes | Mapping) or not isinstance(decisions, Iterable):
        hint = (" (a run's are its .decisions; a trace's: read_trace(path).decisions)"
                if isinstance(decisions, str) or hasattr(decisions, "decisions") else "")
        return f"decisions: expected a list of decision records, got {json_kind(decisions)}{hint}"
    # a DecisionRecord object is one by construction: {} keeps the indices
    return problem(DecisionLog, [{} if is_dataclass(d) else d for d in decisions],
                   "decisions")


def _records(decisions: Any) -> list[dict[str, Any]]:
    """The records of a log as dicts; a one-line TraceError for anything else."""
    if isinstance(decisions, Iterator):
        decisions = list(decisions)
    problem = decision_log_problem(decisions)
    if problem is not None:
        raise TraceError(f"error: not a decision log: {problem}")
    return [_as_dict(d) for d in decisions]


def _signature(d: dict[str, Any]) -> tuple:
    """What makes two quiet cycles "the same" for summarizing."""
    evals = tuple((e.get("action"), e.get("rejected")) for e in d.get("evaluations") or [])
    evals = tuple(sorted(evals, key=str))
    return (d.get("phase"), d.get("configuration"), frozenset(d.get("candidates") or []), evals)


def _top_z(d: dict[str, Any], k: int = 3, key: str = "z") -> str:
    z = {n: v for n, v in (d.get(key) or {}).items() if v}
    top = sorted(z.items(), key=lambda kv: -abs(kv[1]))[:k]
    return ", ".join(f"{n} {_fmt(v, '.2f')}" for n, v in top) or "none"


def _largest(values: Mapping[str, Any]) -> str | None:
    """The module with the largest non-zero |value| (ties: first in order), or None."""
    best, top = None, 0.0
    for n, v in values.items():
        if v is not None and abs(v) > top:
            best, top = n, abs(v)
    return best


def _describe_eval(e: dict[str, Any], weight: str = "z") -> str:
    target = f" → {e['to']}" if e.get("to") else ""
    head = f"{e.get('action')} ({e.get('kind')} on {e.get('module')}{target})"
    parts = []
    if e.get("delta") is not None:
        parts.append(f"Δ={_fmt(e['delta'])}")
    if e.get("spread") is not None:  # runtime.risk
        parts.append(f"{e.get('draws')} draw(s): mean {_fmt(e.get('mean'))}, spread "
                     f"{_fmt(e['spread'])}, ranked by {e.get('rule')}")
    lr = e.get("learned")
    if isinstance(lr, Mapping):  # runtime.learning: this context's record
        parts.append(f"learned here: {lr.get('successes')} of {lr.get('trials')} succeeded, "
                     f"realized Δ {_fmt(lr.get('realized'))}, factor {_fmt(lr.get('factor'))}")
    if e.get("score") is not None:
        plus = " + μ·(U − U_target)" if "@" in str(e.get("action")) and e.get("utility") else ""
        parts.append(f"score={_fmt(e['score'])} = {weight}·Δ − λ·cost{plus}")
    u = e.get("utility")
    if isinstance(u, Mapping) and isinstance(u.get("attributes"), Mapping):
        attrs = ", ".join(
            f"{q} {_fmt(a.get('value'))} → {_fmt(a.get('utility'), '.2f')}"
            for q, a in u["attributes"].items() if isinstance(a, Mapping)
        )
        parts.append(f"U={_fmt(u.get('U'), '.3f')} ({attrs})")
    st = e.get("stability")
    if st:
        parts.append(("stable: " if st.get("ok") else "UNSTABLE: ") + str(st.get("reason") or ""))
    if e.get("rejected"):
        why = f"{e['rejected']}" + (f": {e['detail']}" if e.get("detail") else "")
        parts.append(f"rejected ({why})")
    return head + ("  " + "; ".join(parts) if parts else "")


def _cycle_block(d: dict[str, Any]) -> list[str]:
    lines = [
        f"t = {_fmt(d.get('t'), '.1f')} s  [{d.get('configuration')}]  "
        f"J_obs = {_fmt(d.get('j_obs'))} "
        f"(acceptable {_fmt(d.get('j_ref'))}, r = {_fmt(d.get('r_global'), '+.3g')})",
    ]
    if d.get("phase") == "warmup":
        lines.append("  warm-up: adaptation suppressed")
    cands = d.get("candidates") or []
    z = d.get("z") or {}
    r = d.get("r") or {}
    src = d.get("source")
    if cands:
        shown = ", ".join(
            f"{c} (z = {_fmt(z.get(c), '.2f')}"
            + (f", source ê = {_fmt(src.get(c), '.2f')}" if src is not None else "")
            + (", no residual of its own: estimated through W" if _hidden(c, r, src)
               else f", own r = {_fmt(r.get(c), '.2f')}")
            + ")"
            for c in cands
        )
        lines.append(f"  candidates ({d.get('selector', '')}): {shown}")
    else:
        line = f"  no candidate; largest z: {_top_z(d)}"
        if src is not None:
            line += f"; largest source ê: {_top_z(d, key='source')}"
        lines.append(line)
    top_z, top_e = _largest(z), _largest(src or {})
    same = any(top_z in g and top_e in g for g in d.get("equivalent") or [])
    if src is not None and cands and top_z != top_e and not same:
        lines.append(
            f"  z and source disagree: largest z {_top_z(d, 1)}, "
            f"largest source ê {_top_z(d, 1, key='source')}"
        )
    for group in d.get("equivalent") or []:
        lines.append(
            "  equivalent sources (the residuals cannot tell them apart, all kept as "
            "candidates): " + ", ".join(group)
        )
    if d.get("compensated"):
        lines.append(
            "  compensated (own z only, not propagated through W): "
            + ", ".join(d["compensated"])
        )
    # the planner's weight (a log without the key is the paper's z)
    weight = "ê" if d.get("localization") in ("source", "fit") else "z"
    ch = d.get("chosen") or {}
    chosen_id = ch.get("action")
    for e in d.get("evaluations") or []:
        mark = "  ← chosen" if chosen_id is not None and chosen_id == e.get("action") else ""
        lines.append("    - " + _describe_eval(e, weight) + mark)
    if ch.get("kind") == "parameter_update":
        lines.append(f"  ⇒ updated {ch.get('module')} {ch.get('set')} by {ch.get('action')}")
    elif ch:
        lines.append(f"  ⇒ switched {ch.get('from')} → {ch.get('to')} by {ch.get('action')}")
    if ch and src is not None and weight == "ê":
        lines.append("  " + _why_target(d, ch))
    if d.get("note"):
        lines.append(f"  note: {d['note']}")
    return lines


def _hidden(module: str, r: dict[str, Any], src: dict[str, Any] | None) -> bool:
    """A module with a source estimate but no residual of its own (hidden)."""
    return src is not None and not r.get(module) and bool(src.get(module))


def _why_target(d: dict[str, Any], ch: dict[str, Any]) -> str:
    """Why the chosen action's module: its estimate, its class, the largest estimate."""
    src, r = d.get("source") or {}, d.get("r") or {}
    m = str(ch.get("module"))
    text = f"why {m}: source ê = {_fmt(src.get(m), '.2f')}"
    if _hidden(m, r, src):
        text += " (no residual of its own: estimated from its echoes through W)"
    group = next((g for g in d.get("equivalent") or [] if m in g), None)
    if group:
        others = ", ".join(x for x in group if x != m)
        text += f"; it explains the residuals as well as {others}: the best-scoring action there"
    top = _largest(src)
    if top is not None and top != m and (group is None or top not in group):
        text += (f"; the largest estimate is at {top} ({_fmt(src.get(top), '.2f')}), "
                 "whose actions scored lower or were not admissible")
    return text


def explain(decisions: Iterable[Any]) -> str:
    """Render a decision log for a person asking "why did it switch?".

    Cycles where an action was chosen, or where the candidate set or the outcome
    of the evaluations changed, are shown in full (J, candidates with z and r_i,
    every action with Δ, stability verdict, score or rejection reason). Runs of
    cycles that repeat the previous situation are summarized in one line.

    Parameters
    ----------
    decisions : iterable of DecisionRecord or dict
        The log (``MapeK.decisions``, or the dicts saved with a trace).

    Returns
    -------
    str
        Plain text, one block per notable cycle.
    """
    recs = _records(decisions)
    if not recs:
        return "No MAPE-K decisions were logged."
    chosen = [d for d in recs if d.get("chosen")]
    switches = [d for d in chosen if d["chosen"].get("kind") != "parameter_update"]
    lines = [
        f"MAPE-K decision log: {len(recs)} cycles from t = {_fmt(recs[0].get('t'), '.1f')} s "
        f"to {_fmt(recs[-1].get('t'), '.1f')} s; {len(switches)} architectural change(s), "
        f"{len(chosen) - len(switches)} parameter update(s).",
    ]
    for d in switches:
        ch = d["chosen"]
        lines.append(
            f"  switch at t = {_fmt(d.get('t'), '.1f')} s: {ch.get('from')} → {ch.get('to')} "
            f"({ch.get('action')}, module {ch.get('module')}, z = {_fmt(ch.get('z'), '.2f')}, "
            + (f"source ê = {_fmt(ch.get('source'), '.2f')}, " if "source" in ch else "")
            + f"score {_fmt(ch.get('score'))})"
        )
    lines.append("")
    for kind, seg in _segments(recs):
        if kind == "cycle":
            lines.extend(_cycle_block(seg[0]))
            continue
        a, b = seg[0], seg[-1]
        what = "warm-up" if a.get("phase") == "warmup" else "same situation"
        lines.append(
            f"t = {_fmt(a.get('t'), '.1f')}–{_fmt(b.get('t'), '.1f')} s: {len(seg)} more cycle(s), "
            f"{what} [{a.get('configuration')}], candidates {a.get('candidates') or 'none'}, "
            f"max |z| {_fmt(_peak(seg), '.2f')}"
            + (f", max ê {_fmt(_peak(seg, 'source'), '.2f')}" if "source" in a else "")
        )
    return "\n".join(lines)


def _peak(run: list[dict[str, Any]], key: str = "z") -> float:
    """Largest |z_i| (or of another per-module quantity) over a run of cycles."""
    return max(
        (abs(v) for d in run for v in (d.get(key) or {}).values() if v is not None), default=0.0
    )


def _segments(recs: list[dict[str, Any]]) -> Iterator[tuple[str, list[dict[str, Any]]]]:
    """The log as ``("cycle", [d])`` for notable cycles and ``("run", [d, ...])`` for repeats.

    A cycle is notable when an action was chosen, it carries a note, or its situation
    (phase, configuration, candidates, evaluation outcomes) differs from the cycle before.
    """
    prev_sig: tuple | None = None
    run: list[dict[str, Any]] = []
    for d in recs:
        sig = _signature(d)
        if bool(d.get("chosen")) or d.get("note") or sig != prev_sig:
            if run:
                yield "run", run
                run = []
            yield "cycle", [d]
        else:
            run.append(d)
        prev_sig = sig
    if run:
        yield "run", run


def explain_data(decisions: Iterable[Any]) -> dict[str, Any]:
    """What :func:`explain` shows, as JSON-ready data (``archself explain --json``).

    Returns
    -------
    dict
        ``cycles`` (number logged), ``switches`` and ``updates`` (``{t, action, module,
        from, to | set, z, score}`` and ``source``, the source estimate ê, when the log
        has it; ``equivalent``: the modules the residuals cannot tell apart from the
        chosen action's module, when there are), and ``segments``: the notable cycles
        in full (``{"kind": "cycle", "record": <decision record>}``) and runs of repeated
        cycles summarized
        (``{"kind": "repeat", "t_from", "t_to", "cycles", "phase", "configuration",
        "candidates", "max_abs_z"}`` and ``max_source`` when the log has ê).
    """
    recs = _records(decisions)
    switches, updates = [], []
    for d in recs:
        ch = d.get("chosen")
        if not ch:
            continue
        item = {"t": d.get("t"), **{k: ch.get(k) for k in ("action", "module", "z", "score")}}
        if "source" in ch:
            item["source"] = ch["source"]
        group = next((g for g in d.get("equivalent") or [] if ch.get("module") in g), None)
        if group:
            item["equivalent"] = group
        if ch.get("kind") == "parameter_update":
            updates.append({**item, "set": ch.get("set")})
        else:
            switches.append({**item, "from": ch.get("from"), "to": ch.get("to")})
    segments: list[dict[str, Any]] = []
    for kind, seg in _segments(recs):
        if kind == "cycle":
            segments.append({"kind": "cycle", "record": seg[0]})
        else:
            a = seg[0]
            segments.append({
                "kind": "repeat",
                "t_from": a.get("t"),
                "t_to": seg[-1].get("t"),
                "cycles": len(seg),
                "phase": a.get("phase"),
                "configuration": a.get("configuration"),
                "candidates": list(a.get("candidates") or []),
                "max_abs_z": _peak(seg),
                **({"max_source": _peak(seg, "source")} if "source" in a else {}),
            })
    return jsonable(
        {"cycles": len(recs), "switches": switches, "updates": updates, "segments": segments}
    )
