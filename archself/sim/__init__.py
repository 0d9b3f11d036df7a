"""The simulated world: fault injection from scenarios and the simulation driver.

:mod:`archself.system.live` turns scenario fault entries into output
transformations; :mod:`archself.sim.run` steps a compiled
:class:`~archself.system.live.LiveSystem` through a scenario and records the trace.
"""
