"""Run traces on disk: Parquet (compact, read by pandas and polars) or JSON.

A trace holds a run's recorded series, its decision log and what the run report
needs to be rebuilt (``archself report --trace``) without the architecture file.
The format follows the file name: ``.parquet`` (or ``.pq``) writes Parquet, any other
suffix JSON; reading looks at the content (Parquet's ``PAR1`` magic), not the name.

Parquet layout (``pd.read_parquet(path)`` gives the same columns as
:meth:`archself.sim.run.RunResult.to_pandas`):

- one row per simulation step; ``t`` float64 [s], every other series float32 (7
  significant digits: finer than the JSON trace's rounding to 1e-6 for values below
  10), a vector series one column per component, named by the element names of
  ``meta["elements"]`` where the publishing type declares them (``reference_x`` …),
  else by index (``reference_0`` …): :func:`component_columns`,
  ``configuration`` a dictionary-encoded string (a categorical in pandas);
- the file's key-value metadata ``archself.trace``: JSON ``{"format": 1, "meta": …,
  "series": [[name, width], …]}`` (``meta`` as in the JSON trace, widths to rebuild the
  2-D series);
- key-value metadata ``archself.decisions``: the decision log, JSON compressed with xz
  (LZMA) and base64-encoded (``json.loads(lzma.decompress(base64.b64decode(v)))``).

A 400 s diffdrive run is ≈ 0.4 MB in Parquet against ≈ 2.2 MB of JSON.
The same run and seed give byte-identical files (same pyarrow version).
"""

from __future__ import annotations

import base64
import io
import json
import lzma
import math
import os
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from archself.errors import TraceError
from archself.io.files import path_problem, write_bytes
from archself.io.jsondata import (
    DecisionLog,
    JsonLimitError,
    ParquetHead,
    TraceDocument,
    loads,
    problem,
)

__all__ = [
    "component_columns",
    "TRACE_KEY",
    "DECISIONS_KEY",
    "TraceError",
    "is_parquet_name",
    "parquet_bytes",
    "TraceParts",
    "read_trace_parts",
    "trace_parts_from_bytes",
    "write_trace",
]

TRACE_KEY = b"archself.trace"
DECISIONS_KEY = b"archself.decisions"
FORMAT = 1
_SUFFIXES = (".parquet", ".pq")


def component_columns(name: str, width: int, meta: Any) -> list[str]:
    """The columns of a vector series ``name`` of ``width`` components.

    ``name_<element>`` when ``meta["elements"][name]`` holds ``width`` distinct names (the
    types' ``output_elements``), else ``name_0`` … (old traces, undeclared outputs).

    Examples
    --------
    >>> component_columns("actual", 3, {"elements": {"actual": ["x", "y", "theta"]}})
    ['actual_x', 'actual_y', 'actual_theta']
    >>> component_columns("command", 2, {"elements": {"actual": ["x", "y", "theta"]}})
    ['command_0', 'command_1']
    """
    elements = meta.get("elements") if isinstance(meta, dict) else None
    names = elements.get(name) if isinstance(elements, dict) else None
    if (isinstance(names, list) and len(names) == width and len(set(names)) == width
            and all(isinstance(e, str) and e for e in names)):
        return [f"{name}_{e}" for e in names]
    return [f"{name}_{k}" for k in range(width)]


def is_parquet_name(path: str | Path) -> bool:
    """True when ``path`` asks for a Parquet trace (by its suffix).

    Examples
    --------
    >>> is_parquet_name("run.parquet"), is_parquet_name("run.json"), is_parquet_name("-")
    (True, False, False)
    """
    return Path(str(path)).suffix.lower() in _SUFFIXES


def write_trace(result: Any, path: str | Path) -> None:
    """Write ``result``'s trace to ``path``, atomically: Parquet or JSON by the suffix.

    Raises
    ------
    OutputError
        If the file cannot be written.
    """

    write_bytes(path, parquet_bytes(result) if is_parquet_name(path)
                else json_text(result).encode("utf-8"))


