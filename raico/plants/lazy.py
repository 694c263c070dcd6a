"""A module imported when one of its names is first used: :class:`LazyModule`.

scipy's linear algebra takes about 0.3 s to import; the modules that compute with it are also
imported by ``raico --help``-like paths that only read names and check options. ``lapack =
LazyModule("scipy.linalg.lapack")`` then ``lapack.dposv(...)``: the first access imports the module
and keeps the attribute on the proxy, so later accesses are plain attribute lookups.
"""

from __future__ import annotations

import importlib
from typing import Any


class LazyModule:
    """Stands for the module ``name`` until an attribute is read; then imports it (once)."""

    def __init__(self, name: str):
        self._lazy_name = name

    def __getattr__(self, attr: str) -> Any:   # only called for names not yet cached here
        if attr.startswith("__"):
            raise AttributeError(attr)
        value = getattr(importlib.import_module(self._lazy_name), attr)
        setattr(self, attr, value)
        return value

    def __repr__(self) -> str:
        return f"<lazy module {self._lazy_name!r}>"
