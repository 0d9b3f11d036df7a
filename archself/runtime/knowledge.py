"""The Knowledge of the MAPE-K loop: the live architecture graph a = (M, Γ).

:class:`Knowledge` holds a :class:`networkx.DiGraph` of *all* modules of the
architecture file (node attributes ``kind``, ``type``, ``active``, ``params``)
and of all edges (attributes ``weight``, ``carries``, ``active``), the name of
the current configuration, the parameter values changed at run time and
``t_last``, the time of the last architectural change (Eq. 28). It is kept in
step with the running system: :meth:`Knowledge.sync` reads the active modules
and configuration from the system after each executed action. The graph is
built when it is first asked for and its ``active`` flags are brought up to date
when it is read, not at every change: the loop itself works on the arrays and the
edge set (a switch in a 10^5-module graph would otherwise set 3·10^5 flags).

It also owns the index order of the influence vector and the weighted adjacency
matrix W of the *active* edges (Eq. 13), with the factorization of ``I − Wᵀ``
cached per active edge set (:class:`archself.runtime.influence.InfluenceSolver`).

The decision log of the MAPE-K loop and its human-readable rendering.

One :class:`DecisionRecord` per cycle holds what Algorithm 1 saw and decided:
the objective ``J_obs`` and global residual ``r`` (Eq. 11), the module residuals
``r_i`` (Eq. 12), the influence ``z`` (Eq. 14), the source estimate ``ê``
(:mod:`~archself.runtime.influence`) and which of the two drove the candidate set
(``runtime.localization``), the candidate set (Eq. 16), and
for every action evaluated its estimated improvement Δ (Eq. 18), its stability
verdict (Eq. 21/24), why it was rejected (``not applicable``, ``no change``,
``unavailable``, ``constraint``, ``budget``, ``limit``, ``dwell``, ``held back``,
``no improvement``, ``unstable``), with ``runtime.risk`` Δ's mean, spread and rule,
with ``runtime.learning`` the context's learned record, its score (Eq. 25) and the
action chosen (Eq. 26). Written as the pydantic model
:class:`~archself.io.jsondata.DecisionRecordDoc` (``record.to_dict()``; a log:
``MapeK.log()``): lists, strings, numbers and ``None`` for non-finite numbers.

:func:`~archself.runtime.explanation.explain` renders a log for a person asking "why
did it switch?".

Learning from outcomes: what an action did, measured, and remembered per context.

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

Online W and bands (``runtime.online``): the offline fits, run on the loop's own history.

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
from collections.abc import ItemsView, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from archself.contracts import ManagedSystem
from archself.errors import ArchselfError
from archself.io.files import read_text, write_text
from archself.io.jsondata import DecisionRecordDoc, EvaluationDoc, document, loads
from archself.io.trace import read_trace_parts
from archself.model.architecture import Architecture
from archself.model.architecture import Learning as LearningSettings
from archself.runtime.identify_fit import delta_residuals, fit_target
from archself.runtime.influence import DENSE_MAX, InfluenceSolver, spectral_radius, weight_matrix
from archself.runtime.tails import band_of_level, quantile_level

if TYPE_CHECKING:  # networkx (~0.1 s to import) only when the graph is asked for
    import networkx as nx
    import scipy.sparse

__all__ = [
    "ActionEvaluation",
    "DecisionRecord",
    "Knowledge",
    "Learning",
    "Online",
    "OutcomeTable",
    "ValueMap",
    "active_edges",
    "knowledge_summary",
    "learning_of",
    "load_table",
    "on_cycles",
    "online_of",
]

EdgeKey = tuple[str, str, str]  # (source, target, carries)


def active_edges(
    arch: Architecture, active: Iterable[str], disabled: Iterable[Iterable[str]] = ()
) -> frozenset[EdgeKey]:
    """Edges whose two ends are active and which the configuration does not switch off.

    Parameters
    ----------
    arch : Architecture
        The architecture.
    active : iterable of str
        Active module names.
    disabled : iterable of (source, target)
        The configuration's ``disabled_edges``.

    Returns
    -------
    frozenset of (source, target, carries)
    """
    on = set(active)
    off = {tuple(pair) for pair in disabled}
    return frozenset(
        (e.source, e.target, e.carries)
        for e in arch.edges
        if e.source in on and e.target in on and (e.source, e.target) not in off
    )


class Knowledge:
    """The live architecture graph, the current configuration and ``t_last``.

    Parameters
    ----------
    arch : Architecture
        The architecture file's model.
    configuration : str, optional
        The starting configuration (default: the one marked ``initial``).

    Attributes
    ----------
    graph : networkx.DiGraph
        All modules and edges; ``active`` flags follow the running system.
    names : list of str
        Module names in the index order of ``z``, ``r`` and ``W``.
    configuration : str
        Name of the current configuration.
    active : frozenset of str
        Active modules.
    active_index : numpy.ndarray of int
        Positions of the active modules in :attr:`names`, ascending.
    active_names : list of str
        The active modules in index order.
    active_pos : dict
        name -> position in :attr:`active_names`.
    edges : frozenset of (source, target, carries)
        Active edges.
    params : dict
        module -> {parameter: value}: current parameter values (nominal values
        updated by executed parameter updates).
    t_last : float
        Time of the last architectural change (−inf before the first).
    learned : OutcomeTable or None
        What the loop learned from its actions' outcomes (``runtime.learning``).
    online : list of dict or None
        Every update of W and of the bands (``runtime.online``), accepted or rejected.
    w_scale : float
        Factor applied to every weight so that ρ(W) ≤ ``runtime.max_spectral_radius``
        (1.0 when the file's weights already satisfy it).
    """

    def __init__(self, arch: Architecture, configuration: str | None = None) -> None:
        self.arch = arch
        self.names: list[str] = list(arch.modules)
        self.index = {n: k for k, n in enumerate(self.names)}
        self._graph: nx.DiGraph | None = None
        self._graph_state: tuple[str, frozenset[str]] | None = None  # what its flags show
        self.params: dict[str, dict[str, Any]] = {
            name: {p: spec.value for p, spec in mod.params.items()}
            for name, mod in arch.modules.items()
        }
        # every edge as (source, target, carries) and its ends' positions in names
        self._edge_keys = [(e.source, e.target, e.carries) for e in arch.edges]
        index = self.index
        self._edge_ends = np.array(
            [(index.get(e.source, -1), index.get(e.target, -1)) for e in arch.edges],
            dtype=np.intp,
        ).reshape(-1, 2)
        self._weights: dict[EdgeKey, float] = {}
        for e in arch.edges:
            key = (e.source, e.target, e.carries)
            self._weights[key] = self._weights.get(key, 0.0) + e.weight
        self.t_last = -math.inf
        self.learned: Any = None  # runtime.learning: the OutcomeTable (runtime/knowledge.py)
        self.online: Any = None  # runtime.online: its updates, accepted or rejected (events)
        self.solver = InfluenceSolver()
        # Normalize W so that ρ(W) stays below the declared bound (paper: "the
        # weights are normalized such that ρ(W) < 1"). W of any active subset is
        # entrywise ≤ W of all edges, so by Perron–Frobenius its ρ is no larger.
        full = weight_matrix(self.names, [(e.source, e.target, e.weight) for e in arch.edges],
                             dense_max=DENSE_MAX)
        self.rho_full = spectral_radius(full)
        bound = arch.runtime.max_spectral_radius
        self.w_scale = 1.0 if self.rho_full <= bound else bound / self.rho_full
        conf = configuration or arch.initial_configuration()
        self._set_active(conf, arch.configurations[conf].modules)

    # ------------------------------------------------------------------ state
    def _set_active(self, configuration: str, active: Iterable[str]) -> None:
        self.configuration = configuration
        self.active: frozenset[str] = frozenset(active)
        index = self.index
        on = np.zeros(len(self.names) + 1, dtype=bool)  # the last slot: unknown names
        on[[index[n] for n in self.active if n in index]] = True
        self.active_index = np.flatnonzero(on[:-1])
        self.active_names = [self.names[k] for k in self.active_index.tolist()]
        self.active_pos = {n: i for i, n in enumerate(self.active_names)}
        conf = self.arch.configurations.get(configuration)
        off = {tuple(pair) for pair in (conf.disabled_edges if conf is not None else [])}
        ends = self._edge_ends
        live = (on[ends[:, 0]] & on[ends[:, 1]]).tolist()
        keys = self._edge_keys
        self.edges: frozenset[EdgeKey] = frozenset(
            keys[i] for i, ok in enumerate(live) if ok and keys[i][:2] not in off
        )

    @property
    def graph(self) -> nx.DiGraph:
        """All modules and edges; ``active`` flags follow the running system."""
        g = self._graph
        if g is None:
            import networkx as nx

            g = self._graph = nx.DiGraph()
            for name, mod in self.arch.modules.items():
                # the params dict is Knowledge's own: it stays in step
                g.add_node(name, kind=mod.kind, type=mod.type, active=False,
                           params=self.params[name])
            for e in self.arch.edges:
                if g.has_edge(e.source, e.target):
                    data = g.edges[e.source, e.target]
                    data["weight"] += e.weight
                    data["carries"].append(e.carries)
                else:
                    g.add_edge(e.source, e.target, weight=e.weight, carries=[e.carries],
                               active=False)
        state = (self.configuration, self.active)
        if self._graph_state != state:
            pairs = {(s, t) for s, t, _ in self.edges}
            for n, data in g.nodes(data=True):
                data["active"] = n in self.active
            for s, t, data in g.edges(data=True):
                data["active"] = (s, t) in pairs
            self._graph_state = state
        return g

    def sync(self, system: ManagedSystem) -> None:
        """Read configuration and active modules from the running system."""
        conf = str(system.configuration)
        active = system.active
        if not isinstance(active, (set, frozenset)):
            active = frozenset(active)
        if conf != self.configuration or active != self.active:  # no copy when unchanged
            self._set_active(conf, active)

    def record_structural(self, t: float) -> None:
        """Note an executed architectural change; sets ``t_last`` (Eq. 28)."""
        self.t_last = float(t)

    def record_parameters(self, module: str, values: dict) -> None:
        """Note an executed parameter update."""
        self.params.setdefault(module, {}).update(values)

    # ------------------------------------------------------------------ analysis
    def weight_matrix(self) -> np.ndarray | scipy.sparse.csr_matrix:
        """W of the active edges (Eq. 13), normalized by :attr:`w_scale` (dense up to
        :data:`~archself.runtime.influence.DENSE_MAX` modules, else sparse)."""
        return weight_matrix(
            self.names,
            [(s, t, self.arch_weight(s, t, c)) for s, t, c in sorted(self.edges)],
            scale=self.w_scale,
            dense_max=DENSE_MAX,
        )

    def set_weight(self, source: str, target: str, weight: float) -> None:
        """Set the weight of the pair ``source → target`` (online W, runtime/knowledge.py).

        Parallel edges of the pair keep their shares; the factorization and the
        weights' users re-read W at their next use.
        """
        keys = [k for k in self._weights if k[0] == source and k[1] == target]
        total = sum(self._weights[k] for k in keys)
        for k in keys:
            self._weights[k] = weight * (self._weights[k] / total if total else 1 / len(keys))
        self.solver.key = None
        if self._graph is not None and self._graph.has_edge(source, target):
            self._graph.edges[source, target]["weight"] = weight

    def arch_weight(self, source: str, target: str, carries: str) -> float:
        """Declared weight of an edge (parallel edges with the same ``carries`` add up)."""
        return self._weights.get((source, target, carries), 0.0)

    def influence(self, r: np.ndarray) -> np.ndarray:
        """``z = (I − Wᵀ)⁻¹ r`` (Eq. 14) for the active edges, factorization cached."""
        key = self.solver.key
        if key is not self.edges and key != self.edges:
            self.solver.set_matrix(self.weight_matrix(), key=self.edges)
        return self.solver.solve(r)


class _ValueItems(ItemsView[str, float]):
    _mapping: ValueMap

    def __iter__(self) -> Iterator[tuple[str, float]]:
        m = self._mapping
        return zip(m._names, m._values.tolist(), strict=True)


class ValueMap(Mapping[str, float]):
    """Read-only ``name -> float`` over a list of names and an array of values.

    What a :class:`DecisionRecord` keeps for ``r`` and ``z``: the cycle's arrays
    themselves, not a dict of 10^4 floats per cycle. It compares equal to the
    dict it stands for, and :func:`~archself.io.jsondata.jsonable` turns it into that dict.

    Parameters
    ----------
    names : sequence of str
        The keys, in order.
    index : mapping
        name -> position (shared between cycles while the names are the same).
    values : numpy.ndarray
        One value per name (not copied: do not change it afterwards).

    Examples
    --------
    >>> import numpy as np
    >>> m = ValueMap(["a", "b"], {"a": 0, "b": 1}, np.array([0.5, 2.0]))
    >>> m["b"], m == {"a": 0.5, "b": 2.0}
    (2.0, True)
    """

    __slots__ = ("_index", "_names", "_values")

    def __init__(self, names: Sequence[str], index: Mapping[str, int], values: Any) -> None:
        self._names = names
        self._index = index
        self._values = values

    def __getitem__(self, name: str) -> float:
        return float(self._values[self._index[name]])

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def get(self, name: str, default: Any = None) -> Any:
        i = self._index.get(name)
        return default if i is None else float(self._values[i])

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)

    def items(self) -> ItemsView[str, float]:
        return _ValueItems(self)

    def __repr__(self) -> str:
        return repr(dict(self.items()))

    def __reduce__(self) -> tuple[Any, ...]:
        # a list pickles much faster than many small arrays
        return (_value_map, (self._names, self._index, self._values.tolist()))


def _value_map(names: Sequence[str], index: Mapping[str, int], values: list[float]) -> ValueMap:
    """Unpickle a :class:`ValueMap`."""
    return ValueMap(names, index, np.array(values, dtype=float))


@dataclass(slots=True)
class ActionEvaluation:
    """One action considered in the Plan stage."""

    action: str
    module: str
    kind: str
    to: str | None
    z: float | None = None
    delta: float | None = None
    cost: float = 0.0
    score: float | None = None
    stability: dict[str, Any] | None = None
    rejected: str | None = None
    detail: str = ""
    utility: dict[str, Any] | None = None  # U of the target and its attributes (qualities)
    # runtime.risk (archself.runtime.planner): Δ's draws, their mean and spread, the rule
    mean: float | None = None
    spread: float | None = None
    draws: int | None = None
    rule: str | None = None
    learned: dict[str, Any] | None = None  # runtime.learning: this context's record

    def to_dict(self) -> dict[str, Any]:
        """JSON data: the :class:`~archself.io.jsondata.EvaluationDoc` of the evaluation."""
        return document(EvaluationDoc, self)  # type: ignore[no-any-return]


@dataclass
class DecisionRecord:
    """What one MAPE-K cycle saw and decided."""

    cycle: int
    t: float
    configuration: str
    phase: str  # "warmup" or "adapt"
    j_obs: float
    j_ref: float
    r_global: float
    r: Mapping[str, float]
    z: Mapping[str, float]
    candidates: list[str]
    selector: str
    kappa: dict[str, dict[str, Any]] = field(default_factory=dict)
    evaluations: list[ActionEvaluation] = field(default_factory=list)
    chosen: dict[str, Any] | None = None
    note: str = ""
    compensated: list[str] = field(default_factory=list)
    source: Mapping[str, float] | None = None
    localization: str = "influence"
    equivalent: list[list[str]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON data: the :class:`~archself.io.jsondata.DecisionRecordDoc` of the record."""
        return document(DecisionRecordDoc, self)  # type: ignore[no-any-return]


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

        write_text(Path(path), json.dumps(self.to_dict(), indent=1) + "\n")


def load_table(path: str | Path) -> OutcomeTable:
    """Read a table: a file :meth:`OutcomeTable.save` wrote, or a trace (one-line errors).

    A trace (Parquet, or JSON with ``meta`` and ``series``) holds the table of its run
    in ``meta.knowledge.learned`` when ``runtime.learning`` was on.
    """

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

        trial = dict(pairs)
        trial.update({p: v[0] for p, v in proposed.items()})
        W = weight_matrix(self.k.names, [(a, b, w) for (a, b), w in trial.items()],
                          dense_max=DENSE_MAX)
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
