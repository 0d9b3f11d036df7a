"""The MAPE-K loop on a real plant: measurements in, reconfiguration commands out.

:class:`LiveLoop` owns a :class:`~archself.live.system.MeasuredSystem` and an
unchanged :class:`~archself.runtime.MapeK`. The plant's code calls
:meth:`LiveLoop.push` with each measurement (every step, or only every MAPE-K
period); whenever ``runtime.period_s`` has passed on the plant's clock the loop
runs one cycle, and what it decides comes back as :class:`Command` objects —
returned by :meth:`~LiveLoop.push`, passed to every callback registered with
:meth:`~LiveLoop.on_command` and put on the queue :attr:`~LiveLoop.commands`.

Without a copy of the plant, the improvement Δ and the stability test come from
the architecture's compiled models (:mod:`archself.live.system`): Δ by the
``sensitivity`` (measured residuals) or ``table`` methods, stability by the
eigenvalue margin (Eq. 21) of the models' closed loop. :func:`live_problems`
finds the actions that could be judged only by a rollout on a snapshot (a
``rollout`` Δ, or a target configuration the models give no linearization of);
:class:`LiveLoop` refuses such an architecture with a one-line
:class:`~archself.live.system.LiveError`, or with ``rollout="reject"`` keeps it
and lets the planner reject those actions at run time (fail closed; the decision
log gives :data:`~archself.live.system.NO_ROLLOUT` as the reason). Every cycle
that evaluated an action says in its ``note`` which methods gave Δ and stability,
and each stability verdict carries ``"source": "models"``.
"""

from __future__ import annotations

import math
import queue
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

from archself.live.system import LiveError, MeasuredSystem
from archself.model.architecture import Architecture
from archself.reports.export import _mode_name
from archself.runtime.mapek import MapeK

__all__ = ["Command", "LiveLoop", "MAX_JUMP_PERIODS", "live_problems"]

#: Default longest forward jump of the plant's clock between two measurements, in
#: MAPE-K periods (``LiveLoop(max_jump_s=...)``, ``archself live --max-jump``).
MAX_JUMP_PERIODS = 100

_STABILITY_NAMES = {
    "eigenvalue": "eigenvalue margin of the compiled models",
    "error": "none (the test failed closed)",
    "off": "off (runtime.ablation)",
}


