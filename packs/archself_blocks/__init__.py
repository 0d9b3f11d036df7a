"""Generic building blocks, independent of any domain.

``generic.relay`` (:class:`~archself_blocks.relay.Relay`) lets synthetic graphs of
any size (``archself generate``) validate, compile and run. Registered through
the ``archself.modules`` entry-point group like any plugin.
"""
