"""Recording metadata: plain JSON, checked and normalised where it enters.

Metadata travels with the data through netCDF, XML and databases, so it must be
JSON: numpy scalars and arrays are converted, NaN/inf and non-string keys are
refused with a message naming where they are.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from .errors import ConfigError

__all__ = ["meta_to_json"]


def _jsonable(obj: Any, path: str) -> Any:
    """Return `obj` as plain JSON types (numpy scalars/arrays converted)."""
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        if not math.isfinite(obj):
            raise ConfigError(f"{path} = {float(obj)!r}: JSON has no NaN/inf "
                              "(use None for unknown)")
        return float(obj)
    if isinstance(obj, Mapping):
        out = {}
        for key, value in obj.items():
            if not isinstance(key, str):
                raise ConfigError(f"{path} has key {key!r} of type {type(key).__name__}; "
                                  "metadata keys must be strings")
            out[key] = _jsonable(value, f"{path}[{key!r}]")
        return out
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_jsonable(v, f"{path}[{i}]") for i, v in enumerate(obj)]
    raise ConfigError(f"{path} is a {type(obj).__name__} ({obj!r:.60}), not JSON-serialisable; "
                      "metadata holds str, numbers, bool, None, lists and dicts")


def meta_to_json(meta: Mapping | None) -> str:
    """``meta`` (a mapping, or None for ``{}``) as a JSON string; ConfigError naming a bad entry.

    Parameters
    ----------
    meta : mapping or None
        JSON-serialisable metadata (numpy scalars and arrays are converted).

    Returns
    -------
    str
    """
    if meta is None:
        return "{}"
    if not isinstance(meta, Mapping):
        raise ConfigError(f"meta must be a mapping (dict), got {type(meta).__name__}")
    return json.dumps(_jsonable(meta, "meta"), ensure_ascii=False, allow_nan=False)
