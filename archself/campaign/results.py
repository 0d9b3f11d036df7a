"""The results table of a campaign: one Parquet row per run.

Columns (in this order; the sweep columns, one per PATH, follow ``scenario``):

========================  ===============  =============================================
column                    type             meaning
========================  ===============  =============================================
``run_id``                string           stable key: scenario, sweep values, replicate, mode
``scenario``              string           scenario of the file
*PATH* …                  float64          the swept values (column name = the PATH)
``replicate``             int32            index of the seed, 0 … N−1
``seed``                  int64            seed given to the simulation
``mode``                  string           ``fixed`` or ``adaptive``
``start_configuration``   string           configuration at t = 0
``final_configuration``   string           configuration at the end
``configuration_path``    string           e.g. ``a1>a2``
``switch_times_s``        list<float64>    times of the architectural switches
``n_switches``            int32
``first_fault_onset_s``   float64 (null)   earliest fault onset (null: fault-free)
``detection_delay_s``     float64 (null)   first switch at/after the onset − onset
``false_switches``        int32            switches without a fault / before the onset
``n_updates``             int32            parameter updates the loop made
``updates``               string           each as ``action@t_s``, ``;``-separated
``module_faults``         string (null)    modules unavailable while active, each as
                                           ``module: reason``, ``;``-separated
                                           (``RunResult.faults``; null: the run failed)
``max_error``             float64          objective error J of the run: maximum,
``final_error``           float64          at the end, RMS (in ``unit``), and when
``rms_error``             float64          the maximum was reached
``peak_time_s``           float64
``unit``                  string (null)    unit of J (``runtime.objective.unit``)
``trace``                 string (null)    trace file, with ``--traces``
``error``                 string (null)    why the run failed (metrics NaN then)
========================  ===============  =============================================

The file's schema metadata ``archself.campaign`` holds JSON describing the
campaign (architecture name and SHA-256, root seed, sweep PATHs), which
``--resume`` checks before it continues a file.

Tables written before the error metrics took their unit from the file have the columns
``max_error_m``, ``final_error_m`` and ``rms_error_m`` and no ``unit``:
:func:`read_results` renames them and sets ``unit`` to ``m``, so that such a table is
reported and resumed like a new one.
"""

from __future__ import annotations

import io
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from archself.campaign.sweep import CampaignError
from archself.io.files import write_bytes
from archself.io.html import card, table
from archself.io.jsondata import CampaignMeta, JsonLimitError, document, loads, problem

__all__ = ["META_KEY", "OLD_METRIC_COLUMNS", "read_results", "results_schema", "summary_frame",
           "write_results"]

META_KEY = b"archself.campaign"

_BEFORE = [("run_id", "string"), ("scenario", "string")]
_AFTER = [
    ("replicate", "int32"),
    ("seed", "int64"),
    ("mode", "string"),
    ("start_configuration", "string"),
    ("final_configuration", "string"),
    ("configuration_path", "string"),
    ("switch_times_s", "list<float64>"),
    ("n_switches", "int32"),
    ("first_fault_onset_s", "float64"),
    ("detection_delay_s", "float64"),
    ("false_switches", "int32"),
    ("n_updates", "int32"),
    ("updates", "string"),
    ("module_faults", "string"),
    ("max_error", "float64"),
    ("final_error", "float64"),
    ("rms_error", "float64"),
    ("peak_time_s", "float64"),
    ("unit", "string"),
    ("trace", "string"),
    ("error", "string"),
]


def _type(pa: Any, name: str) -> Any:
    if name == "list<float64>":
        return pa.list_(pa.float64())
    return getattr(pa, name)()


def results_schema(sweep_paths: Sequence[str], meta: dict[str, Any] | None = None) -> Any:
    """The :class:`pyarrow.Schema` of a campaign's results table."""
    import pyarrow as pa

    cols = _BEFORE + [(p, "float64") for p in sweep_paths] + _AFTER
    fields = [pa.field(name, _type(pa, t)) for name, t in cols]
    doc = document(CampaignMeta, meta or {})
    metadata = {META_KEY: json.dumps(doc, sort_keys=True).encode()}
    return pa.schema(fields, metadata=metadata)


def write_results(
    path: str | Path, rows: list[dict[str, Any]], sweep_paths: Sequence[str], meta: dict[str, Any]
) -> None:
    """Write ``rows`` as Parquet to ``path`` atomically.

    The rows are sorted by scenario, sweep values, replicate and mode (deterministic).

    Raises
    ------
    OutputError
        If the file cannot be written.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    ordered = sorted(rows, key=lambda r: (
        r["scenario"], tuple(r[p] for p in sweep_paths), r["replicate"], r["mode"]))
    table = pa.Table.from_pylist(ordered, schema=results_schema(sweep_paths, meta))
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd")
    write_bytes(path, buf.getvalue())


def read_results(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """Read a results file: the :class:`pyarrow.Table` and the campaign metadata.

    Raises
    ------
    CampaignError
        If the file is missing or not an archself campaign's results.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    p = Path(path)
    if not p.is_file():
        raise CampaignError(f"{p}: no such file")
    try:
        table = pq.read_table(p)
    except (OSError, pa.ArrowException) as exc:
        raise CampaignError(f"{p}: not a Parquet file ({type(exc).__name__})") from None
    raw = (table.schema.metadata or {}).get(META_KEY)
    if raw is None:
        raise CampaignError(f"{p}: not the results of an archself campaign (no metadata)")
    try:
        meta = loads(raw)
    except ValueError as exc:  # JsonLimitError (too deep, a huge integer) says which
        why = f" ({exc})" if isinstance(exc, JsonLimitError) else ""
        raise CampaignError(f"{p}: damaged campaign metadata{why}") from None
    bad = problem(CampaignMeta, meta, "meta")
    if bad is not None:
        raise CampaignError(f"{p}: damaged campaign metadata ({bad})")
    return _checked(p, _upgrade(table), meta["sweeps"] if "sweeps" in meta else []), meta


