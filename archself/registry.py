"""The module-type registry: ``type`` strings of a file → runtime classes.

Every type comes from the ``archself.modules`` entry-point group (name = type
key, value = ``package.module:Class``): the packs shipped with archself
(``packs/``) and third-party plugins register the same way, and the core imports
none of them. An entry point is loaded when its type is first asked for, so
``archself validate`` imports only the types a file uses. :func:`register`
adds a class by hand (tests, interactive use). A type resolves only through this
registry: a file never names a Python object to import.
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points
from typing import TYPE_CHECKING

from archself.errors import RegistryError

if TYPE_CHECKING:
    from archself.modules.base import RuntimeModule

ENTRY_POINT_GROUP = "archself.modules"

_TYPES: dict[str, type[RuntimeModule]] = {}
_POINTS: dict[str, EntryPoint] | None = None


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
    _TYPES[key] = cls


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
