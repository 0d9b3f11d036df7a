"""Size of a package as a newcomer meets it: files, lines, code lines, long functions.

Code lines are the lines that hold a token other than a comment, a docstring, a newline
or indentation (tokenize), so docstrings and comments do not count; functions are
measured with ast (``end_lineno - lineno + 1``, docstring included).

Usage::

    python tools/code_size.py [archself] [--over 80]
"""

from __future__ import annotations

import argparse
import ast
import io
import tokenize
from pathlib import Path


def docstring_lines(tree: ast.AST) -> set[int]:
    """Line numbers that belong to docstrings of modules, classes and functions."""
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = getattr(node, "body", [])
            if body and isinstance(body[0], ast.Expr) and isinstance(
                    getattr(body[0], "value", None), ast.Constant) and isinstance(
                    body[0].value.value, str):
                out.update(range(body[0].lineno, body[0].end_lineno + 1))
    return out


def code_lines(text: str) -> int:
    """Lines with code (no comment-only, blank or docstring lines)."""
    skip = docstring_lines(ast.parse(text))
    lines: set[int] = set()
    ignore = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT,
              tokenize.DEDENT, tokenize.ENCODING, tokenize.ENDMARKER}
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type in ignore:
            continue
        for ln in range(tok.start[0], tok.end[0] + 1):
            if ln not in skip:
                lines.add(ln)
    return len(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", nargs="?", default="archself")
    ap.add_argument("--over", type=int, default=80, help="list functions longer than this")
    args = ap.parse_args()
    files = sorted(Path(args.root).rglob("*.py"))
    total = code = 0
    long: list[tuple[int, str]] = []
    for p in files:
        text = p.read_text(encoding="utf-8")
        total += text.count("\n")
        code += code_lines(text)
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > args.over:
                    long.append((n, f"{p}:{node.lineno} {node.name}"))
    print(f"{args.root}: {len(files)} files, {total} lines, {code} code lines, "
          f"{len(list(Path(args.root).glob('*.py')))} files at the root")
    print(f"functions over {args.over} lines: {len(long)}")
    for n, where in sorted(long, reverse=True):
        print(f"  {n:4d}  {where}")


if __name__ == "__main__":
    main()
