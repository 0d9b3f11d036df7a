"""Closed-loop stability verified before a run: every configuration and every action's result.

``archself validate`` calls :func:`verify_stability` when the file opts in with
``runtime.stability.verify: warning`` or ``error``. For each configuration the
system is compiled, stepped once (so model nodes have published and estimators
hold their models) and its closed loop built
(:meth:`archself.system.live.LiveSystem.closed_loop`: the modules' linear models wired by
the configuration's edges, else their ``linearization()`` blocks); the test is the
runtime's own, ``max Re λ(A) ≤ −ε`` (Eq. 21, ε = ``runtime.stability.margin``). A
configuration whose modules give no model is not judged. Each structural action is
judged by its target configuration; each parameter update by the configurations it
applies in, with the new values set.

Compiling the modules imports what their types need (python-control, filterpy), so
the check runs only for a file that asks for it; a file with ``verify: off`` (the
default) is checked without importing them.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from archself.model.architecture import Architecture

__all__ = ["LoopVerdict", "Unstable", "describe_mode", "loop_table", "loop_verdict",
           "verify_stability"]


@dataclass(frozen=True)
class Unstable:
    """One finding of the check: what is unstable (or could not be judged) and where.

    Attributes
    ----------
    path : tuple
        The node of the file it is located at.
    message : str
        One line: max Re λ, the bound, and the modules the unstable mode lives in.
    """

    path: tuple[str | int, ...]
    message: str
    severity: str | None = None  # None: the file's runtime.stability.verify


def describe_mode(closed_loop: Any, margin: float, dt: float) -> tuple[bool, str] | None:
    """``(stable, text)`` of a :class:`~archself.linear.closed_loop.ClosedLoop`; None if empty.

    Examples
    --------
    >>> import numpy as np
    >>> from archself.linear.wiring import ClosedLoop
    >>> describe_mode(ClosedLoop(None, [("pi", np.array([[0.2]]))]), 0.001, 0.1)
    (False, "max Re λ(A) = 0.2 1/s > −ε = -0.001 (from pi's linearization())")
    """
    worst = closed_loop.worst_mode()
    if worst is None:
        return None
    re, mag, shares = worst
    ok = re <= -margin
    rel = "≤" if ok else ">"
    text = f"max Re λ(A) = {re:.4g} 1/s {rel} −ε = {-margin:.4g}"
    if mag is None:
        return ok, f"{text} (from {shares[0][0]}'s linearization())"
    lives = ", ".join(f"{m} {100 * s:.0f} %" for m, s in shares[:3] if s >= 0.005)
    return ok, f"{text} (|λ| = {mag:.4g} per {dt:g} s step); the mode lives in {lives}"


@dataclass
class LoopVerdict:
    """The whole-loop verdict of one configuration (docs/stability.md).

    Attributes
    ----------
    configuration : str
    verdict : str
        ``verified`` (every mode inside the unit circle), ``marginal`` (a mode with
        |λ| within :data:`~archself.linear.closed_loop.MARGINAL_TOL` of 1, none above),
        ``unstable`` or ``unverified``.
    covered, stateful : int
        Stateful modules whose columns entered A without a problem / stateful modules.
    active : int
        Active modules of the configuration.
    states : int
        Size of the loop's state vector.
    max_lambda : float or None
        max |λ| per step (None: unverified).
    marginal, unstable : list of str
        Per mode: ``|λ| (modules it lives in)``.
    why : str
        Why unverified (empty otherwise).
    """

    configuration: str
    verdict: str
    covered: int = 0
    stateful: int = 0
    active: int = 0
    states: int = 0
    max_lambda: float | None = None
    marginal: list[str] = field(default_factory=list)
    unstable: list[str] = field(default_factory=list)
    why: str = ""

    @property
    def margin(self) -> float | None:
        """1 − max |λ| per step."""
        return None if self.max_lambda is None else 1.0 - self.max_lambda

    def row(self) -> str:
        """One line of the table ``validate`` prints."""
        lam = "—" if self.max_lambda is None else f"{self.max_lambda:.6f}"
        extra = "; ".join(self.unstable or self.marginal) or self.why
        return (f"  {self.configuration}: {self.verdict}, {self.covered}/{self.stateful} stateful "
                f"modules ({self.states} states), max |λ| = {lam} per step"
                + (f"; {extra}" if extra else ""))

    def message(self) -> str:
        """The finding's text."""
        head = f"configuration '{self.configuration}'"
        if self.verdict == "unverified":
            return f"{head}: whole-loop stability not verified: {self.why}"
        kind = "unstable" if self.verdict == "unstable" else "marginal"
        modes = self.unstable if self.verdict == "unstable" else self.marginal
        return (f"{head} is {kind} over the whole loop: max |λ| = {self.max_lambda:.6g} per "
                f"step; {len(modes)} {kind} mode(s): {'; '.join(modes[:3])}")


