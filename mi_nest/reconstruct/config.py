"""What a reconstruction is asked to do: the options of ``mi_nest.optimize``, one documented group per job.

``OptimizeConfig(**options)`` is the one place where the flat options that ``optimize`` and
``mi-nest reconstruct`` take (``iterations=300, kind="mlp"``) meet the groups; a group can also be given
whole (``regulariser=REGULARISED``), and flat options then override its parts.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields, replace
from typing import get_type_hints

from ..arguments import whole_number

FORWARD_MODELS = ("product", "magnus4", "linear")
# The Two-step baseline fits per-view unwrapped retardance through the linear model (two_step.py).
METHODS = FORWARD_MODELS + ("two-step",)
KINDS = ("grid", "hashgrid", "mlp")


def _require_share(name, value, of="the run", closed=False):
    if not (0 <= value <= 1 if closed else 0 <= value < 1):
        raise ValueError(f"'{name}' is a share of {of} in [0, 1{']' if closed else ')'}, got {value}")


def _require_positive(name, value):
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"'{name}' must be positive, got {value}")


@dataclass(frozen=True)
class Schedule:
    """How long the run lasts and how it goes from easy to hard. Shares are of the run's progress: by
    iterations, or by time where ``time_limit`` ends the run first."""
    iterations: int = 600
    time_limit: float | None = None  # seconds of optimisation after which the run stops early (None: none)
    coarse_to_fine: bool = True      # grids: start at about 8 nodes across, double up to the resolution
    path_curriculum: float = 0.5     # share of the run over which the longest path admitted to the loss grows
    warm_start: float = 0.0          # share of the run fitting the Two-step's unwrapped data before the joint fit

    def __post_init__(self):
        whole_number("iterations", self.iterations)
        if self.time_limit is not None and not self.time_limit > 0:
            raise ValueError(f"'time_limit' must be a positive number of seconds, got {self.time_limit}")
        _require_share("path_curriculum", self.path_curriculum, of="the iterations", closed=True)
        _require_share("warm_start", self.warm_start)


@dataclass(frozen=True)
class Optimiser:
    """Adam on batches of pixels drawn across the training rotations."""
    learning_rate: float = 3e-2      # in units of the stress scale per step
    final_learning_rate: float = 3e-3  # the end of the rate's geometric decay over the run
    batch_size: int = 4096           # pixels per iteration
    views_per_batch: int = 16        # rotations each batch draws its pixels from
    pixel_samples: int | None = None  # rays averaged per pixel as the camera integrates (None: the dataset's spp, <= 4)
    mask: str | None = "mask.dolp"   # dataset channel of the pixels that enter the loss and the PSNR (None: all)
    seed: int = 0                    # of the batches and the steps' jitter

    def __post_init__(self):
        for name in ("batch_size", "views_per_batch"):
            whole_number(name, getattr(self, name))
        whole_number("seed", self.seed, minimum=0)
        if self.pixel_samples is not None:
            whole_number("pixel_samples", self.pixel_samples)
        for name in ("learning_rate", "final_learning_rate"):
            _require_positive(name, getattr(self, name))


@dataclass(frozen=True)
class ForwardModel:
    """How the rays are marched through the field (docs/methods.md)."""
    method: str = "product"          # product (NeST-general), magnus4, linear (NeST-approx), two-step (baseline)
    step_size: float | None = None   # mm; None: half the grid spacing, or the bounding box / 64

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got '{self.method}'")
        if self.step_size is not None and not (math.isfinite(self.step_size) and self.step_size > 0):
            raise ValueError(f"'step_size' must be a positive length in mm, got {self.step_size}")


@dataclass(frozen=True)
class FieldConfig:
    """The representation reconstructed. ``kind="auto"`` picks the cheapest that fits
    (:func:`mi_nest.reconstruct.fields.choose_kind`)."""
    kind: str = "auto"
    resolution: int = 32             # grid: nodes along the longest axis
    levels: int = 8                  # hashgrid
    features_per_level: int = 2      # hashgrid
    hashmap_size: int = 2 ** 15      # hashgrid: entries per level
    base_resolution: int = 4         # hashgrid
    level_scale: float = 1.5         # hashgrid: resolution ratio between levels
    width: int = 64                  # MLPs: hidden units per layer
    layers: int = 3                  # mlp: hidden layers (hashgrid: 1)
    octaves: int = 6                 # mlp: sinusoidal encoding octaves
    seed: int = 0                    # of the networks' initial weights

    def __post_init__(self):
        if self.kind not in KINDS + ("auto",):
            raise ValueError(f"field kind must be one of {KINDS + ('auto',)}, got '{self.kind}'")
        for name in ("resolution", "levels", "features_per_level", "hashmap_size", "base_resolution", "width",
                     "layers", "octaves"):
            whole_number(name, getattr(self, name))
        if self.resolution < 2:
            raise ValueError(f"grid resolution must be at least 2, got {self.resolution}")


@dataclass(frozen=True)
class Regulariser:
    """What keeps a grid off wrapped and flipped minima the intensities alone cannot tell apart. Gradients
    are in stress scales per box width, so the weights do not depend on a specimen's size or sensitivity."""
    smoothness: float = 0.0          # grids: weight of the mean squared gradient
    final_smoothness: float | None = None  # the weight at the end, decayed over the finest stage (None: constant)
    smoothness_edge: float | None = None   # finest stage: gradient above which the penalty grows linearly
    average_last: float = 0.0        # share of the run at its end whose iterates are averaged into the result
    # A grid's RMS (stress scales) up to which the weights hold as given; above it the smoothness falls as the
    # RMS squared and the edge grows with it, so the penalty keeps its share of the loss as the load grows
    # (None: the weights hold at any scale).
    relative_to: float | None = None

    def __post_init__(self):
        if self.relative_to is not None and not (math.isfinite(self.relative_to) and self.relative_to > 0):
            raise ValueError(f"relative_to is a field RMS in stress scales and must be positive, got {self.relative_to}")
        if not self.smoothness >= 0:
            raise ValueError(f"smoothness must be non-negative, got {self.smoothness}")
        if self.final_smoothness is not None and not 0 < self.final_smoothness <= self.smoothness:
            raise ValueError(f"final_smoothness decays from smoothness ({self.smoothness}) and must lie in "
                             f"(0, smoothness], got {self.final_smoothness}")
        if self.smoothness_edge is not None and not (math.isfinite(self.smoothness_edge) and self.smoothness_edge > 0):
            raise ValueError(f"smoothness_edge is a gradient (stress scales per box width) and must be positive, "
                             f"got {self.smoothness_edge}")
        _require_share("average_last", self.average_last)

    def acts_on_gradients(self) -> bool:
        return bool(self.smoothness) or self.smoothness_edge is not None

    def smoothness_at(self, decayed: float, field_rms: float | None = None) -> float:
        """The smoothness weight once ``decayed`` (0 to 1) of its geometric decay to ``final_smoothness`` is done,
        for a field of RMS ``field_rms`` (used with ``relative_to``)."""
        weight = self.smoothness if self.final_smoothness is None else \
            self.smoothness * (self.final_smoothness / self.smoothness) ** decayed
        return weight / self._growth(field_rms) ** 2

    def edge_at(self, field_rms: float | None = None) -> float | None:
        """The Charbonnier edge for a field of RMS ``field_rms`` (used with ``relative_to``)."""
        return None if self.smoothness_edge is None else self.smoothness_edge * self._growth(field_rms)

    def _growth(self, field_rms):
        if self.relative_to is None or field_rms is None:
            return 1.0
        return max(1.0, field_rms / self.relative_to)


