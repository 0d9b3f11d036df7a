"""The live system: an architecture's configuration compiled and run as synchronous data flow.

:func:`compile_system` binds each module's nominal parameters, instantiates its type
through :mod:`archself.registry` and installs the scenario's faults
(:class:`FaultInjector`); :class:`LiveSystem` runs the active modules of one
configuration with the semantics of :mod:`archself.modules.base`:

1. modules with ``direct_feedthrough = False`` publish ``output(t)``;
2. the other modules ``step`` in topological order of the active edges, with
   the edges *into* non-feedthrough modules cut (an remaining cycle is an
   algebraic loop: :class:`~archself.errors.CompileError`);
3. the non-feedthrough modules ``step`` to advance their state to ``t + dt``.

It knows module *roles* and declared signals, never a module's name, so any
architecture file runs. Everything that can be precomputed (the order, the
routing of each input, edge delays and noise) is computed once per
configuration; the step loop touches plain dicts and lists only.

Design decisions
----------------
* **Hand-over.** On :meth:`LiveSystem.apply_configuration` every newly active
  module receives ``import_state(old.export_state())`` from the deactivated
  module with the same ``role`` (first in file order), e.g. odometry pose and
  covariance → EKF.
* **Persistence.** Module instances live in a pool for the whole run: a
  deactivated module keeps its state and resumes from it when reactivated (after
  the hand-over above, which refreshes what a successor can give it). Module
  types that should not carry stale state reset it in ``import_state``.
* **Robustness.** A module that raises, or publishes a non-finite number, is
  marked unavailable for that step and its last good outputs are held; a module
  whose required input is ``None`` is marked unavailable too (it still runs and
  must tolerate it). A module whose last value was NaN stays unavailable until
  it publishes a good one (a GPS between fixes gives ``None``, not news). Two
  checks need a declaration by the module type: a module with ``max_silence_s``
  (a GPS receiver: a few fix periods) that has published no value for longer
  than that is *silent* (a dropout), and a signal with a declared noise level
  (``noise_levels``, > 0) that repeats the same value ``STALE_REPEATS`` times in
  a row is *stale* (a frozen sensor: real noise never repeats bit for bit).
  :meth:`LiveSystem.health` gives the reason of each unavailable module and
  :meth:`LiveSystem.dependencies` the modules each module of a configuration
  cannot run without.
* **Edges.** ``uncertainty`` adds zero-mean Gaussian noise (own random stream per
  edge) to numeric values; ``latency_s`` delays the value by
  ``round(latency_s / dt)`` steps (``None`` until the line fills).
* **Randomness.** Each module gets ``numpy.random.default_rng([seed,
  stable_hash(name)])``; edges and faults get their own streams the same way.
* **Plans.** :func:`build_plan` computes, once per configuration, the active modules in
  file order, the step order (:func:`archself.system.dataflow.topological_order`), the
  routing of every input (source, edge, noise, delay, the source's output a renamed
  port reads) and the required inputs; :class:`StepPlan` holds it, immutable, with its
  restriction to a partial copy (:meth:`LiveSystem.snapshot`) and its closed loop.

Faults
------
A fault of a scenario (``scenarios.<s>.faults[*]``) transforms one output signal
of one module between ``onset_s`` and ``end_s`` (default: forever). The
transformation knows nothing about the module; it acts on floats and numpy
arrays (every component of a vector signal). ``None`` ("no value this step")
passes through unchanged.

==================  =====================================================
kind                value seen downstream
==================  =====================================================
bias_drift          ``y + magnitude · (t − onset)``
bias                ``y + magnitude``
effectiveness_loss  ``y · (1 − magnitude)``
noise_increase      ``y + n``, ``n ~ N(0, σ²)``: if the module declares its
                    nominal noise ``σ₀`` for the signal (``noise_levels``),
                    ``σ = σ₀ √(magnitude² − 1)`` so the total noise is
                    ``magnitude · σ₀``; otherwise ``σ = magnitude`` (absolute)
dropout             ``None``
stuck               the first value at or after onset, held (steps where the
                    module gives ``None`` stay ``None``)
nan                 NaN (every component of a vector); ``None`` stays ``None``
==================  =====================================================

Examples
--------
>>> from archself.system.live import compile_system
>>> from ruamel.yaml import YAML
>>> from archself.model.architecture import Architecture
>>> from archself.resources import data_dir
>>> raw = YAML(typ="safe").load(data_dir("architectures") / "diffdrive.yaml")
>>> arch = Architecture.model_validate(raw)
>>> sys_ = compile_system(arch, "a1", seed=1, scenario="nominal")
>>> sys_.step(); round(sys_.t, 2)
0.05
>>> f = FaultInjector("bias_drift", onset_s=10.0, magnitude=0.1)
>>> f.apply(5.0, 1.0), round(f.apply(20.0, 1.0), 6)
(1.0, 2.0)
>>> FaultInjector("effectiveness_loss", onset_s=0.0, magnitude=0.2).apply(1.0, 5.0)
4.0
"""

from __future__ import annotations

import copy
import hashlib
import heapq
import math
from collections import deque
from collections.abc import Callable, Collection, Mapping
from functools import lru_cache, partial
from typing import Any, Self

import numpy as np

from archself import registry
from archself.errors import ArchselfError, CompileError, SimulationError
from archself.linear.assembly import Wire
from archself.model.architecture import Architecture, Scenario
from archself.modules.base import RuntimeModule
from archself.system.dataflow import algebraic_loop, topological_order
from archself.system.linearizing import Linearizing

__all__ = ["FAULT_KINDS", "FaultInjector", "LiveSystem", "NOT_NUMERIC", "STALE_REPEATS",
           "StepPlan", "build_module", "build_plan", "compile_system", "component_error",
           "declared_limits", "default_signal", "is_bad", "module_rng", "needs_checks",
           "objective_norm", "publish_checks", "stable_hash"]


# ---------------------------------------------------------------- random streams


def stable_hash(text: str) -> int:
    """A 64-bit hash of ``text`` that is the same in every process (unlike ``hash``).

    Examples
    --------
    >>> stable_hash("imu") == stable_hash("imu")
    True
    """
    return int.from_bytes(hashlib.blake2b(text.encode("utf-8"), digest_size=8).digest(), "little")


