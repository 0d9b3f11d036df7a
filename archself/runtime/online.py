"""Online W and bands (``runtime.online``): the offline fits, run on the loop's own history.

Both updates are off by default; each is bounded, and every update — accepted or
rejected — is an event (:attr:`Online.events`): ``{t_s, kind, what, old, proposed, new,
window, samples, outcome, reason}``, noted in the cycle's decision record (``explain``
shows it) and saved in the trace (``meta.knowledge.online``).

**W** (``runtime.online.weights``), every ``every_s``: the identify fit
(:func:`~archself.runtime.identify_fit.fit_target`, non-negative least squares per
target module) over the last ``window_s`` of the Monitor's filtered residual signals,
in the loop's units (:func:`~archself.runtime.identify_fit.delta_residuals`: σ·|s̄|/n)
and centred on the window's mean. The run's own fluctuations stand in for identify's
perturbation experiments: row i of ``(I − Wᵀ) r = e`` reads ``Δr_i = Σ_k W_ki Δr_k + Δe_i``
and the fit takes ``Δe_i`` as noise independent of the sources'. That fails on a cycle
(a control loop): the source's residual then carries the target's own noise back, and
the fit would find the loop's reverse direction; edges on a cycle of the active graph
are therefore not fitted (logged as rejected). Only the cycles of the current
configuration count, and only edges whose two ends have a residual are fitted. A fitted
weight is taken when its source is excited (``min_excitation``) and the target's R² ≥
``min_r2``; it moves at most ``max_change`` of its value per update and stays within
``[declared/max_factor, declared·max_factor]`` and ≥ 0. An update whose W breaks the rule
of ``archself validate`` (ρ(W) < ``runtime.max_spectral_radius``, ``I − Wᵀ`` not
singular) is rejected as a whole.

**Bands** (``runtime.online.bands``): the run is cut into windows of ``window_s``. A
window is *nominal* when every cycle in it is: J_obs within ``objective.acceptable``, no
κ finding, no action taken, not within the dwell time of a structural change, the
residual filters settled since the configuration was entered (three of the longest
smoothing time constants), one configuration throughout. The candidate alarms are not
asked: they depend on the very band being learned (a band too tight would never see a
nominal window). Per module the largest filtered signal of each nominal window is kept
(the last ``windows``); every ``every_s`` the band is calibrate's per channel
(:func:`~archself.runtime.tails.quantile_level` of the maxima at the share ``rate/K`` of
the K active channels, divided by the alarm factor ``1 + τ/(c_j·σ_j)``,
:func:`~archself.runtime.tails.band_of_level`), moved by at most the factor ``max_step``
per update and kept within ``[declared·min_factor, declared·max_factor]`` (by default
never tighter than the file's: ``min_factor`` 1).

docs/learning.md shows both at work and how they fail.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from archself.runtime.identify_fit import delta_residuals, fit_target
from archself.runtime.tails import band_of_level, quantile_level

__all__ = ["Online", "knowledge_summary", "on_cycles", "online_of"]

MIN_ROWS = 10  # cycles a W fit needs


def _clip(value: float, low: float, high: float) -> float:
    return min(max(value, low), high)


def on_cycles(edges: set[tuple[str, str]]) -> set[tuple[str, str]]:
    """The edges a → b on a cycle (b reaches a): their Δr_a holds b's own Δe_b.

    Examples
    --------
    >>> sorted(on_cycles({("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")}))
    [('a', 'b'), ('b', 'c'), ('c', 'a')]
    """
    succ: dict[str, set[str]] = {}
    for a, b in edges:
        succ.setdefault(a, set()).add(b)
    reach: dict[str, set[str]] = {}
    for start in succ:
        seen, todo = set(), [start]
        while todo:
            for nxt in succ.get(todo.pop(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        reach[start] = seen
    return {(a, b) for a, b in edges if a == b or a in reach.get(b, ())}


class Online:
    """The online updates of W and of the bands of one loop.

    Parameters
    ----------
    arch : Architecture
        Reads ``runtime.online`` and the declared weights and bands.
    knowledge : Knowledge
        Its weights are updated (:meth:`Knowledge.set_weight`).
    monitor : Monitor
        Its bands are updated (:meth:`Monitor.set_nominal`).

    Attributes
    ----------
    events : list of dict
        Every update, accepted or rejected.
    """

    def __init__(self, arch: Any, knowledge: Any, monitor: Any) -> None:
        rt = arch.runtime
        self.s = rt.online
        self.k, self.monitor = knowledge, monitor
        self.events: list[dict[str, Any]] = []
        self.acceptable = float(rt.objective.acceptable)
        self.dwell = float(rt.dwell_s) if rt.ablation.dwell else 0.0
        self.tau = rt.threshold if rt.threshold is not None else (
            rt.hysteresis.on if rt.hysteresis is not None else None)
        res = {n: m.residual for n, m in arch.modules.items() if m.residual is not None}
        self.declared_band = {n: float(r.nominal) for n, r in res.items()}
        self.sensitivity = {n: float(r.sensitivity) for n, r in res.items()}
        self.settle = 3.0 * max((float(r.smoothing_s) for r in res.values()), default=0.0)
        self.declared_w = dict(self._pairs())
        self._history: deque[tuple[float, str, tuple[str, ...], np.ndarray]] = deque()
        self._maxima: dict[str, deque[tuple[float, float, float]]] = {}  # (t0, t1, max)
        self._window: dict[str, Any] | None = None
        self._entered: tuple[str, float] | None = None
        self._last: Any = None  # the previous cycle's record (its action is known now)
        self._due = {"weights": math.inf, "bands": math.inf}

    # ------------------------------------------------------------------ the cycle
    def cycle(self, record: Any, obs: Any) -> bool:
        """Note one cycle; run the updates that are due. True when W changed."""
        t, conf = float(record.t), record.configuration
        if self._entered is None or self._entered[0] != conf:
            self._entered = (conf, t)
        if math.isinf(self._due["weights"]):
            self._due = {"weights": t + self.s.weights.every_s, "bands": t + self.s.bands.every_s}
        names = tuple(obs.signal_names)
        values = np.abs(np.asarray(obs.signal_values, dtype=float))
        values[~np.asarray(obs.signal_ok, dtype=bool)] = math.nan  # an unusable sample: none
        notes: list[str] = []
        changed = False
        if self.s.weights.enabled:
            self._history.append((t, conf, names, values))
            while self._history and self._history[0][0] < t - self.s.weights.window_s - 1e-9:
                self._history.popleft()
            if t >= self._due["weights"] - 1e-9:
                self._due["weights"] = t + self.s.weights.every_s
                changed = self._update_weights(t, conf, notes)
        if self.s.bands.enabled:
            self._note_window(record, t, conf, names, values)
            if t >= self._due["bands"] - 1e-9:
                self._due["bands"] = t + self.s.bands.every_s
                self._update_bands(t, notes)
        self._last = record
        if notes:
            record.note = "; ".join([record.note, *notes] if record.note else notes)
        return changed

    def _event(self, t: float, kind: str, what: str, old: float, proposed: float | None,
               new: float, window: list[float], samples: int, reason: str) -> dict[str, Any]:
        """Log one update; ``accepted`` when the value changed (a bound that keeps it says so)."""
        moved = math.isfinite(new) and new != old
        if not moved and not reason.startswith(("rejected", "poor", "source", "on a", "too")):
            reason += "; unchanged (at its bound)"
        ev = {"t_s": t, "kind": kind, "what": what, "old": old, "proposed": proposed,
              "new": new, "window": window, "samples": samples,
              "outcome": "accepted" if moved else "rejected", "reason": reason}
        self.events.append(ev)
        return ev

    # ------------------------------------------------------------------ W
    def _pairs(self) -> dict[tuple[str, str], float]:
        """Every (source, target) pair's weight in Knowledge (parallel edges summed)."""
        out: dict[tuple[str, str], float] = {}
        for (s, t, _c), w in self.k._weights.items():
            out[(s, t)] = out.get((s, t), 0.0) + w
        return out

    def _rows(self, conf: str) -> tuple[tuple[str, ...], np.ndarray, list[float]]:
        """The window's signals of the current configuration and active set (cycles × modules)."""
        rows = [h for h in self._history if h[1] == conf]
        if not rows:
            return (), np.zeros((0, 0)), []
        names = rows[-1][2]
        rows = [h for h in rows if h[2] == names]
        x = np.array([h[3] for h in rows])
        keep = np.isfinite(x).all(axis=0)  # the modules usable throughout the window
        return (tuple(n for n, k in zip(names, keep, strict=True) if k), x[:, keep],
                [rows[0][0], rows[-1][0]])

    def _update_weights(self, t: float, conf: str, notes: list[str]) -> bool:
        s = self.s.weights
        names, x, window = self._rows(conf)
        if x.shape[0] < MIN_ROWS:
            self._event(t, "weights", "W", math.nan, None, math.nan, window, x.shape[0],
                        f"too few cycles in the window ({x.shape[0]} < {MIN_ROWS})")
            notes.append("online W: not fitted (too few cycles)")
            return False
        col = {n: j for j, n in enumerate(names)}
        sens = np.array([self.sensitivity[n] for n in names])
        scale = (self.monitor.bands(names) if self.monitor.normalization == "nominal"
                 else np.ones(len(names)))
        u = delta_residuals(x, np.zeros(len(names)), sens, scale)
        du = u - u.mean(axis=0)
        pairs = self._pairs()
        sources: dict[str, list[str]] = {}
        proposed: dict[tuple[str, str], tuple[float, float, str]] = {}
        on_cycle = on_cycles({(a, b) for a, b, _c in self.k.edges})
        for a, b, _c in sorted(self.k.edges):
            if (a, b) in on_cycle and a in col and b in col:
                proposed[(a, b)] = (pairs[(a, b)], math.nan, "on a cycle: its source carries "
                                    "the target's own noise back (not fitted online)")
            elif a in col and b in col and a != b and a not in sources.get(b, []):
                sources.setdefault(b, []).append(a)
        for b, srcs in sources.items():
            fit = fit_target(du[:, [col[a] for a in srcs]], du[:, col[b]],
                             min_excitation=s.min_excitation)
            for i, a in enumerate(srcs):
                old, decl = pairs[(a, b)], self.declared_w[(a, b)]
                if not fit.identifiable[i]:
                    proposed[(a, b)] = (old, math.nan, "source not excited or collinear")
                elif not fit.r2 >= s.min_r2:
                    proposed[(a, b)] = (old, float(fit.weights[i]) / self.k.w_scale,
                                        f"poor fit (R² {fit.r2:.2g} < {s.min_r2:g})")
                else:
                    want = float(fit.weights[i]) / self.k.w_scale
                    new = _clip(_clip(want, old * (1 - s.max_change), old * (1 + s.max_change)),
                                decl / s.max_factor, decl * s.max_factor)
                    why = "fitted" if new == want else "fitted, bounded"
                    proposed[(a, b)] = (new, want, f"{why} (R² {fit.r2:.2g})")
        return self._apply_weights(t, pairs, proposed, window, x.shape[0], notes)

    def _apply_weights(self, t: float, pairs: dict, proposed: dict, window: list[float],
                       rows: int, notes: list[str]) -> bool:
        """Check the spectral rule on the whole W; apply and log, or reject all."""
        from archself.runtime.influence import InfluenceSolver, spectral_radius, weight_matrix

        trial = dict(pairs)
        trial.update({p: v[0] for p, v in proposed.items()})
        W = weight_matrix(self.k.names, [(a, b, w) for (a, b), w in trial.items()])
        rho = spectral_radius(W)
        limit = self.k.arch.runtime.max_spectral_radius
        broken = ""
        if rho >= limit:
            broken = f"ρ(W) = {rho:.4g} ≥ max_spectral_radius {limit:g}"
        else:
            try:
                InfluenceSolver().set_matrix(W, key=0)
            except np.linalg.LinAlgError:
                broken = "I − Wᵀ singular"
        changed = 0
        for (a, b), (new, want, why) in sorted(proposed.items()):
            old = pairs[(a, b)]
            if broken and new != old:
                new, why = old, f"rejected: {broken}"
            ev = self._event(t, "weights", f"{a}→{b}", old, None if math.isnan(want) else want,
                             new, window, rows, why)
            if ev["outcome"] == "accepted":
                self.k.set_weight(a, b, new)
                changed += 1
        kept = len(proposed) - changed
        notes.append(f"online W: {changed} weight(s) updated, {kept} kept"
                     + (f" ({broken})" if broken else ""))
        return changed > 0

    # ------------------------------------------------------------------ bands
    def _nominal_cycle(self, record: Any, t: float) -> bool:
        """J acceptable, no module down or limit violated, no action, dwell over, settled."""
        last = self._last
        findings = any(not k.get("available", True) or k.get("violations")
                       for k in record.kappa.values())
        return (record.phase != "warmup" and not findings and math.isfinite(record.j_obs)
                and record.j_obs <= self.acceptable
                and not (last is not None and last.chosen)
                and t - self.k.t_last >= self.dwell - 1e-9
                and self._entered is not None and t - self._entered[1] >= self.settle - 1e-9)

    def _note_window(self, record: Any, t: float, conf: str, names: tuple[str, ...],
                     values: np.ndarray) -> None:
        """Add the cycle to the current window; close it when it is ``window_s`` long.

        A module's maximum counts only when its every sample in the window was usable.
        """
        w = self._window
        if w is None or w["conf"] != conf or w["names"] != names:
            w = self._window = {"t0": t, "conf": conf, "names": names, "ok": True,
                                "max": np.zeros(len(names))}
        w["ok"] = w["ok"] and self._nominal_cycle(record, t)
        w["max"] = np.maximum(w["max"], values)  # NaN stays NaN: that module's window is lost
        if t - w["t0"] >= self.s.bands.window_s - 1e-9:
            if w["ok"]:
                for n, v in zip(names, w["max"].tolist(), strict=True):
                    if not math.isfinite(v):
                        continue
                    self._maxima.setdefault(n, deque(maxlen=self.s.bands.windows)).append(
                        (w["t0"], t, v))
            self._window = None

    def _update_bands(self, t: float, notes: list[str]) -> None:
        s = self.s.bands
        active = [n for n in self.k.active_names if n in self.declared_band]
        ready = [n for n in active if len(self._maxima.get(n, ())) >= s.windows]
        if not ready:
            return
        if self.tau is None:
            self._event(t, "bands", ", ".join(ready), math.nan, None, math.nan, [], 0,
                        "rejected: runtime.top_k has no threshold τ to set bands against")
            return
        moved = []
        for n in ready:
            old, decl = float(self.monitor.bands([n])[0]), self.declared_band[n]
            gain = self._gain(n) * abs(self.sensitivity[n])
            pooled = self._maxima[n]
            window = [pooled[0][0], pooled[-1][1]]
            level = quantile_level(np.array([v for *_, v in pooled]), s.rate / len(active))
            want = band_of_level(level, float(self.tau), gain)
            if not want > 0:
                self._event(t, "bands", n, old, want, old, window, s.windows,
                            "rejected: no signal in the nominal windows")
                continue
            new = _clip(_clip(want, old / s.max_step, old * s.max_step),
                        decl * s.min_factor, decl * s.max_factor)
            why = "calibrated" if new == want else "calibrated, bounded"
            ev = self._event(t, "bands", n, old, want, new, window, s.windows,
                             f"{why} ({s.windows} nominal windows of {s.window_s:g} s)")
            if ev["outcome"] == "accepted":
                self.monitor.set_nominal(n, new)
                moved.append(f"{n} {old:.3g} → {new:.3g}")
        if moved:
            notes.append("online bands: " + ", ".join(moved))

    def _gain(self, name: str) -> float:
        """c_j: the largest |z_i| a unit residual of ``name`` gives (the current W)."""
        e = np.zeros(len(self.k.names))
        e[self.k.index[name]] = 1.0
        return float(np.abs(np.asarray(self.k.influence(e))[self.k.active_index]).max())

    # ------------------------------------------------------------------ output
    def to_dict(self) -> dict[str, Any]:
        """The events and what changed: every weight and band that moved, declared → now."""
        pairs = self._pairs()
        weights = [{"edge": f"{a}→{b}", "declared": d, "now": pairs[(a, b)]}
                   for (a, b), d in sorted(self.declared_w.items()) if pairs[(a, b)] != d]
        names = sorted(self.declared_band)
        now = self.monitor.bands(names) if names else []
        bands = [{"module": n, "declared": self.declared_band[n], "now": float(v)}
                 for n, v in zip(names, now, strict=True) if float(v) != self.declared_band[n]]
        return {"events": list(self.events), "weights": weights, "bands": bands}