def json_text(result: Any) -> str:
    """The JSON trace ``{meta, series, decisions}``: compact, deterministic, one line; a
    :class:`~archself.io.jsondata.TraceDocument` (its meta and log built by their models)."""
    return json.dumps(result.trace(), separators=(",", ":"), allow_nan=False) + "\n"


def parquet_bytes(result: Any) -> bytes:
    """The Parquet trace of ``result`` (see the module's description)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    doc_meta = result.trace_meta()
    columns: dict[str, Any] = {}
    widths: list[list[Any]] = []
    for name, arr in result.series.items():
        a = np.asarray(arr)
        widths.append([name, int(a.shape[1]) if a.ndim == 2 and name != "configuration" else 0])
        if name == "configuration":
            names = list(result.configurations)
            codes = a.astype(np.int32)
            if names:
                columns[name] = pa.DictionaryArray.from_arrays(
                    pa.array(codes, type=pa.int32()), pa.array(names, type=pa.string()))
            else:
                columns[name] = pa.array(codes)
        elif a.ndim == 2:
            for k, col in enumerate(component_columns(name, a.shape[1], doc_meta)):
                columns[col] = pa.array(a[:, k].astype(np.float32))
        elif name == "t":
            columns[name] = pa.array(a.astype(np.float64))
        else:
            columns[name] = pa.array(a.astype(np.float32) if a.dtype.kind == "f" else a)
    decisions = json.dumps(result.trace_decisions(), separators=(",", ":"), allow_nan=False)
    head = {"format": FORMAT, "meta": doc_meta, "series": widths}
    table = pa.table(columns)
    buf = io.BytesIO()
    floats = [n for n, c in columns.items() if pa.types.is_floating(c.type)]
    with pq.ParquetWriter(buf, table.schema, compression="zstd", compression_level=15,
                          use_byte_stream_split=floats,
                          use_dictionary=["configuration"] if "configuration" in columns
                          else False) as writer:
        writer.write_table(table)
        # in the file's key-value metadata only: as schema metadata the Arrow schema
        # (ARROW:schema) would hold the decision log a second time
        writer.add_key_value_metadata({
            TRACE_KEY: json.dumps(head, separators=(",", ":"), allow_nan=False).encode(),
            DECISIONS_KEY: base64.b64encode(lzma.compress(decisions.encode("utf-8"),
                                                          preset=9 | lzma.PRESET_EXTREME)),
        })
    return buf.getvalue()


class TraceParts(NamedTuple):
    """What a trace holds, checked: ``meta``, the ``series`` as arrays, the ``decisions``."""

    meta: dict[str, Any]
    series: dict[str, np.ndarray]
    decisions: list[Any]


def read_trace_parts(path: str | Path) -> TraceParts:
    """The :class:`TraceParts` of a trace file (Parquet or JSON).

    Series come back as float arrays (NaN where the JSON has ``null``), the
    decision log as a list of dicts. :func:`archself.read_trace` builds the
    :class:`~archself.sim.result.RunResult` from them.

    Raises
    ------
    TraceError
        ``PATH: error: not an archself trace (…)`` for any other file.
    """

    problem = path_problem(path)
    if problem is not None:
        raise TraceError(f"<argument>: error: {problem}")
    try:
        raw = Path(os.fsdecode(path)).read_bytes()
    except FileNotFoundError:
        raise TraceError(f"{path}: error: no such file") from None
    except OSError as exc:
        raise TraceError(f"{path}: error: cannot read: {exc.strerror or exc}") from None
    return trace_parts_from_bytes(raw, str(path))


def trace_parts_from_bytes(raw: bytes, name: str = "<trace>") -> TraceParts:
    """:func:`read_trace_parts` of a trace's bytes (stdin: ``archself explain -``)."""
    parquet = raw[:4] == b"PAR1"
    try:
        return _read_parquet(io.BytesIO(raw), name) if parquet else _read_json(raw)
    except TraceError as exc:
        error = TraceError(str(exc))
    except (_Malformed, JsonLimitError) as exc:
        error = TraceError(f"{name}: error: not an archself trace: {exc}")
    except json.JSONDecodeError as exc:  # where the JSON breaks (a truncated trace)
        where = f"{name}:{exc.lineno}:{exc.colno}" if not parquet else name
        error = TraceError(f"{where}: error: not an archself trace: invalid JSON"
                           + (" in its archself metadata" if parquet else "") + f" ({exc.msg})")
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, IndexError,
            AttributeError, lzma.LZMAError, RecursionError) as exc:
        error = TraceError(f"{name}: error: not an archself trace ({type(exc).__name__})")
    raise error  # outside the handlers: without the failed read's exception as context


