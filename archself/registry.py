"""The module-type registry: ``type`` strings of a file → runtime classes.

Every type comes from the ``archself.modules`` entry-point group (name = type
key, value = ``package.module:Class``): the packs shipped with archself
(``packs/``) and third-party plugins register the same way, and the core imports
none of them. An entry point is loaded when its type is first asked for, so
``archself validate`` imports only the types a file uses. :func:`register`
adds a class by hand (tests, interactive use). A type resolves only through this
registry: a file never names a Python object to import.

A type of the API before ``parameters`` (``required_params``/``optional_params``, names
only) is converted when it is registered (:func:`migrate`): its names become
``parameters`` without defaults, so ``archself validate`` checks them again (a misspelt
one is an error with "did you mean"), and a :class:`FutureWarning` says once how to
declare them (docs/plugins.md, "Migrating from optional_params").
"""

from __future__ import annotations

import warnings
from importlib.metadata import EntryPoint, entry_points
from typing import TYPE_CHECKING, Any

from archself.errors import RegistryError

if TYPE_CHECKING:
    from archself.modules.base import RuntimeModule

ENTRY_POINT_GROUP = "archself.modules"

_TYPES: dict[str, type[RuntimeModule]] = {}
_POINTS: dict[str, EntryPoint] | None = None
#: Type key → the migration note of a type converted from ``optional_params``.
LEGACY: dict[str, str] = {}


def register(key: str):
    """Class decorator registering a runtime module type under ``key``.

    Raises
    ------
    RegistryError
        If ``key`` is already registered.

    Examples
    --------
    >>> from archself.modules.base import RuntimeModule
    >>> @register("example.doc_gain")
    ... class DocGain(RuntimeModule):
    ...     pass
    >>> DocGain.type_key
    'example.doc_gain'
    >>> unregister("example.doc_gain")
    """

    def deco(cls: type[RuntimeModule]) -> type[RuntimeModule]:
        add(key, cls)
        return cls

    return deco


def add(key: str, cls: type[RuntimeModule]) -> None:
    """Register ``cls`` under ``key``; a key taken by another class is an error."""
    other = _TYPES.get(key)
    if other is None and key in _points() and _points()[key].value != _qualname(cls):
        other_name = _points()[key].value
    elif other is not None and other is not cls:
        other_name = _qualname(other)
    else:
        other_name = None
    if other_name is not None:
        raise RegistryError(
            f"module type {key!r} is registered twice ({other_name} and {_qualname(cls)})"
        )
    cls.type_key = key
    migrate(key, cls)
    _TYPES[key] = cls


def _no_defaults(cls: Any) -> dict[str, Any]:
    return {}  # the old API had none: the type's own ``params.get(k, default)`` holds


def migrate(key: str, cls: Any) -> str | None:
    """Convert an old declaration (``required_params``, ``optional_params``) into ``parameters``.

    A type that declares ``optional_params`` (a sequence of names) and no ``parameters``
    gets ``parameters`` of those names and of ``required_params`` (required), without
    defaults, units or ranges: the file's names are checked as before the change, and
    the type still reads its own defaults. Warns once per type (:class:`FutureWarning`)
    and returns the note (kept in :data:`LEGACY`); None for any other type.

    Examples
    --------
    >>> from archself.modules.base import RuntimeModule
    >>> class Old(RuntimeModule):
    ...     required_params = ("k",)
    ...     optional_params = ("noise",)
    >>> import warnings
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     note = migrate("doc.old", Old)
    >>> sorted(Old.parameters), Old.parameters["k"].required, Old.default_params()
    (['k', 'noise'], True, {})
    >>> LEGACY.pop("doc.old") == note
    True
    """
    if getattr(cls, "parameters", None) is not None:
        return None
    optional = getattr(cls, "optional_params", None)
    if optional is None:
        return None
    from archself.modules.base import Param

    required = tuple(getattr(cls, "required_params", None) or ())
    params = {n: Param(doc="declared by required_params") for n in required}
    for n in optional:
        params.setdefault(str(n), Param(None, doc="declared by optional_params"))
    cls.parameters = params
    cls.default_params = classmethod(_no_defaults)
    note = (f"module type {key!r} ({_qualname(cls)}) declares optional_params, the API "
            f"before 'parameters': its parameter names are checked, but without defaults, "
            f"units or ranges; declare parameters = {{name: Param(default, unit, doc, "
            f"min=, max=)}} instead (docs/plugins.md, 'Migrating from optional_params')")
    if key not in LEGACY:
        LEGACY[key] = note
        warnings.warn(note, FutureWarning, stacklevel=3)
    return note


def unregister(key: str) -> None:
    """Remove a type added by hand (for tests and interactive use)."""
    _TYPES.pop(key, None)


def _qualname(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _points() -> dict[str, EntryPoint]:
    """Entry points by type key (read once; names only, nothing imported)."""
    global _POINTS
    if _POINTS is None:
        points: dict[str, EntryPoint] = {}
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            if ep.name in points and points[ep.name].value != ep.value:
                raise RegistryError(
                    f"module type {ep.name!r} is registered twice "
                    f"({points[ep.name].value} and {ep.value})"
                )
            points[ep.name] = ep
        _POINTS = points
    return _POINTS


def known_types() -> list[str]:
    """Sorted keys of every registered type (entry points and hand-registered)."""
    return sorted(set(_points()) | set(_TYPES))


def lookup(key: str) -> type[RuntimeModule] | None:
    """The class registered under ``key``, or None; loads its entry point once.

    Raises
    ------
    RegistryError
        If the entry point fails to import (a broken plugin gets a message, not a traceback).
    """
    cls = _TYPES.get(key)
    if cls is not None:
        return cls
    ep = _points().get(key)
    if ep is None:
        return None
    try:
        cls = ep.load()
    except Exception as exc:  # a broken plugin must not take the tool down
        raise RegistryError(f"plugin {key!r} ({ep.value}) failed to load: {exc}") from exc
    cls.type_key = key
    migrate(key, cls)
    _TYPES[key] = cls
    return cls


def get(key: str) -> type[RuntimeModule]:
    """The class registered under ``key``.

    Raises
    ------
    RegistryError
        If no type has that key; the message lists the known types.
    """
    cls = lookup(key)
    if cls is None:
        raise RegistryError(f"unknown module type {key!r}; known types: {', '.join(known_types())}")
    return cls
