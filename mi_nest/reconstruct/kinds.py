"""The field kinds a reconstruction trains, by name (``kind=``, ``--kind``), and what each supports.

The representations themselves are ``fields.py``'s classes (``FIELDS`` maps a
kind to its class); the configuration, the loop and the choices ask a kind
what it supports here instead of comparing names.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class FieldKind:
    name: str
    label: str
    # Nodes on a regular lattice: refined coarse to fine, smoothed by their gradients, balanced by the equilibrium
    # prior, fitted to a start field, marched with steps of half their spacing.
    lattice: bool


GRID = FieldKind("grid", "a dense grid of the deviator's nodes", lattice=True)
HASHGRID = FieldKind("hashgrid", "a multiresolution hash grid decoded by a small MLP", lattice=False)
MLP = FieldKind("mlp", "the NeST paper's MLP on a sinusoidal encoding", lattice=False)
KINDS = {kind.name: kind for kind in (GRID, HASHGRID, MLP)}
# Not a kind but a choice among them (fields.choose_kind): a grid unless it would be too large, so what grids
# support is allowed with it, and refused where a run settles on another kind.
AUTO = FieldKind("auto", "a grid, or a hash grid where a grid would be too large", lattice=True)
CHOICES = {**KINDS, AUTO.name: AUTO}


def kind_named(name: str) -> FieldKind:
    """The kind (or ``auto``) called ``name``; anything else is refused with the choices."""
    if name not in CHOICES:
        raise ValueError(f"field kind must be one of {', '.join(CHOICES)}, got '{name}'")
    return CHOICES[name]
