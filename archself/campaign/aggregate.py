"""The numbers of a campaign report, from its results table (no plotting, no HTML here).

Per scenario, from the rows of :mod:`archself.campaign.results`:

- **correct switches** — an adaptive run in a scenario *with* faults is correct
  when its final configuration is the one the user expects for that scenario
  (``--expect imu_drift=a2``); without an expectation, when it ends in a
  configuration other than its start *and* its RMS error is below that of the
  fixed run with the same seed (the paired baseline; without a fixed run, the
  changed configuration alone). In a scenario *without* faults an adaptive run is
  correct when it does not switch at all (or ends where ``--expect`` says);
- **detection delay** — first switch at or after the first fault onset minus the
  onset (runs that never switch after the onset are "missed");
- **false switches** — the share of adaptive runs on fault-free scenarios with
  at least one switch (and switches before the onset in faulted scenarios);
- **errors** fixed versus adaptive (max, final and RMS), paired by seed;
- **τ sweep** — when the campaign swept ``runtime.threshold`` (or
  ``runtime.hysteresis.on``): for each τ the false-switch rate on the fault-free
  scenarios against the median detection delay on the faulted ones.

Rates come with 95 % Wilson intervals. :mod:`archself.campaign.report` renders
these numbers (terminal, HTML, ``summary.json``); :mod:`archself.campaign.figures`
draws them.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from archself.campaign.sweep import CampaignError

__all__ = ["ERROR_METRICS", "CampaignSummary", "parse_expect", "summarize", "wilson"]

#: The error metrics the report compares, fixed against adaptive (unit: the rows' ``unit``).
ERROR_METRICS = ("max_error", "final_error", "rms_error")


# --------------------------------------------------------------------------- statistics
def wilson(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """95 % Wilson score interval of a rate k/n ((nan, nan) for n = 0).

    Examples
    --------
    >>> [round(x, 3) for x in wilson(0, 10)]
    [0.0, 0.278]
    """
    if n == 0:
        return (math.nan, math.nan)
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, mid - half), min(1.0, mid + half))


def _quantiles(values: Sequence[float]) -> dict[str, float | None]:
    import numpy as np

    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if v.size == 0:
        return {"n": 0, "mean": None, "p10": None, "median": None, "p90": None, "max": None}
    q = np.quantile(v, [0.1, 0.5, 0.9])
    return {
        "n": int(v.size),
        "mean": float(v.mean()),
        "p10": float(q[0]),
        "median": float(q[1]),
        "p90": float(q[2]),
        "max": float(v.max()),
    }


def _rate(k: int, n: int) -> dict[str, Any]:
    lo, hi = wilson(k, n)
    return {
        "k": k,
        "n": n,
        "rate": (k / n) if n else None,
        "lo": None if math.isnan(lo) else lo,
        "hi": None if math.isnan(hi) else hi,
    }


def _share(rows: Sequence[Mapping[str, Any]], key: str) -> dict[str, Any]:
    """:func:`_rate` of the rows whose ``key`` is true."""
    return _rate(sum(1 for r in rows if r[key]), len(rows))


# --------------------------------------------------------------------------- summary
def parse_expect(items: Sequence[str]) -> dict[str, str]:
    """``["imu_drift=a2", ...]`` → ``{"imu_drift": "a2"}``.

    Raises
    ------
    CampaignError
        On an item without ``=``.
    """
    out: dict[str, str] = {}
    for item in items:
        sc, sep, conf = item.partition("=")
        if not sep or not sc.strip() or not conf.strip():
            raise CampaignError(f"--expect {item!r}: expected SCENARIO=CONFIGURATION")
        out[sc.strip()] = conf.strip()
    return out


@dataclass
class CampaignSummary:
    """The numbers of a campaign report (``summary.json``: its
    :class:`~archself.io.jsondata.CampaignReportDoc`)."""

    meta: dict[str, Any]
    runs: int
    failed: int
    scenarios: list[dict[str, Any]]
    tau: dict[str, Any] | None
    sweeps: list[dict[str, Any]]
    expect: dict[str, str]
    errors: list[str] = field(default_factory=list)
    unit: str | None = None  # of the error metrics (the results' ``unit`` column)


def _pair_key(row: Mapping[str, Any], sweeps: Sequence[str]) -> tuple[Any, ...]:
    return (row["scenario"], tuple(row[p] for p in sweeps), row["replicate"])


def _classify(rows: list[dict[str, Any]], sweeps: Sequence[str], expect: Mapping[str, str]) -> None:
    """Add ``faulted``, ``correct`` and ``false_any`` to every adaptive row (in place)."""
    fixed = {_pair_key(r, sweeps): r for r in rows if r["mode"] == "fixed"}
    for r in rows:
        if r["mode"] != "adaptive":
            continue
        faulted = r["first_fault_onset_s"] is not None
        r["faulted"] = faulted
        r["false_any"] = (r["false_switches"] or 0) > 0
        want = expect.get(r["scenario"])
        if want is not None:
            r["correct"] = r["final_configuration"] == want
        elif not faulted:
            r["correct"] = (r["n_switches"] or 0) == 0
        else:
            moved = r["final_configuration"] != r["start_configuration"]
            base = fixed.get(_pair_key(r, sweeps))
            better = True
            if base is not None and base.get("error") is None:
                better = _lt(r["rms_error"], base["rms_error"])
            r["correct"] = bool(moved and better)


def _lt(a: Any, b: Any) -> bool:
    if a is None or b is None or not math.isfinite(a):
        return False
    return not math.isfinite(b) or a < b


def _scenario_block(name: str, rows: list[dict[str, Any]], sweeps: Sequence[str]) -> dict[str, Any]:
    ada = [r for r in rows if r["mode"] == "adaptive"]
    fix = [r for r in rows if r["mode"] == "fixed"]
    faulted = any(r["first_fault_onset_s"] is not None for r in rows)
    block: dict[str, Any] = {
        "scenario": name,
        "faulted": faulted,
        "runs": {"fixed": len(fix), "adaptive": len(ada)},
        "correct": _share(ada, "correct"),
        "false_switch": _share(ada, "false_any"),
        "false_switches_per_run": (sum(r["false_switches"] or 0 for r in ada) / len(ada))
        if ada
        else None,
        "final_configurations": _counts(r["final_configuration"] for r in ada),
        "paths": _counts(r["configuration_path"] for r in ada),
    }
    # one shape for every scenario (``--json``, summary.json): null when fault-free
    block["detected"] = block["delay_s"] = None
    if faulted:
        delays = [r["detection_delay_s"] for r in ada]
        block["detected"] = _rate(sum(1 for d in delays if d is not None), len(ada))
        block["delay_s"] = _quantiles([d for d in delays if d is not None])
    block["errors"] = {
        metric: {
            "fixed": _quantiles([r[metric] for r in fix]),
            "adaptive": _quantiles([r[metric] for r in ada]),
        }
        for metric in ERROR_METRICS
    }
    fixed = {_pair_key(r, sweeps): r for r in fix}
    pairs = [(r, fixed[_pair_key(r, sweeps)]) for r in ada if _pair_key(r, sweeps) in fixed]
    better = sum(1 for a, f in pairs if _lt(a["rms_error"], f["rms_error"]))
    block["adaptive_better_rms"] = _rate(better, len(pairs)) if pairs else None
    return block


def _counts(values: Any) -> list[dict[str, Any]]:
    c = Counter(str(v) for v in values)
    return [{"value": k, "n": n} for k, n in sorted(c.items(), key=lambda kv: (-kv[1], kv[0]))]


def _by_value(path: str, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per value of one swept column: the rates and the median delay (adaptive runs)."""
    groups: dict[float, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        if r["mode"] == "adaptive":
            groups[r[path]].append(r)
    out = []
    for value in sorted(groups):
        g = groups[value]
        faulted = [r for r in g if r["faulted"]]
        free = [r for r in g if not r["faulted"]]
        delays = [r["detection_delay_s"] for r in faulted if r["detection_delay_s"] is not None]
        fs_rows, fs_basis = (
            (free, "fault-free scenarios") if free else (faulted, "before the onset")
        )
        out.append(
            {
                "value": value,
                "runs": len(g),
                "correct": _share(faulted, "correct"),
                "detected": _rate(len(delays), len(faulted)),
                "delay_s": _quantiles(delays),
                "false_switch": _share(fs_rows, "false_any"),
                "false_switch_basis": fs_basis,
                "rms_error": _quantiles([r["rms_error"] for r in g]),
            }
        )
    return out


def summarize(
    table: Any,
    meta: Mapping[str, Any],
    expect: Mapping[str, str] | None = None,
    tau_path: str | None = None,
) -> CampaignSummary:
    """The numbers of the report, from a results table and its metadata.

    Parameters
    ----------
    table : pyarrow.Table or list of dict
    meta : dict
        The campaign metadata of the results file.
    expect : dict, optional
        Expected final configuration per scenario.
    tau_path : str, optional
        The swept column holding τ (default: ``runtime.threshold`` or
        ``runtime.hysteresis.on`` if swept).

    Raises
    ------
    CampaignError
        If ``tau_path`` is not a swept column.
    """
    rows = table if isinstance(table, list) else table.to_pylist()
    sweeps = list(meta.get("sweeps", []))
    expect = dict(expect or {})
    ok = [dict(r) for r in rows if r.get("error") is None]
    units = {r.get("unit") for r in ok} - {None}
    failed = len(rows) - len(ok)
    errors = [f"{r['run_id']}: {r['error']}" for r in rows if r.get("error") is not None][:10]
    _classify(ok, sweeps, expect)
    names = list(dict.fromkeys(r["scenario"] for r in rows))
    unknown = sorted(set(expect) - set(names))
    if unknown:
        raise CampaignError(
            f"--expect {unknown[0]}: no such scenario in the results; known: {', '.join(names)}"
        )
    scenarios = [_scenario_block(n, [r for r in ok if r["scenario"] == n], sweeps) for n in names]
    if tau_path is None:
        found = [p for p in meta.get("thresholds", []) if p in sweeps]
        tau_path = found[0] if found else None
    elif tau_path not in sweeps:
        raise CampaignError(
            f"--tau {tau_path}: not a swept column; swept: {', '.join(sweeps) or 'none'}"
        )
    tau = None
    if tau_path is not None:
        free = [r for r in ok if r["mode"] == "adaptive" and not r["faulted"]]
        curves = []
        for b in scenarios:
            if b["faulted"]:
                mine = [r for r in ok if r["scenario"] == b["scenario"]]
                curves.append(
                    {"scenario": b["scenario"], "points": _by_value(tau_path, mine + free)}
                )
        tau = {"path": tau_path, "points": _by_value(tau_path, ok), "curves": curves}
    by_sweep = [{"path": p, "points": _by_value(p, ok)} for p in sweeps if p != tau_path]
    unit = units.pop() if len(units) == 1 else None
    return CampaignSummary(
        dict(meta), len(rows), failed, scenarios, tau, by_sweep, expect, errors, unit
    )