def loop_verdict(system: Any, configuration: str | None = None, steps: int = 1) -> LoopVerdict:
    """The verdict of ``configuration`` from the whole loop of ``system`` around now."""
    from archself.linear.closed_loop import MARGINAL_TOL

    name = configuration or system.configuration
    try:
        loop = system.whole_loop(configuration, steps)
    except Exception as exc:  # noqa: BLE001 - any failure leaves it unverified
        return LoopVerdict(name, "unverified", why=f"linearization failed: {_why(exc)}")
    n_active = len(system._make_plan(name).active)
    stateful, states = len(loop.stateful), len(loop.owners)
    if loop.problems:
        bad = {p.split("'", 1)[0] for p in loop.problems}
        covered = sum(1 for m in loop.stateful if m not in bad)
        return LoopVerdict(name, "unverified", covered, stateful, n_active, states,
                           why=loop.problems[0])
    worst, marginal, unstable = loop.modes(MARGINAL_TOL)
    verdict = "unstable" if unstable else "marginal" if marginal else "verified"
    return LoopVerdict(
        name, verdict, stateful, stateful, n_active, states, worst,
        marginal=[f"{m.label(loop.steps)} ({m.where()})" for m in marginal],
        unstable=[f"{m.label(loop.steps)} ({m.where()})" for m in unstable])


def map_steps(arch: Architecture) -> int:
    """Steps of the map the whole-loop check linearizes (``runtime.stability.linearize_s``)."""
    rt = arch.runtime
    return max(1, round(float(rt.stability.linearize_s) / float(rt.step_s)))


#: The last tables (architecture, table): ``validate`` prints the one its check computed.
_TABLES: list[tuple[Architecture, list[LoopVerdict]]] = []


def loop_table(arch: Architecture) -> list[LoopVerdict]:
    """The whole-loop verdict of every configuration at its operating point.

    Each configuration is compiled (seed 0), run ``runtime.stability.settle_s``
    (the nominal run's state after warm-up) and linearized
    (:meth:`~archself.system.live.LiveSystem.whole_loop`) over ``linearize_s``. The
    table of the same architecture object is computed once (the check and the
    command line share it).
    """
    for known, table in _TABLES:
        if known is arch:
            return table
    table = _loop_table(arch)
    _TABLES[:] = [*_TABLES[-3:], (arch, table)]
    return table


def table_text(table: list[LoopVerdict]) -> str:
    """The table ``validate`` and ``info --stability`` print."""
    head = ("whole-loop stability (configuration: verdict, modules covered/stateful, "
            "max |λ| per step, marginal or unstable modes):")
    return "\n".join([head, *(v.row() for v in table)])


