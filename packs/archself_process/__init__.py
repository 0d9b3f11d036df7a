"""The liquid-level process pack: module types of ``architectures/process_plant.yaml``.

Registered through the ``archself.modules`` entry-point group like any plugin;
the core never imports this package. :mod:`archself_process.tank` holds the
physics and the hardware, :mod:`archself_process.control` the observer, the
controllers and the setpoint.
"""
