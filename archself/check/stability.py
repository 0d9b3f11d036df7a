"""Closed-loop stability verified before a run: every configuration and every action's result.

``archself validate`` calls :func:`verify_stability` when the file opts in with
``runtime.stability.verify: warning`` or ``error``. For each configuration the
system is compiled, stepped once (so model nodes have published and estimators
hold their models) and its closed loop built
(:meth:`archself.system.executor.LiveSystem.closed_loop`: the modules' linear models wired by
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
from dataclasses import dataclass
from typing import Any

import numpy as np

from archself.model.architecture import Architecture

__all__ = ["Unstable", "describe_mode", "verify_stability"]


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


def _judge(system: Any, configuration: str, margin: float) -> tuple[bool, str] | None:
    return describe_mode(system.closed_loop(configuration), margin, float(system.dt))


def _compiled(arch: Architecture, configuration: str) -> Any:
    from archself.system.compiler import compile_system

    system = compile_system(arch, configuration, seed=0)
    system.step()
    return system


def _why(exc: BaseException) -> str:
    return getattr(exc, "message", None) or str(exc) or type(exc).__name__


def verify_stability(arch: Architecture) -> Iterator[Unstable]:
    """The unstable configurations and actions of ``arch`` (Eq. 21 at its margin).

    Yields nothing for ``runtime.stability.verify: off``. A configuration that cannot
    be compiled or whose models cannot be wired is reported too: its stability is
    unknown.
    """
    rt = arch.runtime.stability
    if rt.verify == "off":
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
        for i, a in enumerate(arch.actions):
            if a.kind != "parameter_update":
                verdict = verdicts.get(a.to or "")
                if verdict is not None and not verdict[0]:
                    yield Unstable(("actions", i, "to"),
                                   f"action '{a.id}' leads to configuration '{a.to}', which is "
                                   f"not stable: {verdict[1]}")
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
