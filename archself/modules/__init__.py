"""The module interface: :class:`~archself.modules.base.RuntimeModule`.

The core ships no module library. Module types come from packs and plugins
through the ``archself.modules`` entry-point group (:mod:`archself.registry`);
the packs shipped with archself live in ``packs/`` (``archself_diffdrive``,
``archself_process``, ``archself_blocks``).
"""