# A grid regulariser that met the targets on the disk and the kitten alike (docs/reconstruction.md).
# The smoothness keeps the coarse stages off wrapped and flipped minima, its edge spares stress concentrations
# in the finest stage, the last tenth's iterates are averaged. Not the default: it hurt the 300 N disk.
REGULARISED = Regulariser(smoothness=1.3e-4, smoothness_edge=5.0, average_last=0.1)


@dataclass(frozen=True)
class Reporting:
    """What the run records besides the field."""
    checkpoint_every: int = 100      # iterations between checkpoints (a rerun resumes from the last)
    track_error_every: int = 0       # with a ground truth: iterations between records of the stress error (0: never)
    evaluate_views: int = 16         # held-out rotations rendered for the PSNR

    def __post_init__(self):
        whole_number("checkpoint_every", self.checkpoint_every)
        for name in ("track_error_every", "evaluate_views"):
            whole_number(name, getattr(self, name), minimum=0)


@dataclass(frozen=True, init=False)
class OptimizeConfig:
    """Everything :func:`mi_nest.optimize` is asked to do, one group per job."""
    schedule: Schedule
    optimiser: Optimiser
    model: ForwardModel
    field: FieldConfig
    regulariser: Regulariser
    reporting: Reporting

    def __init__(self, **options):
        """Groups given whole by name, then flat options by their own names, which override them; a name
        that several groups share (``seed``) sets it in each. Unknown names are refused."""
        groups = get_type_hints(OptimizeConfig)
        names = {name: {f.name for f in fields(group)} for name, group in groups.items()}
        unknown = sorted(set(options) - set(groups) - set().union(*names.values()))
        if unknown:
            raise ValueError(f"unknown option(s) {unknown}; optimize accepts "
                             f"{sorted(set().union(*names.values()))} and the groups {list(groups)}")
        for name, group in groups.items():
            given = options.get(name)
            if given is None:
                given = group()
            elif not isinstance(given, group):
                raise TypeError(f"'{name}' must be a {group.__name__}, got {type(given).__name__}")
            object.__setattr__(self, name, replace(given, **{k: v for k, v in options.items() if k in names[name]}))
        self._check_across_groups()

    def _check_across_groups(self):
        if self.schedule.warm_start and self.model.method == "two-step":
            raise ValueError("'warm_start' starts a joint fit (product, magnus4, linear) from the Two-step fit; "
                             "method 'two-step' is that fit already")
        if self.field.kind in ("hashgrid", "mlp") and self.regulariser.acts_on_gradients():
            # Silently ignored, a regulariser the user asked for would leave them comparing unlike runs.
            raise ValueError(f"the smoothness regulariser acts on grids only, and this field is a "
                             f"'{self.field.kind}' (give kind='grid', or drop smoothness, final_smoothness and "
                             "smoothness_edge)")

    def to_dict(self) -> dict:
        """The groups as plain JSON values (what ``reconstruction.json`` and checkpoints record)."""
        return json.loads(json.dumps(asdict(self)))

    @classmethod
    def from_dict(cls, record: dict) -> OptimizeConfig:
        """What :meth:`to_dict` wrote, or the flat options that results written before the groups recorded."""
        groups = get_type_hints(cls)
        if set(groups) <= set(record):
            return cls(**{name: group(**record[name]) for name, group in groups.items()})
        # Before the groups: flat options, with the field's (and the regulariser's smoothness) under "field".
        return cls(**{**{k: v for k, v in record.items() if k != "field"}, **record.get("field", {})})
