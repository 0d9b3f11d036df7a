"""The context of the semantic checks: the loaded file, the types of its modules, the findings.

Every rule of :mod:`archself.check` takes a :class:`Context` and adds its findings
with :meth:`Context.add`, which locates them in the source (file, line, column).
:func:`refers` reports an unknown module or configuration name with "did you mean";
:func:`closest` is that hint.
"""

from __future__ import annotations

from typing import Any

from archself.findings import Finding
from archself.io.yaml_source import Path_, dotted
from archself.model.architecture import Architecture
from archself.model.loader import Loaded

__all__ = ["Context", "closest", "refers"]


class Context:
    """A loaded architecture under check: ``arch``, ``src``, ``types`` (name → class), ``out``."""

    def __init__(self, loaded: Loaded) -> None:
        from archself import registry

        self.arch: Architecture = loaded.arch
        self.src = loaded.source
        self.out: list[Finding] = []
        modules = self.arch.modules
        by_type = {t: registry.lookup(t) for t in dict.fromkeys(m.type for m in modules.values())}
        self.types: dict[str, Any] = {name: by_type[mod.type] for name, mod in modules.items()}

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
    close = closest(name, pool)
    hint = f"; did you mean '{close}'?" if close else ""
    ctx.add("error", "reference", f"unknown {what} '{name}'{hint}", path)
    return False
