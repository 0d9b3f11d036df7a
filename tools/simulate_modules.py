"""Which archself modules one command runs, and which it merely imports (issue 41).

Runs the command line in this process (``archself.cli.main``) under
``sys.setprofile`` and counts, per module of the ``archself`` package (one ``.py``
file, ``__init__.py`` included):

- **executed**: a function (or method, lambda, comprehension) of the module was
  called while the command ran. Calls made while a module is being imported (its
  body, class bodies, decorators run at import) do not count: a call whose stack
  holds a module body (``<module>``) of another file than this tool's is import
  execution.
- **imported**: the module is in ``sys.modules`` at the end.

Modules of packs (``archself_*`` distributions, ``packs/``) are counted apart.

Usage::

    python tools/simulate_modules.py [--list] [-- ARGS...]

ARGS default to ``simulate architectures/diffdrive.yaml --scenario imu_drift``
(the command's own output goes to /dev/null).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = ["simulate", "architectures/diffdrive.yaml", "--scenario", "imu_drift"]
THIS = str(Path(__file__).resolve())


def _module_of(filename: str, pkg_dir: str) -> str | None:
    """``archself.x.y`` of a file of the package, None for any other file."""
    if not filename.startswith(pkg_dir):
        return None
    rel = Path(filename).relative_to(Path(pkg_dir).parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _in_import(frame: types.FrameType | None) -> bool:
    """A module body (other than this tool's) or the import system is on the stack.

    The import system calls a package's ``__getattr__`` (lazy names) on ``from p import
    x``: import work too.
    """
    while frame is not None:
        code = frame.f_code
        if (code.co_name == "<module>" and code.co_filename != THIS) or (
                code.co_filename.startswith("<frozen importlib")):
            return True
        frame = frame.f_back
    return False


def trace(args: list[str]) -> tuple[dict[str, str], set[str], int]:
    """(executed modules, imported modules, exit code) of ``archself ARGS``.

    The executed modules map to their first call: ``function <- caller module.function``.
    """
    import archself

    pkg_dir = str(Path(archself.__file__).resolve().parent) + os.sep
    executed: dict[str, str] = {}
    seen: dict[str, str | None] = {}  # filename -> module (None: not archself's)

    def profile(frame: types.FrameType, event: str, arg: object) -> None:
        if event != "call":
            return
        filename = frame.f_code.co_filename
        mod = seen.get(filename, "")
        if mod == "":
            mod = seen[filename] = _module_of(str(Path(filename).resolve()), pkg_dir)
        if mod is None or mod in executed or frame.f_code.co_name == "<module>":
            return
        if not _in_import(frame.f_back):
            back = frame.f_back
            caller = "" if back is None else (
                f"{seen.get(back.f_code.co_filename) or Path(back.f_code.co_filename).name}"
                f".{back.f_code.co_name}")
            executed[mod] = f"{frame.f_code.co_name} <- {caller}"

    from archself.cli import main

    old_argv = sys.argv
    sys.argv = ["archself", *args]
    code = 0
    sys.setprofile(profile)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            main()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    finally:
        sys.setprofile(None)
        sys.argv = old_argv
    imported = {m for m in sys.modules if m == "archself" or m.startswith("archself.")}
    return executed, imported, code


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--list", action="store_true", help="list the modules, not only count them")
    ap.add_argument("args", nargs="*", help="the command line (default: %(default)s)",
                    default=DEFAULT)
    ns = ap.parse_args()
    os.chdir(ROOT)
    executed, imported, code = trace(list(ns.args))
    packs = {m for m in sys.modules if m.startswith("archself_")}
    ran = set(executed)
    print(f"archself {' '.join(ns.args)} (exit {code})")
    print(f"core modules executed: {len(executed)}")
    print(f"core modules imported: {len(imported)} ({len(imported - ran)} imported only)")
    print(f"pack modules imported: {len(packs)}")
    if ns.list:
        for m in sorted(imported | ran):
            first = f"  ({executed[m]})" if m in executed else ""
            print(f"  {'run ' if m in ran else 'imp '} {m}{first}")


if __name__ == "__main__":
    main()
