"""The simulated world: fault injection from scenarios and the simulation driver.

:mod:`archself.sim.faults` turns scenario fault entries into output
transformations; :mod:`archself.sim.run` steps a compiled
:class:`~archself.system.LiveSystem` through a scenario and records the trace.
"""
