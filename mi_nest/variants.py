"""Which Mitsuba variant mi_nest runs on: LLVM's on the CPU by default, CUDA's on a GPU when asked for.

The plugins need a JIT, monochromatic, unpolarised variant (``*_ad_mono``: the Jones algebra is mi_nest's own).
``MI_NEST_VARIANT`` (a variant's name, or ``auto``: CUDA's when a CUDA device is present) chooses it for every
mi_nest process, those a run starts included (a cluster's local workers, a sweep's cases); ``mi-nest --variant``
sets it for one command. A variant that cannot run here is refused in one line when the work starts
(:func:`require_usable`), never replaced silently by another.
"""
from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi

DEFAULT = "llvm_ad_mono"
GPU = "cuda_ad_mono"
AUTO = "auto"
ENVIRONMENT = "MI_NEST_VARIANT"

# What was wrong with the variant the environment asked for when mi_nest was imported (None: nothing).
_problem: str | None = None


def supported(variant: str | None) -> bool:
    """Whether mi_nest's plugins run on ``variant``."""
    return variant is not None and variant.endswith("_ad_mono")


def choose(requested: str | None) -> str:
    """The variant ``requested`` names (None or empty: :data:`DEFAULT`; ``auto``: :data:`GPU` where a CUDA device
    is present, else :data:`DEFAULT`); ValueError in one line for one mi_nest cannot run on here."""
    if not requested:
        return DEFAULT
    if requested == AUTO:
        return GPU if dr.has_backend(dr.JitBackend.CUDA) else DEFAULT
    usable = [v for v in mi.variants() if supported(v)]
    if requested not in usable:
        raise ValueError(f"mi_nest runs on the variants {', '.join(usable)} or {AUTO}, not '{requested}'")
    if requested.startswith("cuda") and not dr.has_backend(dr.JitBackend.CUDA):
        raise ValueError(f"{requested} needs a CUDA device and its driver, and this machine has none: use {DEFAULT} "
                         f"(or {AUTO}, which takes the GPU where there is one)")
    return requested


def use(requested: str | None) -> str:
    """Switch to :func:`choose`'s variant and make it the environment's, so that the processes this one starts run
    on it too; returns it."""
    global _problem
    variant = choose(requested)
    mi.set_variant(variant)
    os.environ[ENVIRONMENT] = variant
    _problem = None
    return variant


def set_from_environment() -> None:
    """At import: the variant :data:`ENVIRONMENT` asks for, or :data:`DEFAULT` with the problem kept for
    :func:`require_usable` (an import cannot say it in one line)."""
    global _problem
    requested = os.environ.get(ENVIRONMENT)
    try:
        mi.set_variant(choose(requested))
    except ValueError as problem:
        _problem = f"{ENVIRONMENT}={requested}: {problem}"
        mi.set_variant(DEFAULT)


def require_usable() -> None:
    """Raise the environment's variant problem (ValueError), if it had one: work must not start on another."""
    if _problem is not None:
        raise ValueError(_problem)
