"""The live-system contract over measurements a real plant pushes.

:class:`MeasuredSystem` is what the MAPE-K loop (:class:`archself.runtime.MapeK`)
talks to when the plant is real: it implements the live-system contract of
``docs/develop.md`` from the last measurements the plant gave
(:meth:`MeasuredSystem.update`) instead of from simulated modules. What the loop
reads (J_obs, the residual signals, availability, the operating limits' signals)
comes from the plant; what the loop would otherwise get from a copy of the
running system comes from the architecture's compiled modules, which are never
stepped (the *models*):

* ``linearization(configuration)`` and ``closed_loop`` are those of the compiled
  modules (their ``linear_model``/``linearization()``), at the measured signals
  (the pushed outputs stand in for the executor's outputs as operating points);
* ``dependencies(configuration)`` is structural (types and edges);
* ``snapshot()`` gives a :class:`ModelSnapshot`: a copy of the models on which a
  parameter update or a configuration can be tried and linearized, but which
  cannot be stepped (a rollout raises :class:`LiveError`), because a real plant
  cannot be copied.

Design decisions
----------------
* **The plant is the truth.** ``apply_configuration`` and ``set_params`` assume
  the plant does what it is told (the loop's Knowledge follows at once, as in
  simulation); a measurement that reports the plant's configuration overrides
  that assumption, so a command the plant refused or delayed is seen at the next
  push.
* **Models without state hand-over from the plant.** The compiled modules keep
  their nominal state (hand-overs between them happen as in simulation); only the
  measured outputs reach them. A model whose linearization depends on internal
  state (an operating point it tracks) is therefore linearized at its nominal
  state, or at the measured signals where it reads them from its input ports.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from archself.errors import ArchselfError
from archself.linear.closed_loop import ClosedLoop
from archself.model.architecture import Architecture
from archself.modules.base import RuntimeModule
from archself.system.live import compile_system, component_error, objective_norm

__all__ = ["LiveError", "MeasuredSystem", "ModelSnapshot", "NO_ROLLOUT"]

#: Why a live system cannot be stepped (the message of every refused rollout).
NO_ROLLOUT = (
    "live mode: no rollout (a real plant cannot be copied); "
    "Δ and stability come from the models"
)


class LiveError(ArchselfError):
    """Live mode was asked for something a real plant cannot give (one-line message)."""


def _number(v: Any, where: str) -> float:
    """A pushed number as a float (None: NaN); a string, a huge integer, ... refused, located."""
    if v is None:
        return math.nan
    if isinstance(v, (int, float, np.number)):
        try:
            return float(v)
        except OverflowError:  # an integer beyond a float's range
            digits = math.floor(math.log10(abs(int(v)))) + 1  # str() fails past 4,300 digits
            raise LiveError(f"{where}: expected a number, got an integer of {digits} digits "
                            "(beyond a float's range)") from None
    got = f"a string {v[:40]!r}" if isinstance(v, str) else f"{type(v).__name__}"
    raise LiveError(f"{where}: expected a number or null, got {got}")


def _value(v: Any, where: str) -> Any:
    """A pushed value as the executor would hold it: lists → float arrays, None kept.

    Numbers, booleans, None and (nested) lists of numbers or None are accepted, and
    objects pushed in-process (a model) are kept; a string, a mapping or a list
    holding either is a :class:`LiveError` naming ``where``.
    """
    if v is None or isinstance(v, bool):
        return v
    if isinstance(v, np.ndarray) and v.dtype.kind in "fiub":  # pushed in-process
        return v
    if isinstance(v, (list, tuple)):
        def flat(x: Any, at: str) -> Any:
            if isinstance(x, (list, tuple)):
                return [flat(y, f"{at}[{i}]") for i, y in enumerate(x)]
            return _number(x, at)

        try:
            return np.array(flat(v, where), dtype=float)
        except ValueError:  # ragged nesting
            raise LiveError(f"{where}: expected a number or a list of numbers of one "
                            "shape") from None
    if isinstance(v, (str, bytes, int, float, np.number, Mapping)):
        return _number(v, where)
    return v  # an object pushed in-process (a module's model), as the executor holds it


class MeasuredSystem:
    """A real plant as the MAPE-K loop sees it: pushed measurements plus compiled models.

    Parameters
    ----------
    arch : Architecture
        The architecture (validated).
    configuration : str, optional
        The configuration the plant starts in (default: the file's initial one).
    seed : int, optional
        Seed of the compiled models' random streams (they are never stepped; the
        seed matters only to module types that draw at construction).

    Attributes
    ----------
    t : float
        Time of the last measurement (s, the plant's clock).
    dt : float
        ``runtime.step_s``.
    configuration : str
        The configuration the loop believes active (the plant's when it reports it).
    outputs : dict
        module → signal → value of the last measurement (lists as float arrays).

    Examples
    --------
    >>> from archself.model.loader import load_architecture
    >>> from archself.resources import data_dir
    >>> arch = load_architecture(data_dir("architectures") / "process_plant.yaml").arch
    >>> s = MeasuredSystem(arch)
    >>> s.update(1.0, outputs={"tank": {"level": 1.02}, "setpoint": {"setpoint": [1.0, 0.0]}})
    >>> round(s.objective_error(), 6)
    0.02
    >>> s.linearization("p2").shape
    (2, 2)
    """

    def __init__(
        self, arch: Architecture, configuration: str | None = None, *, seed: int = 0,
        max_jump_s: float | None = None,
    ) -> None:
        self.arch = arch
        self.dt = float(arch.runtime.step_s)
        self.t = 0.0
        self.max_jump_s = max_jump_s
        self.measured = 0  # measurements taken
        self._models = compile_system(arch, configuration, seed=int(seed))
        self.configuration = self._models.configuration
        self.outputs: dict[str, dict[str, Any]] = {}
        self._signals: dict[str, dict[str, float]] = {}
        self._health: dict[str, str | None] = {}
        obj = arch.runtime.objective
        self._actual = obj.actual
        self._reference = obj.reference
        self._components = list(obj.components)
        self.history: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ measurements
    def update(
        self,
        t: float,
        outputs: Mapping[str, Mapping[str, Any]] | None = None,
        signals: Mapping[str, Mapping[str, Any]] | None = None,
        health: Mapping[str, str | None] | None = None,
        configuration: str | None = None,
    ) -> None:
        """Take one measurement of the plant.

        Parameters
        ----------
        t : float
            The plant's time (s).
        outputs : dict, optional
            module → signal → value (numbers or lists of numbers): at least the
            ``runtime.objective`` signals, and the signals operating limits are
            declared on. They replace the previous outputs of the modules given.
        signals : dict, optional
            module → residual signal → float (each module's ``residual.signal``,
            what ``local_signals()`` gives in simulation); replaces the previous
            signals of the modules given. None or a missing value is NaN.
        health : dict, optional
            module → None (available) or the reason it is unavailable (the
            reasons of ``LiveSystem.health``, e.g. ``"silent for 2 s"``); modules
            not given keep their last state (available at the start).
        configuration : str, optional
            The configuration the plant runs; adopted when it differs.

        Raises
        ------
        LiveError
            An unknown configuration; a value that is not a number (a string, an
            integer beyond a float's range; the message names the field, e.g.
            ``outputs.tank.level``); a time ``t`` that is not a finite number, goes
            back before the last measurement's, or jumps forward by more than
            :attr:`max_jump_s` (the first measurement's time is free). The
            measurement refused changes nothing.
        """
        t = self._checked_time(t)
        for what, value in (("outputs", outputs), ("signals", signals), ("health", health)):
            if value is not None and not isinstance(value, Mapping):
                raise LiveError(f"measurement {what} must be a mapping of modules")
            for m, sigs in (value or {}).items() if what != "health" else ():
                if sigs is not None and not isinstance(sigs, Mapping):
                    raise LiveError(f"measurement {what} of module {str(m)!r} must be a "
                                    "mapping of signals")
        if configuration is not None and not isinstance(configuration, str):
            raise LiveError(f"the plant reports configuration {configuration!r}, not a name")
        new_outputs = {str(m): {str(k): _value(v, f"outputs.{m}.{k}")
                                for k, v in (sigs or {}).items()}
                       for m, sigs in (outputs or {}).items()}
        new_signals = {str(m): {str(k): _number(v, f"signals.{m}.{k}")
                                for k, v in (sigs or {}).items()}
                       for m, sigs in (signals or {}).items()}
        if configuration is not None and configuration != self.configuration and (
                configuration not in self.arch.configurations):
            known = ", ".join(self.arch.configurations)
            raise LiveError(f"configuration: the plant reports unknown configuration "
                            f"{configuration!r}; known: {known}")
        self.t = t
        self.measured += 1
        self.outputs.update(new_outputs)
        self._signals.update(new_signals)
        for m, why in (health or {}).items():
            self._health[str(m)] = None if why is None else str(why)
        if configuration is not None and configuration != self.configuration:
            self._switch(configuration, by="plant")

    def _checked_time(self, t: Any) -> float:
        """The measurement's time as a float, refused if not finite, going back or jumping."""
        if isinstance(t, (str, bytes)):
            raise LiveError(f"t: measurement time {t[:40]!r} is not a number (a string)")
        try:
            t = float(t)
        except (TypeError, ValueError, OverflowError):
            what = "an integer beyond a float's range" if isinstance(t, int) else type(t).__name__
            raise LiveError(f"t: measurement time is not a number ({what})") from None
        if not math.isfinite(t):
            raise LiveError(f"t: measurement time {t!r} is not finite")
        if self.measured:
            if t < self.t:
                raise LiveError(f"t: measurement time {t:g} s goes back before the last "
                                f"one, {self.t:g} s (time must not decrease)")
            if self.max_jump_s is not None and t - self.t > self.max_jump_s:
                raise LiveError(f"t: measurement time {t:g} s jumps {t - self.t:g} s past the "
                                f"last one, {self.t:g} s (at most {self.max_jump_s:g} s)")
        return t

    def step(self) -> None:
        """Refused: the plant advances itself; measurements come by :meth:`update`.

        Raises
        ------
        LiveError
            Always.
        """
        raise LiveError(NO_ROLLOUT)

    # ------------------------------------------------------------------ contract
    @property
    def active(self) -> set[str]:
        """Modules of the current configuration."""
        return set(self.arch.configurations[self.configuration].modules)

    @property
    def modules(self) -> dict[str, RuntimeModule]:
        """The compiled models of the active modules (never stepped)."""
        return self._models.modules

    def local_signals(self) -> dict[str, dict[str, float]]:
        """module → residual signal → value of the active modules, as last pushed."""
        return {m: dict(self._signals.get(m, {})) for m in self.active}

    def available(self) -> dict[str, bool]:
        """module → False when the plant last reported a reason it is unavailable."""
        return {m: self._health.get(m) is None for m in self.active}

    def health(self) -> dict[str, str | None]:
        """module → the reason the plant gave for it being unavailable, or None."""
        return {m: self._health.get(m) for m in self.active}

    def dependencies(self, configuration: str | None = None) -> dict[str, frozenset[str]]:
        """module → modules it cannot run without in ``configuration`` (structural)."""
        return self._models.dependencies(configuration or self.configuration)

    def signal(self, ref: str | tuple[str, str]) -> Any:
        """The last pushed value of ``'module.signal'`` (None when not pushed)."""
        mod, sig = ref.rsplit(".", 1) if isinstance(ref, str) else ref
        return (self.outputs.get(mod) or {}).get(sig)

    def objective_error(self) -> float:
        """J_obs from the pushed objective signals (NaN when one is missing)."""
        return objective_norm(
            self.signal(self._actual), self.signal(self._reference),
            self._components,
        )

    def state_error(self) -> np.ndarray:
        """``x − x_ref`` of the objective components from the pushed signals (NaN if unknown)."""
        a, r = self.signal(self._actual), self.signal(self._reference)
        return component_error(a, r, self._components)

    # ------------------------------------------------------------------ models
    def _sync_models(self) -> None:
        self._models.outputs = {m: dict(v) for m, v in self.outputs.items()}

    def closed_loop(self, configuration: str | None = None) -> ClosedLoop:
        """The compiled models' closed loop of ``configuration`` at the measured signals."""
        self._sync_models()
        return self._models.closed_loop(configuration or self.configuration)

    def linearization(self, configuration: str | None = None) -> np.ndarray | None:
        """Closed-loop A (Eq. 20) of ``configuration`` from the compiled models, or None."""
        self._sync_models()
        return self._models.linearization(configuration or self.configuration)

    def snapshot(self, only: Any = None) -> ModelSnapshot:
        """A copy of the compiled models (no plant): linearizable, never stepped.

        ``only`` (the modules a partial rollout copy would hold) is accepted for
        the contract's sake and ignored: the copy is never stepped.
        """
        self._sync_models()
        return ModelSnapshot(self._models.snapshot())

    # ------------------------------------------------------------------ changes
    def _switch(self, name: str, by: str) -> None:
        self._models.apply_configuration(name)
        self.history.append({"t_s": self.t, "from": self.configuration, "to": name, "by": by})
        self.configuration = name

    def apply_configuration(self, name: str) -> None:
        """Record that the plant is told to run ``name`` (the models follow).

        Raises
        ------
        CompileError
            Unknown configuration (or one the models cannot be wired in).
        """
        if name != self.configuration:
            self._switch(name, by="loop")

    def set_params(self, module: str, values: Mapping[str, Any]) -> None:
        """Record a parameter update the plant is told to apply (the models follow)."""
        self._models.set_params(module, dict(values))


class ModelSnapshot:
    """A copy of the compiled models standing in for a snapshot of a real plant.

    It takes a configuration or a parameter update and gives the closed loop that
    results (:meth:`linearization`, :meth:`closed_loop`), which is what the
    eigenvalue test of the stability filter needs; everything that would need the
    plant's future (``step``, ``state_error``, ``objective_error``) raises
    :class:`LiveError`, so a rollout estimate or a Lyapunov test fails closed with
    :data:`NO_ROLLOUT` as its reason.
    """

    def __init__(self, models: Any) -> None:
        self._models = models
        self.dt = models.dt
        self.t = models.t

    @property
    def configuration(self) -> str:
        """The configuration the copy is in."""
        return str(self._models.configuration)

    def apply_configuration(self, name: str) -> None:
        """Move the copy to ``name``."""
        self._models.apply_configuration(name)

    def set_params(self, module: str, values: Mapping[str, Any]) -> None:
        """Apply a parameter update to the copy."""
        self._models.set_params(module, dict(values))

    def linearization(self, configuration: str | None = None) -> np.ndarray | None:
        """Closed-loop A of ``configuration`` (default: the copy's) from the models."""
        return self._models.linearization(configuration or self.configuration)

    def closed_loop(self, configuration: str | None = None) -> ClosedLoop:
        """The closed loop of ``configuration`` (default: the copy's) from the models."""
        return self._models.closed_loop(configuration or self.configuration)

    def step(self) -> None:
        """Refused (:data:`NO_ROLLOUT`)."""
        raise LiveError(NO_ROLLOUT)

    def state_error(self) -> np.ndarray:
        """Refused (:data:`NO_ROLLOUT`)."""
        raise LiveError(NO_ROLLOUT)

    def objective_error(self) -> float:
        """Refused (:data:`NO_ROLLOUT`)."""
        raise LiveError(NO_ROLLOUT)
