"""Learning from outcomes: what an action did, measured, and remembered per context.

With ``runtime.learning.enabled`` (off by default), every executed action opens an
*outcome*: its context is the module it was keyed to (the estimated source the loop
acted on) and the configuration it was taken in. When it has settled
(``settle_s`` after it), the Monitor's J_obs over the second half of that window is
compared with J_obs over the same length just before the action:

    realized Δ = mean J(before) − mean J(after)      (positive = better, J's unit)

The outcome *fails* when realized Δ < −(tolerance + se), se the standard error of the
difference of the two means, or when the configuration was rolled back to the one it
left before the window ended. An outcome that cannot be measured (no finite J in a
window) is logged as ``unmeasured`` and changes nothing.

Per context, :class:`OutcomeTable` keeps trials, successes, the mean realized Δ and the
last outcome. The planner asks :meth:`Learning.review` for each action it evaluates:

- an action whose last outcome in this context failed is ``held back`` for ``hold_s``
  after the failure (a table loaded from a previous run: ``hold_s`` from the run's
  first cycle);
- otherwise its estimated Δ is scaled by the learned factor
  ``max(min_factor, (successes + 1)/(trials + 1))`` (1 while untried, so an empty
  table changes nothing).

The table is the loop's Knowledge (``knowledge.learned``); ``to_dict``/``save`` and
``load_table`` keep it across runs (``archself simulate --knowledge FILE --save-knowledge
FILE``); the trace of a run holds it too (``meta.knowledge.learned``), and
``--knowledge TRACE`` reads it from there. docs/learning.md says what is learned, when it
is trusted and how it fails.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from archself.errors import ArchselfError
from archself.model.architecture import Learning as LearningSettings

__all__ = ["Learning", "OutcomeTable", "learning_of", "load_table"]

FORMAT = "archself-knowledge/1"


@dataclass
class Entry:
    """What one action did in one context (module, configuration)."""

    action: str
    module: str
    configuration: str
    trials: int = 0
    successes: int = 0
    realized: float = 0.0  # mean realized Δ over the trials (J's unit)
    last: str = ""  # "success" or "failure"

    def factor(self, floor: float) -> float:
        """The learned factor on the estimated Δ: (successes + 1)/(trials + 1), floored."""
        return max(floor, (self.successes + 1) / (self.trials + 1))


Key = tuple[str, str, str]  # (action, module, configuration)


@dataclass
class OutcomeTable:
    """The learned record of every action per context; JSON with ``to_dict``."""

    entries: dict[Key, Entry] = field(default_factory=dict)

    def get(self, action: str, module: str, configuration: str) -> Entry | None:
        return self.entries.get((action, module, configuration))

    def add(self, action: str, module: str, configuration: str, realized: float,
            ok: bool) -> Entry:
        """Count one measured outcome."""
        key = (action, module, configuration)
        e = self.entries.setdefault(key, Entry(action, module, configuration))
        e.realized = (e.realized * e.trials + realized) / (e.trials + 1)
        e.trials += 1
        e.successes += int(ok)
        e.last = "success" if ok else "failure"
        return e

    def to_dict(self) -> dict[str, Any]:
        rows = [asdict(e) for _, e in sorted(self.entries.items())]
        return {"format": FORMAT, "entries": rows}

    @classmethod
    def from_dict(cls, data: Any, where: str = "knowledge") -> OutcomeTable:
        """The table of :meth:`to_dict`; a bad document is one located error."""
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise ArchselfError(f"{where}: expected a knowledge table (format: {FORMAT})")
        table = cls()
        for i, row in enumerate(data.get("entries") or []):
            try:
                e = Entry(**row)
                ok = (isinstance(e.trials, int) and isinstance(e.successes, int)
                      and 0 <= e.successes <= e.trials and math.isfinite(float(e.realized))
                      and e.last in ("", "success", "failure"))
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise ArchselfError(
                    f"{where}: entries.{i}: expected {{action, module, configuration, trials, "
                    f"successes ≤ trials, realized (finite), last: success|failure}}"
                )
            table.entries[(e.action, e.module, e.configuration)] = e
        return table

    def save(self, path: str | Path) -> None:
        """Write the table as JSON (atomic)."""
        import json

        from archself.io.files import write_text

        write_text(Path(path), json.dumps(self.to_dict(), indent=1) + "\n")


def load_table(path: str | Path) -> OutcomeTable:
    """Read a table: a file :meth:`OutcomeTable.save` wrote, or a trace (one-line errors).

    A trace (Parquet, or JSON with ``meta`` and ``series``) holds the table of its run
    in ``meta.knowledge.learned`` when ``runtime.learning`` was on.
    """
    from archself.io.files import read_text
    from archself.io.jsondata import loads

    try:
        with open(path, "rb") as fh:
            parquet = fh.read(4) == b"PAR1"
    except OSError:
        parquet = False  # read_text says what is wrong with the path
    data: Any = None
    if not parquet:
        text = read_text(Path(path))
        try:
            data = loads(text)
        except ValueError as exc:  # json.JSONDecodeError and JsonLimitError
            line = getattr(exc, "lineno", None)
            at = f":{line}:{exc.colno}" if line is not None else ""  # type: ignore[attr-defined]
            raise ArchselfError(f"{path}{at}: not a knowledge table: {exc}") from None
    if parquet or (isinstance(data, dict) and "meta" in data and "series" in data):
        return _table_of_trace(path)
    return OutcomeTable.from_dict(data, str(path))


def _table_of_trace(path: str | Path) -> OutcomeTable:
    """The learned table in a trace's ``meta.knowledge.learned`` (the trace checked)."""
    from archself.io.trace import read_trace_parts

    meta = read_trace_parts(path).meta
    known = meta.get("knowledge")
    table = known.get("learned") if isinstance(known, dict) else None
    if table is None:
        raise ArchselfError(f"{path}: meta.knowledge.learned: expected the learned table of "
                            f"the run (a trace of a run with runtime.learning on)")
    return OutcomeTable.from_dict(table, f"{path}: meta.knowledge.learned")