class _Malformed(Exception):
    """A trace document that departs from :class:`~archself.io.jsondata.TraceDocument`."""


def _check_doc(model: Any, doc: Any, root: str = "") -> None:
    """Raise :class:`_Malformed` (``meta.seed: expected …``) unless ``doc`` is a ``model``.

    What the readers (``explain``, ``report --trace``, the frames) index into is the
    model's, so that a truncated, edited or foreign trace is a one-line error, not a crash.
    """
    why = problem(model, doc, root)
    if why is not None:
        raise _Malformed(why)


def _check_series(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """Every series one row per step; configuration codes index ``meta.configurations``."""
    lengths = {name: len(a) for name, a in arrays.items()}
    if len(set(lengths.values())) > 1:
        first = next(iter(lengths))
        other = next(n for n in lengths if lengths[n] != lengths[first])
        raise _Malformed(f"series.{other}: {lengths[other]} rows, but series.{first} has "
                         f"{lengths[first]}; expected one row per step in every series")
    codes = arrays.get("configuration")
    names = meta.get("configurations") or []
    if codes is not None and len(codes) and names and (
            int(codes.min()) < -1 or int(codes.max()) >= len(names)):
        raise _Malformed(f"series.configuration: expected indices into meta.configurations "
                         f"(0 to {len(names) - 1}), got {int(codes.min())} to {int(codes.max())}")


def _read_json(raw: bytes) -> TraceParts:
    doc = loads(raw.decode("utf-8"))
    _check_doc(TraceDocument, doc)
    meta, series, decisions = doc["meta"], doc["series"], doc["decisions"]
    arrays: dict[str, np.ndarray] = {}
    for name, values in series.items():
        if name == "configuration":
            arrays[name] = np.asarray(values, dtype=int)
        else:
            arrays[name] = np.array(
                [[math.nan if v is None else v for v in row] if isinstance(row, list)
                 else (math.nan if row is None else row) for row in values], dtype=float)
    _check_series(meta, arrays)
    return TraceParts(meta, arrays, list(decisions))


def _read_parquet(source: Any, p: str) -> TraceParts:
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(source)
    md = pf.metadata.metadata or {}
    if TRACE_KEY not in md:
        raise TraceError(f"{p}: error: not an archself trace (a Parquet file without "
                         "archself.trace metadata; a campaign's results are read by "
                         "campaign-report)")
    head = loads(md[TRACE_KEY])
    if isinstance(head, dict) and isinstance(head.get("format"), int) and head["format"] > FORMAT:
        raise TraceError(f"{p}: error: trace format {head['format']} is newer than this "
                         f"archself reads ({FORMAT}); upgrade archself")
    _check_doc(ParquetHead, head)
    meta = head["meta"]
    decisions = loads(lzma.decompress(base64.b64decode(md[DECISIONS_KEY]))) \
        if DECISIONS_KEY in md else []
    _check_doc(DecisionLog, decisions, "decisions")
    table = pf.read()
    arrays: dict[str, np.ndarray] = {}
    for name, width in head["series"]:
        if name == "configuration":
            col = table.column(name).combine_chunks()
            col = getattr(col, "indices", col)  # the codes of a dictionary-encoded column
            arrays[name] = np.asarray(col.to_numpy(zero_copy_only=False), dtype=int)
        elif width:
            arrays[name] = np.column_stack([
                np.asarray(table.column(col).to_numpy(zero_copy_only=False), dtype=float)
                for col in component_columns(name, int(width), meta)])
        else:
            arrays[name] = np.asarray(table.column(name).to_numpy(zero_copy_only=False),
                                      dtype=float)
    _check_series(meta, arrays)
    return TraceParts(meta, arrays, list(decisions))
