"""Generic building blocks, independent of any domain.

The block library: LTI plants and models (:mod:`~archself_blocks.lti`), PID
(:mod:`~archself_blocks.pid`), Kalman filter and Luenberger observer
(:mod:`~archself_blocks.estimators`), sensor (:mod:`~archself_blocks.sensors`),
actuator (:mod:`~archself_blocks.actuators`), reference and static blocks
(:mod:`~archself_blocks.signals`), all as ``generic.*`` types; see docs/blocks.md.
``generic.relay`` (:class:`~archself_blocks.relay.Relay`) lets synthetic graphs of
any size (``archself generate``) validate, compile and run. Registered through
the ``archself.modules`` entry-point group like any plugin.
"""