@dataclass
class _Pending:
    action: str
    module: str
    origin: str  # configuration the action was taken in
    target: str  # configuration it led to
    t0: float
    before: list[float]
    estimate: float | None


class Learning:
    """The loop's outcome measurement and the planner's review (``runtime.learning``).

    Parameters
    ----------
    settings : archself.model.architecture.Learning
        ``runtime.learning`` of the file.
    table : OutcomeTable, optional
        What earlier runs learned (default: empty).

    Attributes
    ----------
    table : OutcomeTable
    events : list of dict
        One per closed outcome: ``{t_s, action, module, configuration, j_before,
        j_after, realized, estimate, outcome, detail}``.
    """

    def __init__(self, settings: LearningSettings, table: OutcomeTable | None = None) -> None:
        self.s = settings
        self.table = table if table is not None else OutcomeTable()
        self.events: list[dict[str, Any]] = []
        self._held: dict[Key, float] = {}
        self._loaded = {k for k, e in self.table.entries.items() if e.last == "failure"}
        self._history: deque[tuple[float, float]] = deque()
        self._pending: list[_Pending] = []

    # ------------------------------------------------------------------ monitor
    def observe(self, t: float, j_obs: float, configuration: str) -> list[dict[str, Any]]:
        """Note this cycle's J; close the outcomes that settled (their events)."""
        if self._loaded:  # a failure from an earlier run: held hold_s from this run's start
            for key in self._loaded:
                self._held[key] = t + self.s.hold_s
            self._loaded = set()
        hist = self._history
        hist.append((t, j_obs))
        keep = 1.5 * self.s.settle_s + 1e-9
        while hist and hist[0][0] < t - keep:
            hist.popleft()
        closed = []
        for p in list(self._pending):
            if t >= p.t0 + self.s.settle_s - 1e-9:
                closed.append(self._close(p, t, ""))
            elif configuration != p.target:
                why = "rolled back" if configuration == p.origin else "interrupted"
                closed.append(self._close(p, t, why))
        return closed

    def cycle(self, record: Any) -> None:
        """:meth:`observe` one cycle's DecisionRecord; closed outcomes go to its note."""
        events = self.observe(record.t, record.j_obs, record.configuration)
        notes = [record.note] if record.note else []
        for e in events:
            if e["realized"] is None:
                notes.append(f"outcome of {e['action']}: unmeasured ({e['detail']})")
            else:
                notes.append(f"outcome of {e['action']}: {e['outcome']} ({e['detail']}: "
                             f"J {e['j_before']:.3g} → {e['j_after']:.3g}, "
                             f"realized Δ {e['realized']:.3g})")
        record.note = "; ".join(notes)

    def started(self, action: Any, origin: str, target: str, t: float,
                estimate: float | None) -> None:
        """``action`` was executed at ``t`` in ``origin``, leading to ``target``: it opens."""
        half = self.s.settle_s / 2
        before = [j for tj, j in self._history if t - half - 1e-9 <= tj <= t]
        self._pending.append(
            _Pending(action.id, action.module, origin, target, t, before, estimate)
        )

    def _close(self, p: _Pending, t: float, why: str) -> dict[str, Any]:
        self._pending.remove(p)
        start = p.t0 + (t - p.t0) / 2 if why else p.t0 + self.s.settle_s / 2
        after = [j for tj, j in self._history if start - 1e-9 <= tj <= t and tj > p.t0]
        b = np.asarray([x for x in p.before if math.isfinite(x)])
        a = np.asarray([x for x in after if math.isfinite(x)])
        event: dict[str, Any] = {
            "t_s": t, "action": p.action, "module": p.module, "configuration": p.origin,
            "estimate": p.estimate, "j_before": None, "j_after": None, "realized": None,
        }
        if b.size == 0 or a.size == 0:
            event.update(outcome="unmeasured", detail="no finite J in a window")
            self.events.append(event)
            return event
        realized = float(b.mean() - a.mean())
        se = math.sqrt(b.var() / b.size + a.var() / a.size)
        failed = why == "rolled back" or realized < -(self.s.tolerance + se)
        self.table.add(p.action, p.module, p.origin, realized, not failed)
        if failed:
            self._held[(p.action, p.module, p.origin)] = t + self.s.hold_s
        detail = why or ("J worse" if failed else "J not worse")
        event.update(j_before=float(b.mean()), j_after=float(a.mean()), realized=realized,
                     outcome="failure" if failed else "success", detail=detail)
        self.events.append(event)
        return event

    # ------------------------------------------------------------------ plan
    def review(
        self, action: str, module: str, configuration: str, t: float
    ) -> tuple[float, str, dict[str, Any] | None]:
        """(factor on Δ, why it is held back or "", the context's record for the log)."""
        e = self.table.get(action, module, configuration)
        if e is None:
            return 1.0, "", None
        factor = e.factor(self.s.min_factor)
        until = self._held.get((action, module, configuration), -math.inf)
        info = {"trials": e.trials, "successes": e.successes, "realized": e.realized,
                "factor": factor, "last": e.last}
        if e.last == "failure" and t < until:
            info["held_until"] = until
            return factor, (f"failed here {e.trials - e.successes} of {e.trials} time(s) "
                            f"(realized Δ {e.realized:.3g}); held until t = {until:g} s"), info
        return factor, "", info


def learning_of(arch: Any, learned: OutcomeTable | str | Path | None = None) -> Learning | None:
    """The loop's :class:`Learning` of ``arch``: None when ``runtime.learning`` is off.

    A table (or the path of one) given switches learning on with the file's settings.
    """
    if learned is None and not arch.runtime.learning.enabled:
        return None
    if isinstance(learned, (str, Path)):
        learned = load_table(learned)
    return Learning(arch.runtime.learning, learned)