def knowledge_summary(known: Any) -> list[str]:
    """Lines for a person: what a run learned (a trace's ``meta.knowledge``, or {})."""
    if not isinstance(known, dict):
        return []
    lines = []
    outcomes = known.get("outcomes")
    if isinstance(outcomes, list):
        failed = sum(1 for o in outcomes if isinstance(o, dict) and o.get("outcome") == "failure")
        lines.append(f"learned: {len(outcomes)} outcome(s) measured, {failed} failure(s)")
    online = known.get("online")
    if isinstance(online, dict):
        events = [e for e in online.get("events") or [] if isinstance(e, dict)]
        taken = sum(1 for e in events if e.get("outcome") == "accepted")
        moved = [f"{w.get('edge')} {w.get('declared'):.3g} → {w.get('now'):.3g}"
                 for w in online.get("weights") or []]
        moved += [f"{b.get('module')} {b.get('declared'):.3g} → {b.get('now'):.3g}"
                  for b in online.get("bands") or []]
        lines.append(f"online: {taken} of {len(events)} update(s) accepted; declared → now: "
                     + (", ".join(moved) or "nothing moved"))
    return lines


def online_of(arch: Any, knowledge: Any, monitor: Any) -> Online | None:
    """The loop's :class:`Online` of ``arch``: None when ``runtime.online`` is off."""
    return Online(arch, knowledge, monitor) if arch.runtime.online.enabled else None