#: Columns a results table may lack (written before they were added); null when resumed.
OPTIONAL_COLUMNS = frozenset({"n_updates", "updates", "module_faults", "unit", "trace", "error"})
#: Columns no row leaves empty (the keys of a run; the sweep columns too).
KEY_COLUMNS = ("run_id", "scenario", "replicate", "mode")


def _checked(p: Path, table: Any, sweep_paths: Sequence[str]) -> Any:
    """``table`` with every column of :func:`results_schema` in its type, or a one-line error.

    A column another tool rewrote in a type that converts (``int64`` replicates, numbers
    as strings) is converted; a missing column, one that does not convert and an empty
    key (:data:`KEY_COLUMNS`, the sweep columns) are refused: resuming or reporting such
    a table failed deep inside with an internal error.
    """
    import pyarrow as pa

    names = table.column_names
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise CampaignError(f"{p}: column {twice[0]!r} appears twice; not the results of an "
                            "archself campaign")
    for f in results_schema(sweep_paths):
        if f.name not in names:
            if f.name in OPTIONAL_COLUMNS:
                continue
            raise CampaignError(f"{p}: no column {f.name!r}; not the results of an archself "
                                "campaign")
        col = table.column(f.name)
        if col.type != f.type:
            try:
                col = col.cast(f.type)
            except (pa.ArrowException, ValueError, TypeError):
                raise CampaignError(
                    f"{p}: column {f.name!r} holds {col.type}, expected {f.type}"
                ) from None
            table = table.set_column(names.index(f.name), f.name, col)
        if (f.name in KEY_COLUMNS or f.name in sweep_paths) and col.null_count:
            raise CampaignError(f"{p}: column {f.name!r} has {col.null_count} empty "
                                f"value{'s' * (col.null_count != 1)}; every run has one")
    return table


#: Columns of tables written before the metrics took their unit from the file.
OLD_METRIC_COLUMNS = {"max_error_m": "max_error", "final_error_m": "final_error",
                "rms_error_m": "rms_error"}


def _upgrade(table: Any) -> Any:
    """An old table (``max_error_m`` ... in metres, no ``unit``) with today's column names."""
    import pyarrow as pa

    names = table.column_names
    if "unit" in names or not set(OLD_METRIC_COLUMNS) <= set(names):
        return table
    metadata = table.schema.metadata
    table = table.rename_columns([OLD_METRIC_COLUMNS.get(n, n) for n in names])
    at = names.index("peak_time_s") + 1 if "peak_time_s" in names else len(names)
    table = table.add_column(at, pa.field("unit", pa.string()),
                             pa.array(["m"] * table.num_rows, pa.string()))
    return table.replace_schema_metadata(metadata)


def summary_frame(path: str | Path) -> Any:
    """A results file in one :class:`pandas.DataFrame` row per scenario, sweep point and mode.

    Columns: ``runs``, ``failed``, the medians of ``max_error`` and ``rms_error`` (in
    the table's ``unit``), the mean ``n_switches`` and the most frequent
    ``final_configuration``; the index is ``scenario``, the sweep PATHs and ``mode``.
    What :meth:`archself.campaign.driver.CampaignOutcome.table` returns.

    Raises
    ------
    CampaignError
        As :func:`read_results`.
    """
    table, meta = read_results(path)
    runs = table.to_pandas()
    keys = ["scenario", *meta.get("sweeps", []), "mode"]
    frame = runs.groupby(keys, sort=True).agg(
        runs=("run_id", "size"),
        failed=("error", lambda e: int(e.notna().sum())),
        max_error=("max_error", "median"),
        rms_error=("rms_error", "median"),
        n_switches=("n_switches", "mean"),
        final_configuration=("final_configuration", lambda c: c.mode().iat[0]),
    )
    frame.attrs["unit"] = runs["unit"].dropna().iat[0] if runs["unit"].notna().any() else None
    return frame


def outcome_html(outcome: Any) -> str:
    """The notebook card of a :class:`~archself.campaign.driver.CampaignOutcome`.

    The counts, and per scenario and mode the median errors (from the results file,
    at most :data:`archself.io.html.MAX_ROWS` rows).
    """

    rows = [("results", outcome.out), ("runs", f"{outcome.rows} in the file: {outcome.ran} ran, "
                                      f"{outcome.skipped} kept, {outcome.failed} failed"),
            ("executor", f"{outcome.executor}, {outcome.workers} workers, "
                         f"{outcome.elapsed_s:.1f} s")]
    if outcome.errors:
        rows.append(("first error", outcome.errors[0]))
    try:
        frame = summary_frame(outcome.out)
    except (CampaignError, ImportError) as exc:  # the file gone, or no pandas
        return card("campaign", [*rows, ("table", str(exc))])
    unit = f" [{frame.attrs['unit']}]" if frame.attrs.get("unit") else ""
    body = [(*(k if isinstance(k, tuple) else (k,)), r.runs, f"{r.max_error:.4g}",
             f"{r.rms_error:.4g}", f"{r.n_switches:.2g}", r.final_configuration)
            for k, r in frame.iterrows()]
    header = [*frame.index.names, "runs", f"median max error{unit}",
              f"median RMS error{unit}", "switches", "final configuration"]
    return card("campaign", rows, table(header, body))
