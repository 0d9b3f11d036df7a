"""Every example in README.md and docs/ runs as written; ``console`` ones print what they show.

A ``console`` block holds ``$ command`` lines (a trailing ``\\`` continues a command on
the next line), each followed by the output it prints (stdout and stderr as a terminal
shows them). A line ``...`` stands for any number of lines; ``...`` inside a line stands
for any text. A command must exit with status 0, unless its last line ends with a comment
``# exit N`` that states the status it must end with: ``$ archself validate bad.yaml  # exit 1``.
The blocks of one page run in order in one fresh folder that holds links to the
repository's ``architectures/``, ``plugins/``, ``schemas/`` and ``tests/``.
``pytest tests/test_docs_examples.py --regen-golden`` rewrites the shown outputs.

Every ``python`` block runs too, on its own (``python -c``, in such a folder) and must exit
with status 0: a block is a complete script, not a fragment.

``sh`` blocks are not run here: installation commands (CI runs the README's two
quick-start commands verbatim, see ``.ci/run``) and long jobs (benchmarks, the
1,000-run campaign), each of which has a short ``console`` counterpart that is run.
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
PYTHON = re.compile(r"^```python\n(.*?)^```\n", re.S | re.M)
EXIT = re.compile(r"\s#\s*exit\s+(\d+)\s*$")
LINKED = ("architectures", "plugins", "schemas", "tests")


def _commands(block: str) -> list[tuple[str, list[str]]]:
    """``$ command`` lines (a trailing backslash continues one) with the output after them."""
    out: list[tuple[str, list[str]]] = []
    continued = False
    for line in block.splitlines():
        if continued:
            out[-1] = (out[-1][0] + "\n" + line, [])
        elif line.startswith("$ "):
            out.append((line[2:], []))
        elif out:
            out[-1][1].append(line)
        continued = bool(out) and not out[-1][1] and line.endswith("\\")
    return out


def _line_matches(expected: str, actual: str) -> bool:
    """Equal, or equal where ``...`` inside the expected line stands for any text."""
    if "..." not in expected:
        return expected == actual
    pattern = ".*".join(re.escape(part) for part in expected.split("..."))
    return re.fullmatch(pattern, actual) is not None


def _lines_match(expected: list[str], actual: list[str]) -> bool:
    return len(expected) == len(actual) and all(map(_line_matches, expected, actual))


def _matches(expected: list[str], actual: list[str]) -> bool:
    if "..." not in expected:
        return _lines_match(expected, actual)
    i = expected.index("...")
    head, tail = expected[:i], expected[i + 1 :]
    if len(head) + len(tail) > len(actual):
        return False
    rest = actual[len(head) :]
    if not _lines_match(head, actual[: len(head)]):
        return False
    if "..." in tail:
        return any(_matches(tail, rest[k:]) for k in range(len(rest) + 1))
    return not tail or _lines_match(tail, rest[len(rest) - len(tail) :])


def _elide(expected: list[str], actual: list[str]) -> list[str]:
    if "..." not in expected:
        return actual
    i = expected.index("...")
    n_tail = len(expected) - i - 1
    return actual[:i] + ["..."] + (actual[-n_tail:] if n_tail else [])


def expected_status(cmd: str) -> int:
    """The exit status a command must end with: ``N`` of a trailing ``# exit N``, else 0."""
    m = EXIT.search(cmd.splitlines()[-1])
    return int(m.group(1)) if m else 0


def _env() -> dict[str, str]:
    return {**os.environ, "COLUMNS": "100", "TERM": "dumb", "NO_COLOR": "1",
            "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}


def _run(cmd: str, cwd: Path) -> tuple[int, list[str]]:
    """Exit status and output lines (stdout, then stderr) of ``cmd`` run by bash in ``cwd``."""
    proc = subprocess.run(["bash", "-c", cmd], cwd=cwd, env=_env(), capture_output=True,
                          text=True, timeout=600)
    text = proc.stdout + proc.stderr
    return proc.returncode, [line.rstrip() for line in text.rstrip("\n").splitlines()]


def _link_repository(folder: Path) -> None:
    for name in LINKED:
        (folder / name).symlink_to(ROOT / name)


def _pages_with(fence: str) -> list[Path]:
    return [p for p in PAGES if f"```{fence}\n" in p.read_text(encoding="utf-8")]


def test_expected_status_convention() -> None:
    assert expected_status("archself validate tank.yaml") == 0
    assert expected_status("archself validate tank.yaml  # exit 1") == 1
    assert expected_status("archself simulate x.yaml \\\n  -s drift # exit 2") == 2
    assert expected_status("echo '# exit 1 is a comment'") == 0


@pytest.mark.parametrize("page", _pages_with("console"), ids=lambda p: p.name)
def test_console_examples(page: Path, tmp_path: Path, regen: bool) -> None:
    _link_repository(tmp_path)
    text = page.read_text(encoding="utf-8")
    new_text = text
    failures = []
    for m in BLOCK.finditer(text):
        lines = []
        for cmd, expected in _commands(m.group(1)):
            status, actual = _run(cmd, tmp_path)
            if status != expected_status(cmd):
                failures.append(f"$ {cmd}\nexit status {status}, expected "
                                f"{expected_status(cmd)} (mark an expected failure with "
                                "a trailing '# exit N')\n--- output\n" + "\n".join(actual))
            elif not _matches([e.rstrip() for e in expected], actual):
                failures.append(f"$ {cmd}\n--- expected\n" + "\n".join(expected)
                                + "\n--- actual\n" + "\n".join(actual))
            lines += [f"$ {cmd}", *_elide(expected, actual)]  # continuations kept verbatim
        new_text = new_text.replace(m.group(0), "```console\n" + "\n".join(lines) + "\n```\n", 1)
    if regen and new_text != text:
        page.write_text(new_text, encoding="utf-8")
        return
    assert not failures, f"{page.name}: examples differ (regenerate with --regen-golden)\n\n" + \
        "\n\n".join(failures)


@pytest.mark.parametrize("page", _pages_with("python"), ids=lambda p: p.name)
def test_python_examples(page: Path, tmp_path: Path) -> None:
    _link_repository(tmp_path)
    failures = []
    for i, m in enumerate(PYTHON.finditer(page.read_text(encoding="utf-8")), 1):
        proc = subprocess.run([sys.executable, "-c", m.group(1)], cwd=tmp_path, env=_env(),
                              capture_output=True, text=True, timeout=600)
        if proc.returncode != 0:
            failures.append(f"python block {i} exited with {proc.returncode}:\n"
                            + m.group(1) + "--- stderr\n" + proc.stderr[-3000:])
    assert not failures, f"{page.name}:\n\n" + "\n\n".join(failures)
