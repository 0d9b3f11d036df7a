"""The context of the semantic checks: the loaded file, the types of its modules, the findings.

Every rule of :mod:`archself.check` takes a :class:`Context` and adds its findings
with :meth:`Context.add`, which locates them in the source (file, line, column).
:func:`refers` reports an unknown module or configuration name with "did you mean";
:func:`closest` is that hint.
"""

from __future__ import annotations

from typing import Any

from archself.findings import Finding
from archself.loader import Loaded, Path_, dotted
from archself.model import Architecture

__all__ = ["Context", "closest", "refers"]


class Context:
    """A loaded architecture under check: ``arch``, ``src``, ``types`` (name → class), ``out``."""

    def __init__(self, loaded: Loaded) -> None:
        from archself import registry

        self.arch: Architecture = loaded.arch
        self.src = loaded.source
        self.out: list[Finding] = []
        by_type: dict[str, Any] = {}
        self.types: dict[str, Any] = {}
        for name, mod in self.arch.modules.items():
            if mod.type not in by_type:
                by_type[mod.type] = registry.lookup(mod.type)
            self.types[name] = by_type[mod.type]

    def add(self, sev: str, code: str, msg: str, path: Path_, *, key: bool = False) -> None:
        line, col = self.src.locate(path, key=key)
        self.out.append(Finding(sev, code, msg, dotted(path), self.src.file, line, col))  # type: ignore[arg-type]


def closest(word: str, options: Any) -> str | None:
    """The option closest to ``word`` (difflib), or None."""
    import difflib

    close = difflib.get_close_matches(word, list(options), n=1)
    return close[0] if close else None


def refers(ctx: Context, name: str, path: Path_, what: str = "module") -> bool:
    """Whether ``name`` is a declared module (or configuration); else an error finding."""
    pool = ctx.arch.modules if what == "module" else ctx.arch.configurations
    if name in pool:
        return True
    import difflib

    close = difflib.get_close_matches(name, list(pool), n=1)
    hint = f"; did you mean '{close[0]}'?" if close else ""
    ctx.add("error", "reference", f"unknown {what} '{name}'{hint}", path)
    return False
