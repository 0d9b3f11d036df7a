"""The ``archself`` command line (typer).

Data goes to stdout, diagnostics to stderr. Exit codes (``archself.errors.EXIT_CODES``,
docs/hardening.md): 0 ok, 1 findings or a user error, 2 usage error, 3 internal
error (a bug), 130 interrupted (SIGINT), 143 terminated (SIGTERM). No output is
written onto an input (:mod:`archself.io.outputs`). Heavy libraries (python-control,
filterpy, matplotlib) are imported inside the commands that need them, never at
start-up.

The app and what the commands share are in :mod:`archself.cli.base`; the commands in
:mod:`~archself.cli.files`, :mod:`~archself.cli.runs`, :mod:`~archself.cli.reports`,
:mod:`~archself.cli.campaigns`, :mod:`~archself.cli.calibration`, :mod:`~archself.cli.live` and
:mod:`~archself.cli.ros2`.
They are registered here, in the order ``archself --help`` lists them, each with the
shared ``--quiet``/``--verbose`` options (:func:`~archself.cli.base.with_verbosity`).
"""

from __future__ import annotations

from archself.cli.base import app, main, with_verbosity
from archself.cli.calibration import calibrate, identify
from archself.cli.campaigns import campaign, campaign_report_cmd
from archself.cli.files import docs, export, generate, info, init, schema, validate
from archself.cli.live import live
from archself.cli.reports import report
from archself.cli.ros2 import ros2
from archself.cli.runs import explain, simulate

app.command()(with_verbosity(validate))
app.command()(with_verbosity(schema))
app.command()(with_verbosity(docs))
app.command()(with_verbosity(init))
app.command()(with_verbosity(simulate))
app.command()(with_verbosity(report))
app.command()(with_verbosity(explain))
app.command()(with_verbosity(live))
app.command()(with_verbosity(ros2))
app.command()(with_verbosity(campaign))
app.command("campaign-report")(with_verbosity(campaign_report_cmd))
app.command()(with_verbosity(export))
app.command()(with_verbosity(info))
app.command()(with_verbosity(calibrate))
app.command()(with_verbosity(identify))
app.command()(with_verbosity(generate))

__all__ = ["app", "main"]
