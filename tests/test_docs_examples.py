"""Every ``console`` example in README.md and docs/ runs as written and prints what it shows.

A ``console`` block holds ``$ command`` lines, each followed by the output it prints
(stdout and stderr as a terminal shows them). A line ``...`` stands for any number of
lines. The blocks of one page run in order in one fresh folder that holds links to the
repository's ``architectures/``, ``plugins/``, ``schemas/`` and ``tests/``.
``pytest tests/test_docs_examples.py --regen-golden`` rewrites the shown outputs.

``sh`` blocks (installation commands) are not run here: CI runs the README's two
quick-start commands verbatim (see ``.ci/run``).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"^```console\n(.*?)^```\n", re.S | re.M)
LINKED = ("architectures", "plugins", "schemas", "tests")


def _commands(block: str) -> list[tuple[str, list[str]]]:
    out: list[tuple[str, list[str]]] = []
    for line in block.splitlines():
        if line.startswith("$ "):
            out.append((line[2:], []))
        elif out:
            out[-1][1].append(line)
    return out


def _matches(expected: list[str], actual: list[str]) -> bool:
    if "..." not in expected:
        return expected == actual
    i = expected.index("...")
    head, tail = expected[:i], expected[i + 1 :]
    if len(head) + len(tail) > len(actual):
        return False
    return actual[: len(head)] == head and (not tail or actual[-len(tail) :] == tail) and (
        _matches(tail, actual[len(actual) - len(tail) :]) if "..." in tail else True
    )


def _elide(expected: list[str], actual: list[str]) -> list[str]:
    if "..." not in expected:
        return actual
    i = expected.index("...")
    n_tail = len(expected) - i - 1
    return actual[:i] + ["..."] + (actual[-n_tail:] if n_tail else [])


def _run(cmd: str, cwd: Path) -> list[str]:
    env = {**os.environ, "COLUMNS": "100", "TERM": "dumb", "NO_COLOR": "1",
           "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    proc = subprocess.run(["bash", "-c", cmd], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)
    text = proc.stdout + proc.stderr
    return [line.rstrip() for line in text.rstrip("\n").splitlines()]


def _pages_with_examples() -> list[Path]:
    return [p for p in PAGES if "```console" in p.read_text(encoding="utf-8")]


@pytest.mark.parametrize("page", _pages_with_examples(), ids=lambda p: p.name)
def test_console_examples(page: Path, tmp_path: Path, regen: bool) -> None:
    for name in LINKED:
        (tmp_path / name).symlink_to(ROOT / name)
    text = page.read_text(encoding="utf-8")
    new_text = text
    failures = []
    for m in BLOCK.finditer(text):
        lines = []
        for cmd, expected in _commands(m.group(1)):
            actual = _run(cmd, tmp_path)
            if not _matches([e.rstrip() for e in expected], actual):
                failures.append(f"$ {cmd}\n--- expected\n" + "\n".join(expected)
                                + "\n--- actual\n" + "\n".join(actual))
            lines += [f"$ {cmd}", *_elide(expected, actual)]
        new_text = new_text.replace(m.group(0), "```console\n" + "\n".join(lines) + "\n```\n", 1)
    if regen and new_text != text:
        page.write_text(new_text, encoding="utf-8")
        return
    assert not failures, f"{page.name}: examples differ (regenerate with --regen-golden)\n\n" + \
        "\n\n".join(failures)
