"""Deterministic random streams: a process-independent hash and the stream of each name.

Each module gets ``numpy.random.default_rng([seed, stable_hash(name)])``; edges and
faults get their own streams the same way (``edge:…``, ``fault:…`` names).
"""

from __future__ import annotations

import hashlib

import numpy as np

__all__ = ["module_rng", "stable_hash"]


def stable_hash(text: str) -> int:
    """A 64-bit hash of ``text`` that is the same in every process (unlike ``hash``).

    Examples
    --------
    >>> stable_hash("imu") == stable_hash("imu")
    True
    """
    return int.from_bytes(hashlib.blake2b(text.encode("utf-8"), digest_size=8).digest(), "little")


def module_rng(seed: int, name: str) -> np.random.Generator:
    """The deterministic random stream of module (or edge, fault) ``name`` for ``seed``."""
    return np.random.default_rng([int(seed), stable_hash(name)])
