"""The decision log of the MAPE-K loop and its human-readable rendering.

One :class:`DecisionRecord` per cycle holds what Algorithm 1 saw and decided:
the objective ``J_obs`` and global residual ``r`` (Eq. 11), the module residuals
``r_i`` (Eq. 12), the influence ``z`` (Eq. 14), the source estimate ``ê``
(:mod:`~archself.runtime.sources`) and which of the two drove the candidate set
(``runtime.localization``), the candidate set (Eq. 16), and
for every action evaluated its estimated improvement Δ (Eq. 18), its stability
verdict (Eq. 21/24), why it was rejected (``not applicable``, ``no change``,
``unavailable``, ``constraint``, ``budget``, ``limit``, ``dwell``, ``held back``,
``no improvement``, ``unstable``), with ``runtime.risk`` Δ's mean, spread and rule,
with ``runtime.learning`` the context's learned record, its score (Eq. 25) and the
action chosen (Eq. 26). Written as the pydantic model
:class:`~archself.io.jsondata.DecisionRecordDoc` (``record.to_dict()``; a log:
``MapeK.log()``): lists, strings, numbers and ``None`` for non-finite numbers.

:func:`explain` renders a log for a person asking "why did it switch?"
(:mod:`archself.runtime.explanation`, re-exported here).
"""

from __future__ import annotations

from collections.abc import ItemsView, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from archself.io.jsondata import DecisionRecordDoc, EvaluationDoc, document
from archself.runtime.explanation import explain, explain_data

__all__ = ["ActionEvaluation", "DecisionRecord", "ValueMap", "explain", "explain_data"]


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
    import numpy as np

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
    # runtime.risk (archself.runtime.risk): Δ's draws, their mean and spread, the rule
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
