"""``archself campaign-report``: what a campaign says about the adaptation loop.

From a results table (:mod:`archself.campaign.results`) it computes, per scenario:

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

Rates come with 95 % Wilson intervals. The HTML page is rendered from
``templates/campaign_report.html.j2`` in a sandboxed Jinja environment
(``StrictUndefined``, autoescape); the figures are SVG files beside it, drawn
with matplotlib's object-oriented API (Agg/SVG, imported only here). The same
numbers go to ``summary.json``.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from archself.campaign.sweep import CampaignError

__all__ = ["CampaignSummary", "campaign_report", "parse_expect", "summarize", "summary_text"]


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
    """The numbers of a campaign report (``to_dict()`` is ``summary.json``)."""

    meta: dict[str, Any]
    runs: int
    failed: int
    scenarios: list[dict[str, Any]]
    tau: dict[str, Any] | None
    sweeps: list[dict[str, Any]]
    expect: dict[str, str]
    errors: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "meta": self.meta,
            "runs": self.runs,
            "failed": self.failed,
            "expect": self.expect,
            "scenarios": self.scenarios,
            "tau": self.tau,
            "sweeps": self.sweeps,
            "errors": self.errors,
        }


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
                better = _lt(r["rms_error_m"], base["rms_error_m"])
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
        "correct": _rate(sum(1 for r in ada if r["correct"]), len(ada)),
        "false_switch": _rate(sum(1 for r in ada if r["false_any"]), len(ada)),
        "false_switches_per_run": (sum(r["false_switches"] or 0 for r in ada) / len(ada))
        if ada
        else None,
        "final_configurations": _counts(r["final_configuration"] for r in ada),
        "paths": _counts(r["configuration_path"] for r in ada),
    }
    if faulted:
        delays = [r["detection_delay_s"] for r in ada]
        block["detected"] = _rate(sum(1 for d in delays if d is not None), len(ada))
        block["delay_s"] = _quantiles([d for d in delays if d is not None])
    errors: dict[str, Any] = {}
    for metric in ("max_error_m", "final_error_m", "rms_error_m"):
        errors[metric] = {
            "fixed": _quantiles([r[metric] for r in fix]),
            "adaptive": _quantiles([r[metric] for r in ada]),
        }
    block["errors"] = errors
    fixed = {_pair_key(r, sweeps): r for r in fix}
    pairs = [(r, fixed[_pair_key(r, sweeps)]) for r in ada if _pair_key(r, sweeps) in fixed]
    if pairs:
        block["adaptive_better_rms"] = _rate(
            sum(1 for a, f in pairs if _lt(a["rms_error_m"], f["rms_error_m"])), len(pairs)
        )
    else:
        block["adaptive_better_rms"] = None
    return block


def _counts(values: Any) -> list[dict[str, Any]]:
    c: dict[str, int] = defaultdict(int)
    for v in values:
        c[str(v)] += 1
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
        if free:
            fs = _rate(sum(1 for r in free if r["false_any"]), len(free))
            fs_basis = "fault-free scenarios"
        else:
            fs = _rate(sum(1 for r in faulted if r["false_any"]), len(faulted))
            fs_basis = "before the onset"
        out.append(
            {
                "value": value,
                "runs": len(g),
                "correct": _rate(sum(1 for r in faulted if r["correct"]), len(faulted)),
                "detected": _rate(len(delays), len(faulted)),
                "delay_s": _quantiles(delays),
                "false_switch": fs,
                "false_switch_basis": fs_basis,
                "rms_error_m": _quantiles([r["rms_error_m"] for r in g]),
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
    return CampaignSummary(dict(meta), len(rows), failed, scenarios, tau, by_sweep, expect, errors)


def _pct(rate: Mapping[str, Any] | None) -> str:
    if not rate or rate.get("rate") is None:
        return "–"
    return f"{100 * rate['rate']:.0f} % ({rate['k']}/{rate['n']})"


def _num(x: Any, fmt: str = "{:.2f}") -> str:
    return "–" if x is None else fmt.format(x)


def summary_text(s: CampaignSummary) -> str:
    """A few lines for the terminal: per scenario the rates, delay and errors."""
    lines = [
        f"{s.meta.get('architecture', '?')}: {s.runs} runs"
        + (f", {s.failed} failed" if s.failed else "")
    ]
    for b in s.scenarios:
        e = b["errors"]["rms_error_m"]
        head = f"  {b['scenario']}{' (fault-free)' if not b['faulted'] else ''}: "
        parts = [f"correct {_pct(b['correct'])}"]
        if b["faulted"]:
            parts.append(f"median delay {_num(b['delay_s']['median'], '{:.1f}')} s")
        parts.append(f"false switches {_pct(b['false_switch'])}")
        parts.append(
            f"median RMS fixed {_num(e['fixed']['median'])} m"
            f" / adaptive {_num(e['adaptive']['median'])} m"
        )
        lines.append(head + ", ".join(parts))
    if s.tau:
        lines.append(f"  τ sweep ({s.tau['path']}):")
        for c in s.tau["curves"]:
            for p in c["points"]:
                lines.append(
                    f"    {c['scenario']} τ = {p['value']:g}: median delay "
                    f"{_num(p['delay_s']['median'], '{:.1f}')} s, detected "
                    f"{_pct(p['detected'])}, false switches {_pct(p['false_switch'])}"
                )
    return "\n".join(lines)


# --------------------------------------------------------------------------- figures
def _figure(width: float = 6.4, height: float = 3.6) -> Any:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    return fig


def _save(fig: Any, path: Path) -> None:
    import io

    import matplotlib

    from archself.atomic import write_bytes

    buf = io.BytesIO()
    with matplotlib.rc_context({"svg.hashsalt": "archself", "svg.fonttype": "none"}):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    write_bytes(path, buf.getvalue())


def _fig_delays(rows: list[dict[str, Any]], names: list[str], path: Path) -> bool:
    data = [
        [
            r["detection_delay_s"]
            for r in rows
            if r["scenario"] == n
            and r["mode"] == "adaptive"
            and r.get("error") is None
            and r["detection_delay_s"] is not None
        ]
        for n in names
    ]
    if not any(data):
        return False
    fig = _figure()
    ax = fig.add_subplot()
    for n, d in zip(names, data, strict=True):
        if d:
            ax.hist(d, bins=min(30, max(5, len(d) // 3)), alpha=0.6, label=f"{n} (n = {len(d)})")
    ax.set_xlabel("detection delay [s]")
    ax.set_ylabel("runs")
    ax.legend(frameon=False)
    ax.set_title("Detection delay: first switch after the fault onset")
    _save(fig, path)
    return True


def _fig_errors(rows: list[dict[str, Any]], names: list[str], metric: str, path: Path) -> bool:
    fig = _figure(max(6.4, 1.6 * len(names) + 2), 3.8)
    ax = fig.add_subplot()
    data, labels, colors = [], [], []
    for n in names:
        for mode, color in (("fixed", "#999999"), ("adaptive", "#1f77b4")):
            v = [
                r[metric]
                for r in rows
                if r["scenario"] == n
                and r["mode"] == mode
                and r.get("error") is None
                and r[metric] is not None
                and math.isfinite(r[metric])
            ]
            if v:
                data.append(v)
                labels.append(f"{n}\n{mode}")
                colors.append(color)
    if not data:
        return False
    parts = ax.boxplot(data, patch_artist=True, showfliers=True)
    ax.set_xticks(range(1, len(labels) + 1), labels)
    for patch, c in zip(parts["boxes"], colors, strict=True):
        patch.set_facecolor(c)
        patch.set_alpha(0.6)
    ax.set_ylabel(metric.removesuffix("_m").replace("_", " ") + " [m]")
    ax.set_yscale("log" if min(min(d) for d in data) > 0 else "linear")
    title = {"rms_error_m": "RMS", "max_error_m": "Maximum", "final_error_m": "Final"}[metric]
    ax.set_title(f"{title} error, fixed vs adaptive (paired seeds)")
    _save(fig, path)
    return True


def _fig_tau(tau: Mapping[str, Any], path: Path) -> bool:
    """One curve per faulted scenario: false-switch rate (x) against median delay (y) over τ."""
    curves = tau.get("curves") or [{"scenario": "all faulted", "points": tau["points"]}]
    fig = _figure(6.0, 4.4)
    ax = fig.add_subplot()
    colors = ["#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2"]
    drawn = False
    xs_all: list[float] = []
    basis = ""
    for c, curve in enumerate(curves):
        color = colors[c % len(colors)]
        pts = [p for p in curve["points"] if p["false_switch"]["rate"] is not None]
        ok = [p for p in pts if p["delay_s"]["median"] is not None]
        if not pts:
            continue
        basis = pts[0]["false_switch_basis"]
        xs_all += [p["false_switch"]["rate"] for p in pts]
        if ok:
            drawn = True
            x = [p["false_switch"]["rate"] for p in ok]
            y = [p["delay_s"]["median"] for p in ok]
            ax.plot(x, y, "-o", color=color, label=str(curve["scenario"]))
            for k, (p, xi, yi) in enumerate(zip(ok, x, y, strict=True)):
                ax.plot(
                    [xi, xi],
                    [p["delay_s"]["p10"], p["delay_s"]["p90"]],
                    color=color,
                    alpha=0.35,
                    lw=3,
                )
                ax.plot(
                    [p["false_switch"]["lo"], p["false_switch"]["hi"]],
                    [yi, yi],
                    color=color,
                    alpha=0.35,
                    lw=1,
                )
                # the ends of the curve are labelled; when both sit on one spot (every τ
                # detects in the first cycle, say) one label gives the range
                together = len(ok) > 1 and x[0] == x[-1] and abs(y[0] - y[-1]) < 1.0
                label = None
                if together and k == 0:
                    label = f"τ={ok[0]['value']:g}…{ok[-1]['value']:g}"
                elif not together and k in (0, len(ok) - 1):
                    label = f"τ={p['value']:g}"
                if label is not None:
                    ax.annotate(
                        label,
                        (xi, yi),
                        textcoords="offset points",
                        xytext=(6, 2),
                        fontsize=7,
                        color=color,
                    )
        for p in pts:
            if p["delay_s"]["median"] is None:
                drawn = True
                ax.axvline(p["false_switch"]["rate"], color=color, ls=":", lw=1)
                ax.annotate(
                    f"{curve['scenario']}, τ={p['value']:g}: never detected",
                    (p["false_switch"]["rate"], 0),
                    fontsize=7,
                    color=color,
                    rotation=90,
                    va="bottom",
                )
    if not drawn:
        return False
    ax.set_xlabel(f"false-switch rate ({basis})")
    ax.set_ylabel("detection delay [s] (median, 10–90 %)")
    ax.set_title(f"τ sweep: {tau['path']}")
    ax.set_xlim(-0.03, max(1.0, max(xs_all)) + 0.03)
    ax.legend(frameon=False, fontsize=8)
    _save(fig, path)
    return True


# --------------------------------------------------------------------------- report
def _environment() -> Any:
    from jinja2 import FileSystemLoader, StrictUndefined
    from jinja2.sandbox import SandboxedEnvironment

    from archself.resources import data_dir

    env = SandboxedEnvironment(
        loader=FileSystemLoader(str(data_dir("templates"))),
        undefined=StrictUndefined,
        autoescape=True,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )
    env.filters["pct"] = _pct
    env.filters["num"] = _num
    return env


def campaign_report(
    results: str | Path,
    out_dir: str | Path,
    *,
    expect: Mapping[str, str] | None = None,
    tau_path: str | None = None,
) -> CampaignSummary:
    """Write ``index.html``, ``summary.json`` and the SVG figures of a campaign to ``out_dir``.

    Raises
    ------
    CampaignError
        Unreadable results, an unknown scenario in ``expect``, a bad ``tau_path``.
    OutputError
        If ``out_dir`` cannot be written.
    """
    from archself.atomic import write_text
    from archself.campaign.results import read_results
    from archself.errors import OutputError

    table, meta = read_results(results)
    summary = summarize(table, meta, expect, tau_path)
    rows = table.to_pylist()
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot create folder: {exc.strerror}") from None
    names = [b["scenario"] for b in summary.scenarios]
    figures: dict[str, str | None] = {}
    specs = [
        (
            "delays",
            lambda p: _fig_delays(
                rows, [b["scenario"] for b in summary.scenarios if b["faulted"]], p
            ),
        ),
        ("rms", lambda p: _fig_errors(rows, names, "rms_error_m", p)),
        ("max", lambda p: _fig_errors(rows, names, "max_error_m", p)),
        ("final", lambda p: _fig_errors(rows, names, "final_error_m", p)),
        ("tau", lambda p: summary.tau is not None and _fig_tau(summary.tau, p)),
    ]
    for key, draw in specs:
        name = f"{key}.svg"
        figures[key] = name if draw(out / name) else None
    env = _environment()
    html = env.get_template("campaign_report.html.j2").render(
        s=summary.to_dict(),
        figures=figures,
        results_name=Path(results).name,
    )
    write_text(out / "index.html", html)
    write_text(
        out / "summary.json",
        json.dumps(_jsonable(summary.to_dict()), indent=2, ensure_ascii=False) + "\n",
    )
    return summary


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
