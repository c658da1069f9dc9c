"""Tie the on-disk cache of the compiled simulator loops to the source of the physics they call.

numba's cache (``@njit(cache=True)``) is invalidated when the file that
defines a function changes, but not when a compiled function it calls from
another module does: after an edit to :mod:`drivesense.machine.friction`
alone, the simulators would keep running the old friction from their cache.
numba does key each cache entry on the contents of the function's closure,
so the simulator loops are defined inside a factory that closes over
:func:`source_digest` of the modules they call::

    def _make_loop(physics_source: str):
        @njit(cache=True)
        def _loop(...):
            physics_source      # part of the cache key
            ...
        return _loop

    _loop = _make_loop(source_digest(friction, encoders))

An unchanged digest loads the cached machine code; a changed one compiles afresh.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from types import ModuleType

__all__ = ["source_digest"]


def source_digest(*modules: ModuleType) -> str:
    """SHA-256 of the source files of ``modules``, in the order given.

    Parameters
    ----------
    *modules : module
        Imported modules with a ``__file__``.

    Returns
    -------
    str
        Hex digest (64 characters).
    """
    h = hashlib.sha256()
    for mod in modules:
        path = Path(mod.__file__)
        h.update(f"{mod.__name__}\0".encode())
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()