@dataclass(frozen=True)
class Command:
    """One reconfiguration the plant is told to make.

    Attributes
    ----------
    t_s : float
        Plant time of the measurement the decision was taken on.
    kind : str
        ``"configuration"`` (switch to :attr:`configuration`) or ``"parameters"``
        (set :attr:`values` on :attr:`module`).
    action : str
        Id of the architecture file's action.
    module : str
        The module the action is keyed to (for ``"parameters"``, the one to update).
    configuration : str
        The configuration to run after the command (the current one for ``"parameters"``).
    previous : str
        The configuration before it.
    values : dict
        Parameter values to set (empty for ``"configuration"``).

    Examples
    --------
    >>> c = Command(134.0, "configuration", "use_b", "observer_a", "p2", "p1")
    >>> Command.from_dict(c.to_dict()) == c
    True
    """

    t_s: float
    kind: str
    action: str
    module: str
    configuration: str
    previous: str
    values: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON data (the wire format of :mod:`archself.live.wire`)."""
        return asdict(self)

    def ros2_mode(self, system: str) -> tuple[str, str]:
        """``(part, mode)`` to request from a ROS 2 system_modes mode manager.

        The names of ``archself export --to ros2-modes`` (docs/export.md): a
        configuration is a mode of the system (``system``: the architecture's
        ``name``), a parameter update a mode of the module's node named after the
        action.

        Examples
        --------
        >>> Command(1.0, "configuration", "use_b", "obs", "p2", "p1").ros2_mode("my plant")
        ('my_plant', 'P2')
        >>> Command(1.0, "parameters", "raise-gain", "pi", "p1", "p1").ros2_mode("x")
        ('pi', 'RAISE_GAIN')
        """

        if self.kind == "configuration":
            return _mode_name(system).lower(), _mode_name(self.configuration)
        return self.module, _mode_name(self.action)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Command:
        """The inverse of :meth:`to_dict`."""
        return cls(
            float(data["t_s"]),
            str(data["kind"]),
            str(data["action"]),
            str(data["module"]),
            str(data["configuration"]),
            str(data["previous"]),
            dict(data.get("values") or {}),
        )


def live_problems(arch: Architecture, system: MeasuredSystem | None = None) -> list[str]:
    """The actions of ``arch`` that only a rollout on a snapshot of the plant could judge.

    An action needs a rollout when its improvement method is ``rollout``, or,
    with the stability filter on, when the compiled models give no linearization
    of the configuration it leads to (a parameter update: of each configuration
    it applies in, with the update applied) — the simulator would then fall back
    to the Lyapunov test on a snapshot.

    Parameters
    ----------
    arch : Architecture
    system : MeasuredSystem, optional
        Its compiled models are used (default: compiled here).

    Returns
    -------
    list of str
        One line per action, ``"action <id>: <why>"``; empty when every action
        can be judged from the models.
    """
    system = system or MeasuredSystem(arch)
    out: list[str] = []
    check_stability = arch.runtime.ablation.stability
    seen: dict[str, bool] = {}

    def has_model(conf: str) -> bool:
        if conf not in seen:
            try:
                seen[conf] = system.linearization(conf) is not None
            except Exception:  # noqa: BLE001 - a model that cannot be wired is no model
                seen[conf] = False
        return seen[conf]

    for a in arch.actions:
        if a.improvement.method == "rollout":
            out.append(f"action {a.id}: its Δ is estimated by rollout")
            continue
        if not check_stability:
            continue
        if a.kind != "parameter_update":
            if a.to is not None and not has_model(a.to):
                out.append(f"action {a.id}: configuration {a.to} has no linear model")
            continue
        for conf, spec in arch.configurations.items():
            if a.module not in spec.modules or (a.applies_in and conf not in a.applies_in):
                continue
            try:
                snap = system.snapshot()
                snap.apply_configuration(conf)
                snap.set_params(a.module, dict(a.set or {}))
                ok = snap.linearization(conf) is not None
            except Exception:  # noqa: BLE001
                ok = False
            if not ok:
                out.append(f"action {a.id}: configuration {conf} with it has no linear model")
                break
    return out


class LiveLoop:
    """The MAPE-K loop (Algorithm 1) on a real plant.

    Parameters
    ----------
    arch : Architecture
        The architecture the plant runs (validated).
    configuration : str, optional
        The configuration the plant starts in (default: the file's initial one).
    seed : int, optional
        Seed of the compiled models (see :class:`MeasuredSystem`).
    start_s : float, optional
        The plant's time at which the loop's clock starts: cycles run at
        ``start_s + n·period_s`` (n = 1, 2, …), on the first measurement at or
        after each. Default 0.
    max_jump_s : float, optional
        Longest forward step of the plant's clock between two measurements
        (default :data:`MAX_JUMP_PERIODS` periods, ``runtime.period_s`` each); a
        longer one, a time going back or one that is not finite is refused
        (:meth:`MeasuredSystem.update`).
    rollout : {"refuse", "reject"}
        What to do with actions only a rollout could judge (:func:`live_problems`):
        refuse the architecture (:class:`LiveError`, default) or keep it and let
        the planner reject those actions when they come up.
    on_command : callable, optional
        ``on_command(command)``, called for every :class:`Command` (more with
        :meth:`on_command`).

    Attributes
    ----------
    system : MeasuredSystem
        What the loop sees.
    mapek : MapeK
        The loop itself (its ``decisions`` are the decision log).
    commands : queue.Queue of Command
        Every command, in order (thread-safe: another thread may act on them;
        drain it or ignore it). :meth:`push` itself is not thread-safe: call it
        from one thread.
    measurements : int
        Number of measurements pushed.

    Raises
    ------
    LiveError
        With ``rollout="refuse"``, when an action needs a rollout (the message
        names the first one and how many there are).

    Examples
    --------
    >>> from archself.model.loader import load_architecture
    >>> from archself.resources import data_dir
    >>> arch = load_architecture(data_dir("architectures") / "process_plant.yaml").arch
    >>> loop = LiveLoop(arch)
    >>> loop.push(1.0, outputs={"tank": {"level": 1.0}, "setpoint": {"setpoint": [1.0, 0.0]}})
    []
    >>> loop.mapek.cycle
    1
    """

    def __init__(
        self,
        arch: Architecture,
        *,
        configuration: str | None = None,
        seed: int = 0,
        start_s: float = 0.0,
        max_jump_s: float | None = None,
        rollout: str = "refuse",
        on_command: Callable[[Command], Any] | None = None,
    ) -> None:
        if rollout not in ("refuse", "reject"):
            raise LiveError(f"rollout must be 'refuse' or 'reject', not {rollout!r}")
        self.arch = arch
        self.period_s = float(arch.runtime.period_s)
        if max_jump_s is None:
            max_jump_s = MAX_JUMP_PERIODS * self.period_s
        if not (isinstance(max_jump_s, (int, float)) and math.isfinite(max_jump_s)
                and max_jump_s > 0):
            raise LiveError(f"max_jump_s must be a finite number > 0, not {max_jump_s!r}")
        self.system = MeasuredSystem(arch, configuration, seed=seed,
                                     max_jump_s=float(max_jump_s))
        self.problems = live_problems(arch, self.system)
        if self.problems and rollout == "refuse":
            more = len(self.problems) - 1
            tail = f" (and {more} more)" if more else ""
            raise LiveError(
                f"{arch.name}: {self.problems[0]}{tail}, which needs a snapshot of the plant; "
                "live mode judges actions by table or sensitivity and the models' "
                "eigenvalues (or pass rollout='reject')"
            )
        self.mapek = MapeK(arch)
        self.start_s = float(start_s)
        self._cycles_due = 1
        self._eps = 1e-6 * float(arch.runtime.step_s)
        self._callbacks: list[Callable[[Command], Any]] = []
        self._cycle_callbacks: list[Callable[[Any], Any]] = []
        if on_command is not None:
            self._callbacks.append(on_command)
        self.commands: queue.Queue[Command] = queue.Queue()
        self.measurements = 0
        self._methods = {a.id: a.improvement.method for a in arch.actions}

    # ------------------------------------------------------------------ API
    def on_command(self, fn: Callable[[Command], Any]) -> Callable[[Command], Any]:
        """Register ``fn(command)`` for every command (usable as a decorator)."""
        self._callbacks.append(fn)
        return fn

    def on_cycle(self, fn: Callable[[Any], Any]) -> Callable[[Any], Any]:
        """Register ``fn(record)`` for the decision record of every cycle, as it ends.

        Called after the record is complete and before the cycle's commands go
        out (``archself live --log`` appends it to its journal there).
        """
        self._cycle_callbacks.append(fn)
        return fn

    @property
    def configuration(self) -> str:
        """The configuration the loop believes the plant runs."""
        return self.system.configuration

    @property
    def decisions(self) -> list[Any]:
        """The decision log (one record per cycle)."""
        return self.mapek.decisions

    @property
    def switches(self) -> list[dict[str, Any]]:
        """Every configuration change commanded: ``{t_s, from, to, action, module}``."""
        return self.mapek.switches

    @property
    def updates(self) -> list[dict[str, Any]]:
        """Every parameter update commanded: ``{t_s, action, module, set}``."""
        return self.mapek.updates

    def push(
        self,
        t: float,
        outputs: Mapping[str, Mapping[str, Any]] | None = None,
        signals: Mapping[str, Mapping[str, Any]] | None = None,
        health: Mapping[str, str | None] | None = None,
        configuration: str | None = None,
    ) -> list[Command]:
        """Take one measurement; run a MAPE-K cycle when one is due.

        The arguments are those of :meth:`MeasuredSystem.update`. A cycle runs
        when ``t`` has reached ``start_s + n·period_s`` for the next n (several
        overdue periods give one cycle, on the measurement at hand).

        Returns
        -------
        list of Command
            What the cycle decided (usually nothing); the same commands went to
            the callbacks and the queue first.

        Raises
        ------
        LiveError
            A measurement the system refuses (:meth:`MeasuredSystem.update`).
        """
        self.system.update(t, outputs, signals, health, configuration)
        self.measurements += 1
        due = self.start_s + self._cycles_due * self.period_s
        if self.system.t + self._eps < due:
            return []
        passed = math.floor((self.system.t - self.start_s + self._eps) / self.period_s)
        self._cycles_due = max(self._cycles_due, passed) + 1
        return self._cycle()

    # ------------------------------------------------------------------ cycle
    def _cycle(self) -> list[Command]:
        mapek = self.mapek
        n_updates = len(mapek.updates)
        switches = mapek(self.system)
        record = mapek.decisions[-1]
        self._annotate(record)
        for fn in self._cycle_callbacks:
            fn(record)
        out = [
            Command(float(s["t_s"]), "configuration", str(s["action"]), str(s["module"]),
                    str(s["to"]), str(s["from"]))
            for s in switches
        ]
        conf = self.system.configuration
        out += [
            Command(float(u["t_s"]), "parameters", str(u["action"]), str(u["module"]), conf,
                    conf, dict(u["set"]))
            for u in mapek.updates[n_updates:]
        ]
        for c in out:
            self.commands.put(c)
            for fn in self._callbacks:
                fn(c)
        return out

    def _annotate(self, record: Any) -> None:
        """Say in the cycle's record which methods gave Δ and stability (no snapshot)."""
        deltas: set[str] = set()
        stab: set[str] = set()
        for ev in record.evaluations:
            if ev.delta is not None:
                deltas.add(self._methods.get(ev.action, "?"))
            if ev.stability is not None:
                ev.stability["source"] = "models"
                method = str(ev.stability.get("method"))
                stab.add(_STABILITY_NAMES.get(method, method))
        parts = [f"{what} by {', '.join(sorted(got))}"
                 for what, got in (("Δ", deltas), ("stability", stab)) if got]
        if not parts:
            return
        note = "live (no plant snapshot): " + "; ".join(parts)
        record.note = f"{record.note}; {note}" if record.note else note
