"""The module-type registry: ``type`` strings of a file → runtime classes.

Built-in types register with the :func:`register` decorator when
:mod:`archself.modules` is imported; third-party types come from the
``archself.modules`` entry-point group (name = type key, value =
``package.module:Class``). A type resolves only through this registry: a
file never names a Python object to import.

Importing this module and the built-in library is cheap: module classes import
python-control and filterpy lazily, when they are instantiated.
"""

from __future__ import annotations

from importlib.metadata import entry_points
from typing import TYPE_CHECKING

from archself.errors import RegistryError

if TYPE_CHECKING:
    from archself.modules.base import RuntimeModule

ENTRY_POINT_GROUP = "archself.modules"

_TYPES: dict[str, type[RuntimeModule]] = {}
_loaded = False


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
    """Register ``cls`` under ``key``; registering a key twice is an error."""
    if key in _TYPES and _TYPES[key] is not cls:
        raise RegistryError(
            f"module type {key!r} is registered twice "
            f"({_TYPES[key].__module__}.{_TYPES[key].__qualname__} and "
            f"{cls.__module__}.{cls.__qualname__})"
        )
    cls.type_key = key
    _TYPES[key] = cls


def unregister(key: str) -> None:
    """Remove a type (for tests and interactive use)."""
    _TYPES.pop(key, None)


def _load() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    import archself.modules  # noqa: F401  (registers the built-ins)

    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in _TYPES:
            raise RegistryError(
                f"module type {ep.name!r} from entry point {ep.value!r} is registered twice"
            )
        try:
            cls = ep.load()
        except Exception as exc:  # a broken plugin must not take the tool down
            raise RegistryError(f"plugin {ep.name!r} ({ep.value}) failed to load: {exc}") from exc
        add(ep.name, cls)


def known_types() -> list[str]:
    """Sorted keys of every registered type, built-in and plugin."""
    _load()
    return sorted(_TYPES)


def get(key: str) -> type[RuntimeModule]:
    """The class registered under ``key``.

    Raises
    ------
    RegistryError
        If no type has that key; the message lists the known types.
    """
    _load()
    try:
        return _TYPES[key]
    except KeyError:
        raise RegistryError(
            f"unknown module type {key!r}; known types: {', '.join(sorted(_TYPES))}"
        ) from None


def lookup(key: str) -> type[RuntimeModule] | None:
    """The class registered under ``key``, or None."""
    _load()
    return _TYPES.get(key)
