"""Mitsuba plugins of mi_nest, one module per XML plugin type.

Each module registers its plugin at import time (at the bottom, like Mitsuba's
own Python integrators). Plugin classes derive from variant-specific Mitsuba
base classes, so :func:`register` re-imports them whenever the variant changes.
"""
from __future__ import annotations

import importlib
import sys

MODULES = ("stress", "specimen", "polariscope_light", "polariscope", "photoelastic")


def register() -> None:
    """Import (or re-import) every plugin module, registering it for the current variant."""
    for name in MODULES:
        full_name = f"{__name__}.{name}"
        if full_name in sys.modules:
            importlib.reload(sys.modules[full_name])
        else:
            importlib.import_module(full_name)