def module_rng(seed: int, name: str) -> np.random.Generator:
    """The deterministic random stream of module (or edge, fault) ``name`` for ``seed``."""
    return np.random.default_rng([int(seed), stable_hash(name)])


# ---------------------------------------------------------------- the objective (Eq. 11)


def component_error(actual: Any, reference: Any, components: list[int]) -> np.ndarray:
    """``actual[c] − reference[c]`` for the objective components (a scalar is a 1-vector).

    Components a signal does not have, and values that are not numbers, give NaN.

    Examples
    --------
    >>> component_error([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [0, 1]).tolist()
    [1.0, 2.0]
    >>> component_error(2.0, 0.5, [0]).tolist()
    [1.5]
    """
    try:
        a = np.asarray(actual, dtype=float).reshape(-1)  # a scalar is a 1-vector
        r = np.asarray(reference, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return np.full(len(components), np.nan)
    out = np.full(len(components), np.nan)
    for k, c in enumerate(components):
        if -a.size <= c < a.size and -r.size <= c < r.size:
            out[k] = a[c] - r[c]
    return out


def objective_norm(actual: Any, reference: Any, components: list[int]) -> float:
    """J = ‖actual[c] − reference[c]‖ over the objective components (NaN when unknown).

    The norm is ``sqrt(Σ d²)`` summed in component order, on floats: the per-step
    series J of a run and J_obs of the MAPE-K loop come from this one function, so
    they agree to the last bit.

    Examples
    --------
    >>> objective_norm([3.0, 4.0, 9.0], [0.0, 0.0, 0.0], [0, 1])
    5.0
    >>> objective_norm(None, [0.0], [0])
    nan
    """
    if actual is None or reference is None:
        return math.nan
    if type(actual) is np.ndarray and type(reference) is np.ndarray:  # the common case
        al, rl = actual.tolist(), reference.tolist()
        if type(al) is list and type(rl) is list:
            try:
                s2 = 0.0
                for c in components:
                    d = al[c] - rl[c]
                    s2 += d * d
                return math.sqrt(s2)
            except (IndexError, TypeError):
                pass
    s2 = 0.0
    for d in component_error(actual, reference, components).tolist():
        s2 += d * d
    return math.sqrt(s2)


# ---------------------------------------------------------------- faults


FAULT_KINDS = frozenset(
    {"bias_drift", "bias", "effectiveness_loss", "noise_increase", "dropout", "stuck", "nan"}
)


def default_signal(module: Any) -> str | None:
    """The signal a fault without ``signal`` acts on: ``module.main_output`` or ``outputs[0]``."""
    main = getattr(module, "main_output", None)
    if main:
        return str(main)
    outs = getattr(module, "outputs", ())
    return outs[0] if outs else None


class FaultInjector:
    """One fault acting on one output signal.

    Parameters
    ----------
    kind : str
        One of :data:`FAULT_KINDS`.
    onset_s : float
        Start of the fault (s).
    magnitude : float
        Size of the fault (units depend on ``kind``).
    end_s : float, optional
        When the fault clears (default never).
    signal : str, optional
        The output signal it acts on (informational; the system routes it).
    rng : numpy.random.Generator, optional
        Noise source for ``noise_increase``.
    base_noise : float, optional
        Nominal noise standard deviation of the signal, if the module declares it.
    """

    def __init__(
        self,
        kind: str,
        onset_s: float,
        magnitude: float = 0.0,
        end_s: float | None = None,
        signal: str | None = None,
        rng: np.random.Generator | None = None,
        base_noise: float | None = None,
    ) -> None:
        if kind not in FAULT_KINDS:
            raise ValueError(
                f"unknown fault kind {kind!r}; known: {', '.join(sorted(FAULT_KINDS))}"
            )
        self.kind = kind
        self.onset = float(onset_s)
        self.end = math.inf if end_s is None else float(end_s)
        self.magnitude = float(magnitude)
        self.signal = signal
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.sigma = 0.0  # of the added noise (noise_increase)
        if kind == "noise_increase":
            self.sigma = (base_noise * math.sqrt(max(self.magnitude**2 - 1.0, 0.0))
                          if base_noise is not None and base_noise > 0 else abs(self.magnitude))
        self.held: Any = None

    def active(self, t: float) -> bool:
        """Whether the fault acts at time ``t``."""
        return self.onset <= t + 1e-9 and t < self.end - 1e-9

    def apply(self, t: float, value: Any) -> Any:
        """The faulty version of ``value`` at time ``t``."""
        if not self.active(t):
            self.held = None
            return value
        kind = self.kind
        if kind == "dropout" or value is None:
            return None
        if kind == "bias_drift":
            return value + self.magnitude * (t - self.onset)
        if kind == "bias":
            return value + self.magnitude
        if kind == "effectiveness_loss":
            return value * (1.0 - self.magnitude)
        if kind == "nan":
            if isinstance(value, np.ndarray):
                return np.full(value.shape, math.nan)
            return math.nan
        if kind == "noise_increase":
            if isinstance(value, np.ndarray):
                return value + self.sigma * self.rng.standard_normal(value.shape)
            return value + self.sigma * float(self.rng.standard_normal())
        # stuck
        if self.held is None:
            self.held = value.copy() if isinstance(value, np.ndarray) else value
        return self.held.copy() if isinstance(self.held, np.ndarray) else self.held


# ---------------------------------------------------------------- health


_isfinite = math.isfinite
NOT_NUMERIC: frozenset[type] = frozenset({str, bool, type(None)})  # never numbers

#: A noisy signal repeating the same value this many times in a row is stale.
STALE_REPEATS = 3


def is_bad(value: Any) -> bool:
    """True for a non-finite float or an array with a non-finite entry."""
    tp = type(value)
    if tp is float:
        return not math.isfinite(value)
    if tp is np.ndarray:
        if value.dtype.kind != "f":
            return False
        flat = value.tolist() if value.ndim == 1 else value.ravel().tolist()
        return not math.isfinite(sum(flat))
    if isinstance(value, (float, np.floating)):
        return not math.isfinite(float(value))
    return False


def declared_limits(module: RuntimeModule) -> tuple[Any, Any]:
    """``(max_silence_s, noise_levels)`` of ``module``: what its silence and stale checks need."""
    return getattr(module, "max_silence_s", None), getattr(module, "noise_levels", None)


def needs_checks(module: RuntimeModule, faults: Any = None) -> bool:
    """Whether the executor checks what ``module`` publishes (:func:`_health_lines`).

    False only when nothing there can fail: the type declares ``finite_outputs``
    (:class:`~archself.modules.base.RuntimeModule`: finite inputs give finite outputs),
    no fault is injected into its outputs, and it declares neither a silence limit
    (``max_silence_s``) nor noise levels (``noise_levels``). A type that declares
    nothing keeps every check. Raising and lost inputs are checked for every module.
    """
    return bool(
        faults
        or not getattr(type(module), "finite_outputs", False)
        or getattr(module, "max_silence_s", None) is not None
        or getattr(module, "noise_levels", None)
    )


def publish_checks(module: RuntimeModule, name: str, faults: Any = None
                   ) -> tuple[bool, Any, tuple[tuple[str, tuple[str, str], Any], ...]]:
    """What the step checks of what ``module`` (named ``name``) publishes, once per bind.

    ``(scan, max_silence_s, stale)``: ``scan`` the NaN/inf scan of every output (a type
    without ``finite_outputs``, or a fault on its outputs); ``stale`` one
    ``(signal, (name, signal), level)`` per declared noise level (the repeat counts).
    """
    limit, levels = declared_limits(module)
    scan = bool(faults) or not getattr(type(module), "finite_outputs", False)
    return scan, limit, tuple((sig, (name, sig), lv) for sig, lv in (levels or {}).items())


def _module_checks(module: RuntimeModule, name: str, faults: Any) -> tuple[Any, ...] | None:
    """What the generated step checks of ``module``'s publishing (:func:`_health_lines`):
    None (nothing, :func:`needs_checks`) or ``(scan, faulted, max_silence_s, stale)``."""
    if not needs_checks(module, faults):
        return None
    scan, limit, stale = publish_checks(module, name, faults)
    return scan, bool(faults), limit, stale


# ---------------------------------------------------------------- the step plan


class StepPlan:
    """Precomputed execution plan of one configuration (immutable)."""

    def __init__(
        self,
        name: str,
        active: list[str],
        nonft: list[str],
        order: list[str],
        routes: dict[str, list[tuple[str, str, int, float, int]]],
        required: dict[str, tuple[str, ...]],
        edges: list[int],
        multi: dict[str, frozenset[str]],
        reads: dict[int, str],
    ) -> None:
        self.name = name
        self.active = active
        self.active_set = frozenset(active)
        self.nonft = nonft
        self.order = order
        self.routes = routes
        self.required = required
        self.edges = edges
        # edge index -> the source's output it reads, where the target's input port is
        # named otherwise (archself.model.architecture: routes are keyed by the target's port)
        self.reads = reads
        # (module, whether it steps) of the publishing phases of a step
        self.publishing = [(n, False) for n in nonft] + [(n, True) for n in order]
        # (signal, source) pairs of the modules whose inputs pass unchanged (no edge
        # latency, noise or renamed port): the step gathers them without the general path
        self.direct: dict[str, tuple[tuple[str, str], ...] | None] = {
            n: None
            if n in multi or any(unc or delay or i in reads for _, _, i, unc, delay in r)
            else tuple((carries, src) for carries, src, *_ in r)
            for n, r in routes.items()
        }
        # module -> its inputs that collect a list, one value per active edge
        self.multi = multi
        self.nonft_set = frozenset(nonft)
        # some module type overrides linear_model or linearization (set by the system)
        self.linearizable = True
        self._wires: list[Wire] | None = None
        # what is checked of each module's publishing -> the step function (LiveSystem._bind)
        self.step_functions: dict[tuple[Any, ...], Callable[..., None]] = {}

    def wires(self) -> list[Wire]:
        """The active edges as :class:`~archself.linear.wiring.Wire` s (made once)."""
        if self._wires is None:
            self._wires = [
                Wire(src, n, carries, delay)
                for n in self.active
                for carries, src, _i, _unc, delay in self.routes[n]
            ]
        return self._wires

    def restricted(self, keep: Collection[str]) -> StepPlan:
        """The plan of the modules ``keep`` alone (file order and step order kept)."""
        active = [n for n in self.active if n in keep]
        plan = StepPlan(
            self.name,
            active,
            [n for n in self.nonft if n in keep],
            [n for n in self.order if n in keep],
            {n: self.routes[n] for n in active},
            {n: self.required[n] for n in active},
            sorted(r[2] for n in active for r in self.routes[n]),
            {n: v for n, v in self.multi.items() if n in keep},
            self.reads,
        )
        plan.linearizable = self.linearizable
        return plan

    def reach(self, starts: Collection[str], steps: int) -> set[str]:
        """The active modules whose outputs reach ``starts`` within ``steps`` steps.

        Upstream along the routes: an edge into a module without direct
        feedthrough takes a step, a latency its steps, an edge into a feedthrough
        module none (Dijkstra over these step counts).
        """
        dist = {m: 0 for m in starts if m in self.active_set}
        heap = [(0, m) for m in dist]
        nonft = self.nonft_set
        routes = self.routes
        while heap:
            d, m = heapq.heappop(heap)
            if d > dist[m]:
                continue
            hop = d + (1 if m in nonft else 0)
            for _carries, src, _i, _unc, delay in routes[m]:
                nd = hop + delay
                if nd <= steps and nd < dist.get(src, steps + 1):
                    dist[src] = nd
                    heapq.heappush(heap, (nd, src))
        return set(dist)


def build_plan(
    arch: Architecture,
    configuration: str,
    module: Callable[[str], RuntimeModule],
    dt: float,
) -> StepPlan:
    """The plan of ``configuration``; ``module(name)`` gives the (pooled) module instance.

    Raises
    ------
    CompileError
        If the configuration is unknown, names unknown modules or has an algebraic loop.
    """
    conf = arch.configurations.get(configuration)
    if conf is None:
        known = ", ".join(arch.configurations)
        raise CompileError(f"unknown configuration {configuration!r}; known: {known}")
    missing = [m for m in conf.modules if m not in arch.modules]
    if missing:
        raise CompileError(
            f"configuration {configuration!r} names unknown modules: {', '.join(missing)}"
        )
    index = {n: i for i, n in enumerate(arch.modules)}
    active = sorted(set(conf.modules), key=index.__getitem__)
    act = set(active)
    disabled = {tuple(e) for e in conf.disabled_edges}
    classes = {n: type(module(n)) for n in active}
    nonft = [n for n in active if not classes[n].direct_feedthrough]
    nonft_set = set(nonft)
    routes: dict[str, list[tuple[str, str, int, float, int]]] = {n: [] for n in active}
    flow: list[tuple[str, str]] = []  # the data flow of a step: edges into feedthrough
    edges: list[int] = []
    reads: dict[int, str] = {}
    ports = arch.edge_ports  # named ports: archself.model.architecture
    for i, e in enumerate(arch.edges):
        if e.source not in act or e.target not in act or (e.source, e.target) in disabled:
            continue
        edges.append(i)
        if ports.to_port[i] not in (None, e.carries):  # read as the source's output
            reads[i] = e.carries
        delay = int(round(e.latency_s / dt)) if e.latency_s > 0 else 0
        routes[e.target].append((ports.into(i), e.source, i, float(e.uncertainty), delay))
        if e.target not in nonft_set:
            flow.append((e.source, e.target))
    loop = algebraic_loop(flow)
    if loop is not None:
        path = " -> ".join([*loop, loop[0]])
        raise CompileError(
            f"configuration {configuration!r} has an algebraic loop: {path} "
            "(a loop needs a module with direct_feedthrough = False)"
        )
    order = [n for n in topological_order(active, flow, index) if n not in nonft_set]
    required = {n: tuple(classes[n].inputs) for n in active}
    multi = {n: frozenset(classes[n].multi_inputs) for n in active if classes[n].multi_inputs}
    plan = StepPlan(configuration, active, nonft, order, routes, required, edges, multi, reads)
    plan.linearizable = any(
        cls.linear_model is not RuntimeModule.linear_model
        or cls.linearization is not RuntimeModule.linearization
        for cls in set(classes.values())
    )
    return plan


def _input_lines(k: int, direct: tuple[tuple[str, str], ...] | None, name: str,
                 held: dict[str, str]) -> tuple[list[str], dict[str, str]]:
    """Lines of a generated step that gather a module's inputs; ``carries -> local``.

    Direct inputs become local variables (the first source of a signal, then a later
    one's value where it is not None, as :meth:`LiveSystem._gather`), read from the
    source's outputs as this step holds them (``held``: module -> local, set where it
    published); the others come from ``gather``.
    """
    if direct is None:
        return [f"    inputs = gather({name!r})"], {}
    lines: list[str] = []
    local: dict[str, str] = {}
    for j, (carries, src) in enumerate(direct):
        value = (f"{held[src]}.get({carries!r})" if src in held
                 else f"(outs.get({src!r}) or _EMPTY).get({carries!r})")
        if carries not in local:
            local[carries] = f"v{k}_{j}"
            lines.append(f"    {local[carries]} = {value}")
        else:
            lines += [f"    _v = {value}", "    if _v is not None:",
                      f"        {local[carries]} = _v"]
    items = ", ".join(f"{c!r}: {v}" for c, v in local.items())
    return [*lines, f"    inputs = {{{items}}}"], local


def _lost_tests(required: tuple[str, ...], local: dict[str, str] | None
                ) -> list[tuple[str, str]]:
    """``(condition, signal)`` per required input, in order, up to one that is never routed."""
    tests = []
    for s in required:
        if local is None:
            tests.append((f"inputs.get({s!r}) is None", s))
        elif s in local:
            tests.append((f"{local[s]} is None", s))
        else:
            tests.append(("True", s))
            break
    return tests


def _literal(x: float) -> str:
    """``x`` as Python source (``float('inf')`` and ``float('nan')`` too)."""
    return repr(x) if math.isfinite(x) else f"float({str(x)!r})"


def _health_lines(k: int, name: str, scan: bool, faulted: bool, limit: Any,
                  stale: tuple[tuple[str, tuple[str, str], Any], ...]) -> list[str]:
    """Lines of a generated step that publish what module ``k`` (``name``) returned (``out``)
    into ``o<k>`` and check it; the reason it is unavailable into ``r`` (None: available).

    In order: the scenario's faults on its outputs (``faulted``: the injectors in
    ``inj[k]``); the NaN/inf ``scan`` (:meth:`LiveSystem._scan`; a non-finite value is
    not published, the last good outputs are held, and the module is broken until a
    good value comes); silence longer than ``limit`` (``max_silence_s``); the repeats of
    its noisy signals ``stale`` (of :func:`publish_checks`: each counted, the first that
    repeated :data:`STALE_REPEATS` times gives the reason). Indented for the ``try`` of
    its call.
    """
    lines = ["        if out is None:", "            out = {}"]
    if faulted:
        lines += ["        out = dict(out)", f"        for _s, _inj in inj[{k}]:",
                  "            if _s in out:", "                out[_s] = _inj.apply(t, out[_s])"]
    if scan:
        lines += ["        _h = scan(out)", "        if _h is None:",
                  f"            broken.add({name!r})", "            r = 'non-finite output'",
                  f"            o{k} = outs.get({name!r}) or _EMPTY", "        else:",
                  f"            outs[{name!r}] = o{k} = out", "            r = None",
                  "            if _h:", f"                heard[{name!r}] = t",
                  "                if broken:", f"                    broken.discard({name!r})",
                  f"            elif {name!r} in broken:",
                  "                r = 'non-finite output'"]
    else:
        lines += [f"        outs[{name!r}] = o{k} = out", "        r = None",
                  "        for _v in out.values():", "            if _v is not None:",
                  f"                heard[{name!r}] = t", "                if broken:",
                  f"                    broken.discard({name!r})", "                break",
                  "        else:", f"            if {name!r} in broken:",
                  "                r = 'non-finite output'"]
    if limit is not None:  # (quiet is 0 when heard now)
        lines += ["        if r is None:", f"            _q = t - heard.setdefault({name!r}, t)",
                  f"            if _q > {_literal(float(limit) + 1e-9)}:",
                  '                r = f"silent for {_q:.3g} s"']
    if stale:  # a signal without a value this step keeps its count (and stays stale)
        lines.append("        if r is None:")
    for i, (sig, key, level) in enumerate(stale):
        lines.append(f"            _v = o{k}.get({sig!r})")
        if level and level > 0:
            lines += ["            if _v is None:", f"                _n = repeats.get({key!r}, 0)",
                      "            else:",
                      "                _c = _v.tobytes() if type(_v) is _nd else _v",
                      f"                _n = repeats[{key!r}] = (repeats.get({key!r}, 0) + 1"
                      f" if last.get({key!r}) == _c else 0)",
                      f"                last[{key!r}] = _c"]
        else:
            lines.append(f"            _n = repeats.get({key!r}, 0)")
        lines += [f"            if _n >= {STALE_REPEATS}{' and r is None' if i else ''}:",
                  f"                r = {'stale ' + sig + ' ('!r} + str(_n + 1)"
                  " + ' identical values)'"]
    return lines


def _publishing_lines(k: int, name: str, direct: tuple[tuple[str, str], ...] | None,
                      stepped: bool, required: tuple[str, ...], checks: Any,
                      held: dict[str, str]) -> list[str]:
    """Lines of a generated step for module ``k`` of phases 1 and 2 (output or step, publish,
    lost inputs, health), as :meth:`LiveSystem.step` documents them; its outputs as
    published (or held) go into the local ``o<k>``, recorded in ``held``. ``checks``: None
    (nothing to check) or the ``(scan, faulted, limit, stale)`` of :func:`_health_lines`."""
    lines, local = _input_lines(k, direct, name, held) if stepped else ([], {})
    held[name] = f"o{k}"
    call = f"m[{k}].step(t, dt, inputs)" if stepped else f"m[{k}].output(t)"
    lines += ["    try:", f"        out = {call}"]
    if checks is not None:
        lines += [*_health_lines(k, name, *checks),
                  "    except Exception as exc:", '        r = f"raised {type(exc).__name__}"',
                  f"        o{k} = outs.get({name!r}) or _EMPTY"]
    else:
        lines += ["    except Exception as exc:", '        r = f"raised {type(exc).__name__}"',
                  f"        o{k} = outs.get({name!r}) or _EMPTY",
                  "    else:", f"        outs[{name!r}] = o{k} = {{}} if out is None else out",
                  "        r = None"]
    tests = _lost_tests(required, local if direct is not None else None)
    if tests:
        lines.append("    if r is None:")
        for i, (cond, s) in enumerate(tests):
            lines += [f"        {'el' if i else ''}if {cond}:",
                      f"            r = {'lost input ' + s!r}"]
    return lines + ["    if r is None:", f"        ok[{name!r}] = True", "        if why:",
                    f"            why.pop({name!r}, None)", "    else:",
                    f"        ok[{name!r}] = False", f"        why[{name!r}] = r"]


def _advancing_lines(k: int, name: str, direct: tuple[tuple[str, str], ...] | None,
                     required: tuple[str, ...], held: dict[str, str]) -> list[str]:
    """Lines of a generated step for state-only module ``k`` of phase 3 (advance to t + dt)."""
    lines, local = _input_lines(k, direct, name, held)
    lines += ["    try:", f"        m[{k}].step(t, dt, inputs)", "    except Exception as exc:",
              f"        ok[{name!r}] = False",
              f'        why[{name!r}] = f"raised {{type(exc).__name__}}"']
    tests = _lost_tests(required, local if direct is not None else None)
    if tests:
        lines += ["    else:", f"        if ok[{name!r}]:"]
        for i, (cond, s) in enumerate(tests):
            lines += [f"            {'el' if i else ''}if {cond}:",
                      f"                ok[{name!r}] = False",
                      f"                why[{name!r}] = {'lost input ' + s!r}"]
    return lines


#: what a generated step reads of its system, by the name its lines use
_STEP_READS = {"gather": "_gather", "scan": "_scan", "heard": "_heard", "broken": "_broken",
               "last": "_last", "repeats": "_repeats"}


@lru_cache(maxsize=256)
def _step_function(body: str, reads: tuple[str, ...]) -> Callable[..., None]:
    """The function ``_step(outs, ok, why, system, t, dt, m, inj)`` of ``body`` (lines
    of :func:`_publishing_lines` and :func:`_advancing_lines`) that first reads ``reads``
    (names of :data:`_STEP_READS`) of ``system``; compiled once per text: systems and
    their copies with the same plan share it."""
    space: dict[str, Any] = {"_EMPTY": {}, "_nd": np.ndarray}
    src = "".join(["def _step(outs, ok, why, system, t, dt, m, inj):\n",
                   *(f"    {r} = system.{_STEP_READS[r]}\n" for r in reads), body])
    exec(compile(src, "<step plan>", "exec"), space)  # noqa: S102 - source built here
    return space["_step"]


class LiveSystem(Linearizing):
    """A running configuration of an architecture (the compiler → runtime contract).

    Build it with :func:`archself.system.live.compile_system`; see
    ``docs/develop.md`` for the contract table.

    Parameters
    ----------
    arch : Architecture
        The architecture.
    configuration : str
        The active configuration.
    factory : callable
        ``factory(name) -> RuntimeModule``: instantiates a module with its
        nominal parameters and own random stream.
    seed : int
        Seed of the edge noise streams.
    faults : dict, optional
        module name -> list of ``(signal, injector)`` from
        :mod:`archself.system.live`; applied while the module is active.
    """

    def __init__(
        self,
        arch: Architecture,
        configuration: str,
        factory: Callable[[str], RuntimeModule],
        *,
        seed: int = 0,
        faults: dict[str, list[tuple[str, Any]]] | None = None,
    ) -> None:
        self.arch = arch
        self.seed = int(seed)
        self.dt = float(arch.runtime.step_s)
        self.t = 0.0
        self.k = 0
        self._factory = factory
        self._pool: dict[str, RuntimeModule] = {}
        self._faults = faults or {}
        self._edge_rng: dict[int, np.random.Generator] = {}
        self._delay: dict[int, deque] = {}
        self._plans: dict[str, StepPlan] = {}
        self.outputs: dict[str, dict[str, Any]] = {}
        self._ok: dict[str, bool] = {}
        self._why: dict[str, str] = {}
        self._heard: dict[str, float] = {}  # module -> time of its last published value
        self._last: dict[tuple[str, str], Any] = {}  # (module, signal) -> last value
        self._repeats: dict[tuple[str, str], int] = {}
        self._broken: set[str] = set()  # modules whose last value was not finite
        # output types found not to be numbers (model objects): this system skips them
        self._not_numeric: set[type] = set(NOT_NUMERIC)
        self.history: list[dict[str, Any]] = []
        obj = arch.runtime.objective
        self._obj_actual = obj.actual
        self._obj_ref = obj.reference
        self._obj_comp = list(obj.components)
        self._scope: frozenset[str] | None = None  # a partial copy's modules (snapshot(only=))
        self._scoped: dict[str, StepPlan] = {}  # its plans, restricted to them
        self._plan = self._make_plan(configuration)  # instantiates the active modules
        # (plan, publishing ops, state-only ops) of the current plan (_bind); None: to make
        self._bound: tuple[StepPlan, Callable[..., None], list[Any], list[Any]] | None = None
        self.configuration = configuration

    # ------------------------------------------------------------------ plans
    def _module(self, name: str) -> RuntimeModule:
        mod = self._pool.get(name)
        if mod is None:
            if name not in self.arch.modules:
                raise SimulationError(f"unknown module {name!r}")
            mod = self._pool[name] = self._factory(name)
        return mod

    def _make_plan(self, configuration: str) -> StepPlan:
        plan = self._full_plan(configuration)
        if self._scope is None:
            return plan
        found = self._scoped.get(configuration)
        if found is None:
            found = self._scoped[configuration] = plan.restricted(self._scope)
        return found

    def _full_plan(self, configuration: str) -> StepPlan:
        plan = self._plans.get(configuration)
        if plan is None:
            plan = self._plans[configuration] = build_plan(
                self.arch, configuration, self._module, self.dt
            )
        return plan

    # ------------------------------------------------------------------ contract
    @property
    def active(self) -> set[str]:
        """Names of the active modules."""
        return set(self._plan.active)

    @property
    def modules(self) -> dict[str, RuntimeModule]:
        """Active modules by name (file order)."""
        return {n: self._pool[n] for n in self._plan.active}

    @property
    def execution_order(self) -> list[str]:
        """Order of one step: non-feedthrough outputs, then the feedthrough modules."""
        return list(self._plan.nonft) + list(self._plan.order)

    @property
    def active_edges(self) -> list[int]:
        """Indices into ``arch.edges`` of the edges active in this configuration."""
        return list(self._plan.edges)

    def _gather(self, name: str) -> dict[str, Any]:
        """Inputs of ``name`` whose routes need more than a read: latency, noise, a renamed
        port or a list input (the direct ones are read by the step function, :meth:`_bind`)."""
        outs = self.outputs
        inputs: dict[str, Any] = {}
        multi = self._plan.multi.get(name, ())
        reads = self._plan.reads
        for carries, src, idx, unc, delay in self._plan.routes[name]:
            src_out = outs.get(src)
            sig = reads.get(idx, carries) if reads else carries
            val = src_out.get(sig) if src_out is not None else None
            if delay:
                line = self._delay.get(idx)
                if line is None:
                    line = self._delay[idx] = deque([None] * delay)
                line.append(val)
                val = line.popleft()
            if unc and val is not None and isinstance(val, (float, int, np.ndarray)):
                rng = self._edge_rng.get(idx)
                if rng is None:
                    e = self.arch.edges[idx]
                    rng = self._edge_rng[idx] = module_rng(
                        self.seed, f"edge:{e.source}->{e.target}:{e.carries}"
                    )
                if isinstance(val, np.ndarray):
                    val = val + unc * rng.standard_normal(val.shape)
                else:
                    val = val + unc * float(rng.standard_normal())
            if carries in multi:
                inputs.setdefault(carries, []).append(val)
            elif val is not None or carries not in inputs:
                inputs[carries] = val
        return inputs

    def _bind(self, plan: StepPlan) -> tuple[Callable[..., None], list[Any], list[Any]]:
        """The step of ``plan`` on this system's modules: a straight-line function, its
        modules and their fault injectors.

        The function (:func:`_step_function`) makes each module's call in step order,
        reads its direct inputs into local variables, applies the faults and checks its
        publishing inline (:func:`_health_lines`) only where :func:`needs_checks` finds
        something to check (and only what :func:`publish_checks` finds), and tests its
        lost inputs inline; inputs that need the general path (latency, noise, renamed
        ports, list inputs) come from :meth:`_gather`. Bound once per plan and again when
        a module's parameters change (:meth:`set_params`); the plan keeps the function per
        set of checks, and copies with the same plan (or the same source text) share it.
        """
        pool = self._pool
        mods = [pool[n] for n, _ in plan.publishing] + [pool[n] for n in plan.nonft]
        faults = self._faults
        # per module: None (nothing to check) or (scan, faulted, max_silence_s, stale)
        checks = tuple(_module_checks(pool[n], n, faults.get(n)) for n, _ in plan.publishing)
        inj = [faults.get(n) for n, _ in plan.publishing]
        fn = plan.step_functions.get(checks)
        if fn is None:
            body: list[str] = []
            held: dict[str, str] = {}  # module -> the local holding its outputs this step
            for k, (n, stepped) in enumerate(plan.publishing):
                body += _publishing_lines(k, n, plan.direct[n] if stepped else (), stepped,
                                          plan.required[n] if stepped else (), checks[k], held)
            for k, n in enumerate(plan.nonft, start=len(plan.publishing)):
                body += _advancing_lines(k, n, plan.direct[n], plan.required[n], held)
            checked = [c for c in checks if c is not None]
            reads = (("gather",) * any(plan.direct[n] is None for n in plan.active)
                     + ("scan",) * any(c[0] for c in checked)
                     + ("heard", "broken", "last", "repeats") * bool(checked))
            fn = plan.step_functions[checks] = _step_function("\n".join(body or ["    pass"]),
                                                              reads)
        return fn, mods, inj

    def step(self) -> None:
        """Advance the system by one step ``dt`` (the plan's step function, :meth:`_bind`)."""
        plan = self._plan
        bound = self._bound
        if bound is None or bound[0] is not plan:
            bound = self._bound = (plan, *self._bind(plan))
        bound[1](self.outputs, self._ok, self._why, self, self.t, self.dt, bound[2], bound[3])
        self.k += 1
        self.t = self.k * self.dt

    def run(self, duration_s: float) -> None:
        """Step for ``duration_s`` seconds."""
        for _ in range(int(round(duration_s / self.dt))):
            self.step()

    def local_signals(self) -> dict[str, dict[str, float]]:
        """module -> signal -> value of the active modules' residual signals (Eq. 12)."""
        return {n: self._pool[n].local_signals() for n in self._plan.active}

    def available(self) -> dict[str, bool]:
        """module -> False when it raised, gave NaN, lost a required input, fell silent or
        stale in the last step."""
        return {n: self._ok.get(n, True) for n in self._plan.active}

    @property
    def unavailable(self) -> dict[str, str]:
        """module -> why it was unavailable in the last step, for the modules that were
        (the executor's own dict: read it, do not change it; may name a module the last
        hand-over deactivated)."""
        return self._why

    def health(self) -> dict[str, str | None]:
        """module -> why it is unavailable (None when available), for the active modules.

        Reasons: ``raised <Exception>``, ``non-finite output``, ``lost input <signal>``
        (an upstream failure, not the module's own), ``silent for <t> s``,
        ``stale <signal> (<n> identical values)``.
        """
        why = self._why
        return {n: (None if self._ok.get(n, True) else why.get(n)) for n in self._plan.active}

    def dependencies(self, configuration: str | None = None) -> dict[str, frozenset[str]]:
        """module -> the modules it cannot run without in ``configuration`` (default: active).

        A module depends on the providers of its required inputs (the type's
        ``inputs``) along the configuration's edges, and on the modules its
        ``constraints.requires`` names. Optional inputs create no dependency.
        """
        plan = self._make_plan(configuration or self.configuration)
        out: dict[str, frozenset[str]] = {}
        for n in plan.active:
            need = set(plan.required[n])
            deps = {src for carries, src, *_ in plan.routes[n] if carries in need}
            deps.update(
                m for m in self.arch.modules[n].constraints.requires if m in plan.active_set
            )
            deps.discard(n)
            out[n] = frozenset(deps)
        return out

    def signal(self, ref: str | tuple[str, str]) -> Any:
        """The current value of ``'module.signal'`` (None when not published)."""
        mod, sig = ref.rsplit(".", 1) if isinstance(ref, str) else ref
        out = self.outputs.get(mod)
        return None if out is None else out.get(sig)

    def state_error(self) -> np.ndarray:
        """``x − x_ref`` of the ``runtime.objective`` components (NaN when unknown, Eq. 22)."""
        return component_error(
            self.signal(self._obj_actual), self.signal(self._obj_ref), self._obj_comp
        )

    def objective_error(self) -> float:
        """J_obs: norm of :meth:`state_error` (NaN before the first step).

        The same number as the run's J series at this step (:func:`objective_norm`).
        """
        return objective_norm(
            self.signal(self._obj_actual), self.signal(self._obj_ref), self._obj_comp
        )

    # ------------------------------------------------------------------ changes
    def apply_configuration(self, name: str) -> None:
        """Hot swap to configuration ``name`` with state hand-over by role.

        Raises
        ------
        CompileError
            If the configuration is unknown or has an algebraic loop.
        """
        if name == self.configuration:
            return
        old = self._plan
        new = self._make_plan(name)
        gone = [n for n in old.active if n not in new.active_set]
        for n in new.active:
            if n in old.active_set:
                continue
            mod = self._module(n)
            for g in gone:
                prev = self._pool[g]
                if prev.role == mod.role:
                    mod.import_state(prev.export_state())
                    break
        for g in gone:
            self.outputs.pop(g, None)
            self._ok.pop(g, None)
            self._why.pop(g, None)
            self._heard.pop(g, None)
            self._broken.discard(g)
        self._plan = new
        self.history.append({"t_s": self.t, "from": old.name, "to": name})
        self.configuration = name

    def set_params(self, module: str, values: Mapping[str, Any]) -> None:
        """Apply a parameter update to ``module`` (instantiated if not yet used)."""
        self._module(module).set_params(dict(values))
        self._bound = None  # its noise levels or silence limit may have changed

    def pool(self) -> dict[str, RuntimeModule]:
        """Every module instantiated so far (active or not)."""
        return dict(self._pool)

    # ------------------------------------------------------------------ publishing and health
    def _scan(self, out: dict[str, Any]) -> bool | None:
        """None when a value of ``out`` is not finite, else whether it has a value (output
        types found not to be numbers are learnt and skipped)."""
        heard = False
        for v in out.values():
            if v is None:
                continue
            tp = type(v)
            if tp is float:  # inlined is_bad for the common types (a hot loop)
                bad = not _isfinite(v)
            elif tp is np.ndarray:
                bad = v.dtype.kind == "f" and not _isfinite(
                    sum(v.tolist() if v.ndim == 1 else v.ravel().tolist())
                )
            elif tp in self._not_numeric:  # model objects, strings: nothing to check
                bad = False
            else:
                bad = is_bad(v)
                if not bad and not isinstance(v, (float, int, np.number)):
                    self._not_numeric.add(tp)
            if bad:
                return None
            heard = True
        return heard

    # ------------------------------------------------------------------ snapshots
    def snapshot(self, only: Collection[str] | None = None) -> Self:
        """An independent deep copy (same RNG states, so a rollout is deterministic).

        With ``only``, a partial copy of those modules alone (with their outputs,
        health, faults and the edges into them): it steps them as the whole system
        would as long as what it is asked about depends on them only, e.g. the
        objective over a rollout when ``only`` is :meth:`rollout_scope`. Its
        ``modules``, ``available()``, ``dependencies()`` and the like answer for
        those modules; a module outside ``only`` that it is given an update for is
        created from the file and never stepped.
        """
        memo = {id(self.arch): self.arch, id(self._factory): self._factory}
        memo.update((id(p), p) for p in (*self._plans.values(), *self._scoped.values()))
        memo[id(self._bound)] = None  # the ops bind this system's modules: made again
        if only is None:
            return copy.deepcopy(self, memo)
        keep = frozenset(only) if self._scope is None else self._scope.intersection(only)
        edges = self.arch.edges
        per_module = {
            "_pool": {n: m for n, m in self._pool.items() if n in keep},
            "outputs": {n: v for n, v in self.outputs.items() if n in keep},
            "_ok": {n: v for n, v in self._ok.items() if n in keep},
            "_why": {n: v for n, v in self._why.items() if n in keep},
            "_heard": {n: v for n, v in self._heard.items() if n in keep},
            "_last": {k: v for k, v in self._last.items() if k[0] in keep},
            "_repeats": {k: v for k, v in self._repeats.items() if k[0] in keep},
            "_broken": self._broken & keep,
            "_faults": {n: v for n, v in self._faults.items() if n in keep},
            "_delay": {i: v for i, v in self._delay.items() if edges[i].target in keep},
            "_edge_rng": {i: v for i, v in self._edge_rng.items() if edges[i].target in keep},
            "_scoped": {},
            "_plan": None,
        }
        rest = {k: v for k, v in self.__dict__.items() if k not in per_module}
        part = object.__new__(type(self))
        rest, per_module = copy.deepcopy((rest, per_module), memo)
        part.__dict__.update(rest)
        part.__dict__.update(per_module)
        part._scope = keep
        part._plan = part._make_plan(self.configuration)
        return part

    def rollout_scope(self, configuration: str | None = None, steps: int = 0) -> frozenset[str]:
        """The modules a rollout of ``steps`` steps in ``configuration`` needs for the objective.

        Those whose outputs reach a ``runtime.objective`` signal within ``steps``
        steps along the configuration's edges (an edge into a module without
        direct feed-through takes a step, a latency its steps; an edge into a
        feed-through module none), and for each of them that a switch to
        ``configuration`` brings in, the module it would take its state from
        (hand-over by role). :meth:`snapshot` ``(only=…)`` of these gives the same
        objective error, step by step, as a copy of the whole system.
        """
        plan = self._full_plan(configuration or self.configuration)
        refs = (self._obj_actual, self._obj_ref)
        starts = {(r.rsplit(".", 1)[0] if isinstance(r, str) else r[0]) for r in refs}
        keep = plan.reach(starts, steps)
        current = self._plan
        if plan.name != current.name:
            gone = [g for g in current.active if g not in plan.active_set]
            for n in [n for n in keep if n not in current.active_set]:
                role = self._module(n).role
                giver = next((g for g in gone if self._pool[g].role == role), None)
                if giver is not None:
                    keep.add(giver)
        return frozenset(keep)


# ---------------------------------------------------------------- the compiler


def build_module(arch: Architecture, name: str, seed: int) -> RuntimeModule:
    """Instantiate module ``name`` with its nominal parameters and own random stream.

    Raises
    ------
    CompileError
        If the module is unknown or its type refuses the parameters.
    RegistryError
        If its type is not registered.
    """
    spec = arch.modules.get(name)
    if spec is None:
        raise CompileError(f"unknown module {name!r}")
    cls = registry.get(spec.type)
    try:
        params = {k: p.value for k, p in spec.params.items()}  # the nominal values
        return cls(name, params, module_rng(seed, name))
    except ArchselfError:
        raise
    except Exception as exc:
        raise CompileError(f"module {name!r} ({spec.type}) could not be built: {exc}") from exc


def compile_system(
    arch: Architecture,
    configuration: str | None = None,
    *,
    seed: int,
    scenario: str | Scenario | None = None,
) -> LiveSystem:
    """Build the live system of ``configuration`` with the faults of ``scenario``.

    Parameters
    ----------
    arch : Architecture
        A validated architecture.
    configuration : str, optional
        Configuration to start in (default: the file's initial one).
    seed : int
        Seed of every random stream (modules, edges, faults).
    scenario : str or Scenario, optional
        Scenario whose faults are installed (None: no faults).

    Returns
    -------
    LiveSystem

    Raises
    ------
    CompileError
        Unknown configuration or module, a fault on a module that does not
        accept its kind or lacks the signal, an algebraic loop.
    SimulationError
        Unknown scenario.
    """
    configuration = configuration or arch.initial_configuration()
    if configuration not in arch.configurations:
        known = ", ".join(arch.configurations)
        raise CompileError(f"unknown configuration {configuration!r}; known: {known}")
    factory = partial(build_module, arch, seed=int(seed))  # snapshots share it
    sc = arch.scenarios.get(scenario) if isinstance(scenario, str) else scenario
    if sc is None and scenario is not None:
        known = ", ".join(arch.scenarios) or "none"
        raise SimulationError(f"unknown scenario {scenario!r}; known: {known}")
    faults: dict[str, list[tuple[str, FaultInjector]]] = {}
    for i, f in enumerate(sc.faults if sc is not None else ()):
        if f.module not in arch.modules:
            raise CompileError(f"fault {i} targets unknown module {f.module!r}")
        cls = registry.get(arch.modules[f.module].type)
        if f.kind not in cls.fault_kinds:
            raise CompileError(
                f"fault {i}: module {f.module!r} ({cls.type_key}) does not take "
                f"{f.kind!r} faults (it takes: {', '.join(sorted(cls.fault_kinds)) or 'none'})"
            )
        probe = build_module(arch, f.module, seed)
        signal = f.signal or default_signal(probe)
        if signal is None or signal not in cls.outputs:
            raise CompileError(
                f"fault {i}: module {f.module!r} has no output {signal!r} "
                f"(outputs: {', '.join(cls.outputs)})"
            )
        base = (getattr(probe, "noise_levels", None) or {}).get(signal)
        inj = FaultInjector(
            f.kind,
            onset_s=f.onset_s,
            magnitude=f.magnitude,
            end_s=f.end_s,
            signal=signal,
            rng=module_rng(seed, f"fault:{f.module}:{i}"),
            base_noise=base,
        )
        faults.setdefault(f.module, []).append((signal, inj))
    return LiveSystem(arch, configuration, factory, seed=int(seed), faults=faults)
