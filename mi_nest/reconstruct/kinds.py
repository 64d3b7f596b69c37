"""The field kinds a reconstruction trains, by name (``kind=``, ``--kind``), and what each supports.

The representations themselves are ``fields.py``'s classes (``FIELDS`` maps a
kind to its class); the configuration, the loop and the choices ask a kind
what it supports here instead of comparing names.
"""
from __future__ import annotations

from dataclasses import dataclass, fields


@dataclass(frozen=True)
class KindOptions:
    """A kind's own options, read from the flat ``FieldConfig`` a run takes and records (where their defaults
    live): each representation reads these and nothing else."""

    @classmethod
    def of(cls, config) -> KindOptions:
        return cls(**{f.name: getattr(config, f.name) for f in fields(cls)})

    @classmethod
    def names(cls) -> set[str]:
        return {f.name for f in fields(cls)}


@dataclass(frozen=True)
class GridOptions(KindOptions):
    resolution: int             # nodes along the longest axis


@dataclass(frozen=True)
class NetworkOptions(KindOptions):
    # Nodes along the longest axis of the lattice the network is sampled on once an iteration, the rays marching
    # through those samples as through a grid's nodes; 0: the network evaluated at every step of every ray.
    resolution: int


@dataclass(frozen=True)
class HashGridOptions(NetworkOptions):
    levels: int
    features_per_level: int
    hashmap_size: int           # entries per level
    base_resolution: int
    level_scale: float          # resolution ratio between levels
    width: int                  # the decoder's hidden units
    seed: int                   # of the initial weights


@dataclass(frozen=True)
class MLPOptions(NetworkOptions):
    width: int                  # hidden units per layer
    layers: int
    octaves: int                # of the sinusoidal encoding
    seed: int


@dataclass(frozen=True)
class FieldKind:
    name: str
    label: str
    # Its parameters are the nodes of a regular lattice: fitted to a start field, refilled by branch repair,
    # balanced by the equilibrium prior. (What is marched on a lattice, refined coarse to fine and smoothed by its
    # gradients: FieldConfig.on_lattice, a grid or a network sampled on one.)
    trains_nodes: bool
    options: type[KindOptions]


GRID = FieldKind("grid", "a dense grid of the deviator's nodes", trains_nodes=True, options=GridOptions)
HASHGRID = FieldKind("hashgrid", "a multiresolution hash grid decoded by a small MLP", trains_nodes=False,
                     options=HashGridOptions)
MLP = FieldKind("mlp", "the NeST paper's MLP on a sinusoidal encoding", trains_nodes=False,
                options=MLPOptions)
KINDS = {kind.name: kind for kind in (GRID, HASHGRID, MLP)}
# Not a kind but a choice among them (fields.choose_kind): a grid unless it would be too large, so what grids
# support is allowed with it, and refused where a run settles on another kind; it may read any kind's options.
AUTO = FieldKind("auto", "a grid, or a hash grid where a grid would be too large", trains_nodes=True,
                 options=KindOptions)
CHOICES = {**KINDS, AUTO.name: AUTO}


def kind_named(name: str) -> FieldKind:
    """The kind (or ``auto``) called ``name``; anything else is refused with the choices."""
    if name not in CHOICES:
        raise ValueError(f"field kind must be one of {', '.join(CHOICES)}, got '{name}'")
    return CHOICES[name]
