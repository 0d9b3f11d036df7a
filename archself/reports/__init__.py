"""Reports people read, generated from the same data the runtime uses.

Report *models* (plain dataclasses, no text) are kept apart from *rendering*
(Jinja templates in ``templates/``, :mod:`archself.reports.render`):

============================  ==================================================
model                         rendered by
============================  ==================================================
:mod:`~.dsm` (DSM, orderings)  ``dsm.html.j2``, ``dsm.md.j2``, ``dsm.csv.j2``
:mod:`~.graph` (graph, diff)   ``graph.dot.j2`` (then Graphviz ``dot``)
:mod:`~.run` (run report)      ``run_report.html.j2`` + :mod:`~.figures` (matplotlib)
============================  ==================================================

Entry points: :func:`archself.reports.architecture.write_architecture_report`
(``archself report``) and :func:`archself.reports.run_report.write_run_report`
(``archself simulate --report``). Nothing here is imported at CLI start-up.
"""
