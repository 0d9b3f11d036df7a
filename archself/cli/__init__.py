"""The ``archself`` command line (typer).

Data goes to stdout, diagnostics to stderr. Exit codes (``archself.errors.EXIT_CODES``,
docs/hardening.md): 0 ok, 1 findings or a user error, 2 usage error, 3 internal
error (a bug), 130 interrupted (SIGINT), 143 terminated (SIGTERM). No output is
written onto an input (:mod:`archself.io.files`). Heavy libraries (python-control,
filterpy, matplotlib) are imported inside the commands that need them, never at
start-up.

The app and what the commands share are in :mod:`archself.cli.base`; the commands in
:mod:`~archself.cli.files`, :mod:`~archself.cli.runs`, :mod:`~archself.cli.reports`,
:mod:`~archself.cli.campaigns`, :mod:`~archself.cli.calibration` and
:mod:`~archself.cli.live` (live, ros2).
They are registered by :func:`~archself.cli.base.register`, in the order ``archself
--help`` lists them (:data:`~archself.cli.base.COMMANDS`), each with the shared
``--quiet``/``--verbose`` options (:func:`~archself.cli.base.with_verbosity`).
``archself.cli.app`` is the app with every command; :func:`main` (the ``archself``
script) imports only the module of the command it runs.
"""

from __future__ import annotations

from typing import Any

from archself.cli.base import COMMANDS, main, register

__all__ = ["COMMANDS", "app", "main", "register"]


def __getattr__(name: str) -> Any:
    if name == "app":
        return register()
    raise AttributeError(f"module 'archself.cli' has no attribute {name!r}")