def _loop_table(arch: Architecture) -> list[LoopVerdict]:
    settle = float(arch.runtime.stability.settle_s)
    out = []
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        for name in arch.configurations:
            try:
                system = _compiled(arch, name)
                system.run(settle)
            except Exception as exc:  # noqa: BLE001
                out.append(LoopVerdict(name, "unverified", why=f"the nominal run failed: "
                                                                f"{_why(exc)}"))
                continue
            out.append(loop_verdict(system, name, map_steps(arch)))
    return out


def _judge(system: Any, configuration: str, margin: float) -> tuple[bool, str] | None:
    return describe_mode(system.closed_loop(configuration), margin, float(system.dt))


def _compiled(arch: Architecture, configuration: str) -> Any:
    from archself.system.live import compile_system

    system = compile_system(arch, configuration, seed=0)
    system.step()
    return system


def _why(exc: BaseException) -> str:
    return getattr(exc, "message", None) or str(exc) or type(exc).__name__


def verify_stability(arch: Architecture, verify: str | None = None) -> Iterator[Unstable]:
    """The unstable configurations and actions of ``arch`` (Eq. 21 at its margin).

    ``verify`` overrides the file's ``runtime.stability.verify`` (``validate
    --stability``); yields nothing when it is off. A configuration that cannot
    be compiled or whose models cannot be wired is reported too: its stability is
    unknown.
    """
    rt = arch.runtime.stability
    if (verify or rt.verify) == "off":
        return
    margin = float(rt.margin)
    verdicts: dict[str, tuple[bool, str] | None] = {}
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        for name in arch.configurations:
            path: tuple[str | int, ...] = ("configurations", name)
            try:
                verdict = _judge(_compiled(arch, name), name, margin)
            except Exception as exc:  # noqa: BLE001 - any failure leaves it unverified
                yield Unstable(path, f"configuration '{name}': stability not verified: "
                                     f"{_why(exc)}")
                continue
            verdicts[name] = verdict
            if verdict is not None and not verdict[0]:
                yield Unstable(path, f"configuration '{name}' is not stable: {verdict[1]}")
        loops = {v.configuration: v for v in loop_table(arch)}
        for name, v in loops.items():
            declared = verdicts.get(name)
            # reported already: unstable by the declared models, or not compiled at all
            flagged = (declared is not None and not declared[0]) or name not in verdicts
            if (v.verdict in ("unstable", "unverified") and not flagged) or (
                    v.verdict == "marginal" and rt.marginal != "pass"):
                yield Unstable(("configurations", name), v.message(),
                               "warning" if v.verdict == "marginal" and rt.marginal == "warning"
                               else None)
        for i, a in enumerate(arch.actions):
            if a.kind != "parameter_update":
                verdict = verdicts.get(a.to or "")
                if verdict is not None and not verdict[0]:
                    yield Unstable(("actions", i, "to"),
                                   f"action '{a.id}' leads to configuration '{a.to}', which is "
                                   f"not stable: {verdict[1]}")
                elif (target := loops.get(a.to or "")) is not None and (
                        target.verdict == "unstable"):
                    yield Unstable(("actions", i, "to"),
                                   f"action '{a.id}' leads to configuration '{a.to}', which is "
                                   f"unstable over the whole loop (max |λ| = "
                                   f"{target.max_lambda:.6g} per step)")
                continue
            for name in a.applies_in or list(arch.configurations):
                conf = arch.configurations.get(name)
                if conf is None or a.module not in conf.modules:
                    continue
                try:
                    system = _compiled(arch, name)
                    system.set_params(a.module, dict(a.set or {}))
                    verdict = _judge(system, name, margin)
                except Exception as exc:  # noqa: BLE001
                    yield Unstable(("actions", i, "set"),
                                   f"action '{a.id}' in configuration '{name}': stability not "
                                   f"verified: {_why(exc)}")
                    continue
                if verdict is not None and not verdict[0]:
                    yield Unstable(("actions", i, "set"),
                                   f"action '{a.id}' makes configuration '{name}' unstable: "
                                   f"{verdict[1]}")
