"""What a reconstruction is asked to do: the options of ``mi_nest.optimize``, one documented group per job.

``OptimizeConfig(**options)`` is the one place where the flat options that ``optimize`` and
``mi-nest reconstruct`` take (``iterations=300, kind="mlp"``) meet the groups; a group can also be given
whole (``regulariser=NO_REGULARISER``), and flat options then override its parts.

The defaults are the configuration that met the reconstruction targets (the 100 N disk and the kitten,
docs/reconstruction.md): 20,000 iterations of 2,048 pixels, the learning rate from 0.05 down to 0.002, a
grid whose resolution follows the specimen's shape (:func:`~mi_nest.reconstruct.fields.default_resolution`)
and the :data:`REGULARISED` regulariser, its weights relative to the field's own scale. :data:`FAST_OPTIONS`
meet the same targets, by less, in about a third of the time (docs/performance.md).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields, replace
from typing import get_type_hints

from ..arguments import whole_number
from ..tracer.registry import DIFFERENTIABLE
from .kinds import AUTO, KINDS, MLP, kind_named

# The tracer's methods a reconstruction can differentiate.
FORWARD_MODELS = DIFFERENTIABLE
# The Two-step baseline fits per-view unwrapped retardance through the linear model (two_step.py).
TWO_STEP = "two-step"
METHODS = FORWARD_MODELS + (TWO_STEP,)


def _require_share(name, value, of="the run", closed=False, positive=False):
    """``value`` in [0, 1), or with ``closed`` up to 1 included, and with ``positive`` above 0."""
    above_low = 0 < value if positive else 0 <= value
    if not (above_low and (value <= 1 if closed else value < 1)):
        raise ValueError(f"'{name}' is a share of {of} in {'(' if positive else '['}0, 1{']' if closed else ')'}, "
                         f"got {value}")


def _require_positive(name, value, what="positive"):
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"'{name}' must be {what}, got {value}")


@dataclass(frozen=True)
class Schedule:
    """How long the run lasts and how it goes from easy to hard. Shares are of the run's progress: by
    iterations, or by time where ``time_limit`` ends the run first."""
    iterations: int = 20_000         # the targets reached theirs by 19,538 (kitten) and 18,728 (disk)
    time_limit: float | None = None  # seconds of optimisation after which the run stops early (None: none)
    coarse_to_fine: bool = True      # grids: start at about 8 nodes across, double up to the resolution
    finest_stage: float = 0.5        # coarse to fine: share of the run on the final grid (the coarser share the rest)
    path_curriculum: float = 0.5     # share of the run over which the longest path admitted to the loss grows
    warm_start: float = 0.0          # share of the run fitting the Two-step's unwrapped data before the joint fit
    # A field to start from (a reconstruction directory or a stress file, such as an FEM model of the part): a
    # grid fits it and runs on its final grid alone, without the coarse stages and the path curriculum
    # (reconstruct/start.py).
    start: str | None = None
    # The start is taken at the load factor within 1 +- this whose images fit a sample of the training views best
    # (stress follows the load in linear elasticity, and a model's load is rarely the test's); 0: as given.
    start_scale_range: float = 0.3
    # The test's load over the start's, known from the load cell: a reconstruction of the same part at a lower load
    # (a load series, as photoelasticians count fringes while loading) is multiplied by it before the scan.
    start_load_ratio: float = 1.0
    # Grids: every this share of the run on the final grid (up to 70% of the run), refill the regions that nodes out
    # of equilibrium enclose, where the descent sits on a swapped branch (reconstruct/repair.py); 0: never.
    branch_repair: float = 0.1

    def __post_init__(self):
        whole_number("iterations", self.iterations)
        if self.time_limit is not None and not self.time_limit > 0:
            raise ValueError(f"'time_limit' must be a positive number of seconds, got {self.time_limit}")
        _require_share("path_curriculum", self.path_curriculum, of="the iterations", closed=True)
        _require_share("warm_start", self.warm_start)
        _require_share("finest_stage", self.finest_stage, closed=True, positive=True)
        _require_share("start_scale_range", self.start_scale_range, of="the start's load")
        _require_positive("start_load_ratio", self.start_load_ratio,
                          "the test's load over the start's, a positive number")
        _require_share("branch_repair", self.branch_repair, of="the run", closed=True)


@dataclass(frozen=True)
class Optimiser:
    """Adam on batches of pixels drawn across the training rotations."""
    learning_rate: float = 5e-2      # in units of the stress scale per step
    final_learning_rate: float = 2e-3  # the end of the rate's geometric decay over the run
    batch_size: int = 2048           # pixels per iteration
    views_per_batch: int = 16        # rotations each batch draws its pixels from
    pixel_samples: int | None = None  # rays averaged per pixel as the camera integrates (None: the dataset's spp, <= 4)
    coarse_pixel_samples: int | None = None  # the same in the coarse-to-fine stages before the finest (None: as above)
    mask: str | None = "mask.dolp"   # dataset channel of the pixels that enter the loss and the PSNR (None: all)
    seed: int = 0                    # of the batches and the steps' jitter
    # One CPU thread, so that the gradients' scatter-adds sum in one order and a seeded run of a given number of
    # iterations repeats bit for bit (with two threads their order varies: runs end a few 0.01% apart).
    deterministic: bool = False
    # Weight of the neighbour loss (reconstruct/neighbours.py): the rotation from each of batch_size / 2 pixels'
    # Jones matrix to a neighbour's against the one the measurements give; 0: the intensities alone; None: chosen
    # from the data (fields.settle: NEIGHBOUR_WEIGHT where it applies and the fringes are resolved, else 0).
    neighbour_loss: float | None = None
    neighbour_share: float = 0.5     # the share of the run, from its start, in which the neighbour loss acts

    def __post_init__(self):
        if self.neighbour_loss is not None and not (math.isfinite(self.neighbour_loss) and self.neighbour_loss >= 0):
            raise ValueError(f"neighbour_loss must be a non-negative weight, got {self.neighbour_loss}")
        _require_share("neighbour_share", self.neighbour_share, closed=True, positive=True)
        for name in ("batch_size", "views_per_batch"):
            whole_number(name, getattr(self, name))
        whole_number("seed", self.seed, minimum=0)
        for name in ("pixel_samples", "coarse_pixel_samples"):
            if getattr(self, name) is not None:
                whole_number(name, getattr(self, name))
        for name in ("learning_rate", "final_learning_rate"):
            _require_positive(name, getattr(self, name))


@dataclass(frozen=True)
class ForwardModel:
    """How the rays are marched through the field (docs/methods.md)."""
    method: str = "product"          # product (NeST-general), magnus4, linear (NeST-approx), two-step (baseline)
    step_size: float | None = None   # mm; None: half the grid spacing, or the bounding box / 64
    # nm between the wavelengths a dataset's broad bands (a colour camera's) are traced at; None: the dataset's own
    spectral_step: float | None = None

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got '{self.method}'")
        if self.step_size is not None:
            _require_positive("step_size", self.step_size, "a positive length in mm")
        if self.spectral_step is not None:
            _require_positive("spectral_step", self.spectral_step, "a positive number of nm")


@dataclass(frozen=True)
class FieldConfig:
    """The representation reconstructed. ``kind="auto"`` picks the cheapest that fits
    (:func:`mi_nest.reconstruct.fields.choose_kind`), ``resolution=None`` one for the specimen's shape
    (:func:`mi_nest.reconstruct.fields.default_resolution`); ``optimize`` records what they became."""
    kind: str = AUTO.name             # a name of kinds.KINDS, or auto
    # Nodes along the longest axis of a grid, or of the lattice a network is sampled on (0: a network evaluated at
    # every step, as NeST does).
    resolution: int | None = None
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
        kind_named(self.kind)
        for name in ("levels", "features_per_level", "hashmap_size", "base_resolution", "width", "layers", "octaves"):
            whole_number(name, getattr(self, name))
        if self.resolution is not None:
            whole_number("resolution", self.resolution, minimum=0)
        if self.resolution == 0 and kind_named(self.kind).trains_nodes:
            raise ValueError("a grid's resolution must be at least 2 nodes (0, a network evaluated at every step, is "
                             "for kind=hashgrid or mlp), got 0")
        if self.resolution == 1:
            raise ValueError("resolution must be at least 2 nodes (or 0: a network evaluated at every step), got 1")

    @property
    def on_lattice(self) -> bool:
        """Whether the rays march through values at the nodes of a lattice (a grid, or a network sampled on one):
        refined coarse to fine, smoothed by its gradients, in steps of half its spacing."""
        return self.resolution != 0


@dataclass(frozen=True)
class Regulariser:
    """What keeps a grid off wrapped and flipped minima the intensities alone cannot tell apart. Gradients
    are in stress scales per box width, so the weights do not depend on a specimen's size or sensitivity."""
    smoothness: float = 0.0          # grids: weight of the mean squared gradient
    final_smoothness: float | None = None  # the weight at the end, decayed over the finest stage (None: constant)
    smoothness_edge: float | None = None   # finest stage: gradient above which the penalty grows linearly
    average_last: float = 0.0        # share of the run at its end whose iterates are averaged into the result
    # Grids: weight of the mean squared equilibrium residual |div(s) + grad(p)|^2 inside the specimen, the mean
    # stress p a free unknown beside the deviator s (reconstruct/equilibrium.py). 0: no equilibrium prior.
    equilibrium: float = 0.0
    # Weight of the mean squared shear traction of the deviator on the free surface (stress scales), zero for a
    # body in equilibrium whatever its mean stress (reconstruct/free_surface.py). 0: no free-surface prior.
    free_surface: float = 0.0
    # A grid's RMS (stress scales) up to which the weights hold as given; above it the smoothness falls as the
    # RMS squared and the edge grows with it, so the penalty keeps its share of the loss as the load grows
    # (None: the weights hold at any scale).
    relative_to: float | None = None

    def __post_init__(self):
        if self.relative_to is not None:
            _require_positive("relative_to", self.relative_to, "a positive field RMS in stress scales")
        if not self.smoothness >= 0:
            raise ValueError(f"smoothness must be non-negative, got {self.smoothness}")
        if self.final_smoothness is not None and not 0 < self.final_smoothness <= self.smoothness:
            raise ValueError(f"final_smoothness decays from smoothness ({self.smoothness}) and must lie in "
                             f"(0, smoothness], got {self.final_smoothness}")
        if self.smoothness_edge is not None:
            _require_positive("smoothness_edge", self.smoothness_edge,
                              "a positive gradient (stress scales per box width)")
        _require_share("average_last", self.average_last)
        for name in ("equilibrium", "free_surface"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be a non-negative weight, got {getattr(self, name)}")

    def acts_on_gradients(self) -> bool:
        return bool(self.smoothness) or self.smoothness_edge is not None

    def smoothness_at(self, decayed: float, field_rms: float | None = None) -> float:
        """The smoothness weight once ``decayed`` (0 to 1) of its geometric decay to ``final_smoothness`` is done,
        for a field of RMS ``field_rms`` (used with ``relative_to``)."""
        weight = self.smoothness if self.final_smoothness is None else \
            self.smoothness * (self.final_smoothness / self.smoothness) ** decayed
        return weight / self._growth(field_rms) ** 2

    def equilibrium_at(self, field_rms: float | None = None) -> float:
        """The equilibrium weight for a field of RMS ``field_rms`` (used with ``relative_to``): the residual grows
        with the field as its gradient does, so the weight follows the smoothness's."""
        return self.equilibrium / self._growth(field_rms) ** 2

    def free_surface_at(self, field_rms: float | None = None) -> float:
        """The free-surface weight for a field of RMS ``field_rms`` (used with ``relative_to``): the shear
        traction grows with the field, so the weight falls as its square."""
        return self.free_surface / self._growth(field_rms) ** 2

    def edge_at(self, field_rms: float | None = None) -> float | None:
        """The Charbonnier edge for a field of RMS ``field_rms`` (used with ``relative_to``)."""
        return None if self.smoothness_edge is None else self.smoothness_edge * self._growth(field_rms)

    def _growth(self, field_rms):
        if self.relative_to is None or field_rms is None:
            return 1.0
        return max(1.0, field_rms / self.relative_to)


# The grids' default: the regulariser that met the targets on the disk and the kitten alike
# (docs/reconstruction.md). The smoothness keeps the coarse stages off wrapped and flipped minima, its edge
# spares stress concentrations in the finest stage, the last tenth's iterates are averaged. Its weights were set
# on the 100 N disk (field RMS 0.49 stress scales) and held on the kitten (0.94); above an RMS of 1 they follow
# the field's scale, so that a higher load is not over-smoothed (the 300 N disk, RMS 1.46: 44.8% where the
# fixed weights gave 51.9%, in 3 minutes).
REGULARISED = Regulariser(smoothness=1.3e-4, smoothness_edge=5.0, average_last=0.1, relative_to=1.0)
# The grids' default where the data's fringes alias in more than a tenth of the pixels (fields.settle): the
# smoothness eased from half the field RMS. The 300 N disk (15% aliased) ended at 18.9% error with it against
# 39.7% with REGULARISED (the accuracy suite, 10 minutes each, one run); the stacked disks, on 64 nodes, at 29.6%
# to 30.2% over three seeds against 26.5% (one run).
DENSE_REGULARISED = replace(REGULARISED, relative_to=0.5)
# The neighbour loss's weight where the defaults take it (fields.settle): data whose fringes the pixels resolve (no
# more than DENSE_FRINGES_SHARE aliased), straight rays, one band, a descent (not the Two-step). There it met 15%
# where the intensities alone stopped on a wrapped minimum (the accuracy suite, 10 minutes each: the 300 N disk over
# 90 degrees 8.7% and 6.9% against 54.8% and 55.6%, the Lame cylinder's seeds 1 and 3 2.6% and 2.5% against 34.0%
# and 21.0%) and left the other six such cases as they were (the targets 4.6% and 9.8%, the networks, the bracket,
# Boussinesq); on dense fringes it changed little (the 300 N disk 17.5% against 18.6%) or broke the run where the
# axes turn along the rays (the shaft in torsion 106% against 2.1%, the stacked disks 43.1% against 11% to 30%).
NEIGHBOUR_WEIGHT = 1.0
# The options that give a run's regulariser: one given is the user's, even where it equals the default.
REGULARISER_OPTIONS = frozenset({"regulariser", *(f.name for f in fields(Regulariser))})
# The MLP's default steps evaluated at every step, 50 times smaller than a grid's: at the grids' 0.05 the paper's
# MLP ran away on the disk target (diverged at iteration 100 of a 10-minute run). In 2 minutes (104 iterations on
# 2 cores) it ended at 180%, 173%, 123% and 96% error from 0.03, 0.01, 3e-3 and 1e-3
# (experiments/network_learning_rate.py): none learned the field in that budget, and the smallest strayed least.
MLP_EVERY_STEP_OPTIMISER = Optimiser(learning_rate=1e-3, final_learning_rate=4e-5)
# Sampled on a lattice the MLP makes thousands of steps, and larger ones pay: on the disk target's data in 3 minutes
# (Intel Xeon, 2 cores; seeds 0 and 1) it ended at 15.7% and 17.8% from 1e-3, 9.2% and 9.2% from 3e-3, 7.8% and
# 7.4% from 1e-2, 6.1% and 6.4% from 3e-2, 7.4% (seed 0) from 5e-2 and 88% from 0.1, each decaying 25-fold over the
# run (experiments/sweeps/mlp_learning_rate.toml). But the decay follows the budget: in 10 minutes 3e-2 stayed above
# 1.5e-2 for 8,000 iterations, its loss jumped up twice there, and it ended at 35.0%. 1e-2 stays below that.
MLP_OPTIMISER = Optimiser(learning_rate=1e-2, final_learning_rate=4e-4)
# The learning rate of a run with a start field where none was given (fields.settle): a tenth of the descent's,
# since the start is already near the answer and the descent's first steps threw it off. One run each against the
# descent's rate: the kitten in air from a model at 80% of its load 8.9% against 16.3% (10 minutes), from its own
# reconstruction at a third of the load 14.8% against 17.6%, the 1 kN disk at 256 px from its reconstruction at
# 100 N 4.7% against 5.3% (6 minutes each), the 600 N disk from a model at 80% of its load 10.1% against 10.3%
# (3 minutes; docs/reconstruction.md, "A start from a model of the part" and "A load series"). Whole load series at
# it: the 600 N disk 4.9%, the 300 N disk 4.7%, over 90 degrees 5.5% (5.6%, 4.7%, 5.6% in earlier runs at 0.05); the
# stacked disks 7.3% against 6.4% at 0.05 the same day, their start (19%) far from the answer, still descending.
STARTED_LEARNING_RATE = 5e-3
# The options that give a run's learning rate: one given is the user's, even where it equals the default.
LEARNING_RATE_OPTIONS = frozenset({"optimiser", "learning_rate"})
# The plain fit: the default of hash grids and MLPs, which the smoothness does not act on.
NO_REGULARISER = Regulariser()

# The defaults' schedule made about 3 times faster (``mi-nest reconstruct --fast``): one ray per pixel in the coarse
# stages, which only choose the branch, and fewer of them (the finest stage 70% of the run, the path curriculum
# over the coarse 30%); half the pixels a batch, for more Adam steps (batch noise did not limit); a higher final
# learning rate with the last 45% of the iterates averaged. Side by side with the defaults (docs/performance.md,
# "Time to the targets"): the disk and the kitten targets met in about a third of the defaults' time.
FAST_OPTIONS = {"iterations": 10_800, "finest_stage": 0.7, "path_curriculum": 0.3, "batch_size": 1024,
                "coarse_pixel_samples": 1, "final_learning_rate": 1e-2, "average_last": 0.45}


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
        that several groups share (``seed``) sets it in each. Unknown names are refused. The regulariser
        defaults to :data:`REGULARISED` on a lattice (grids, ``kind="auto"``, and networks sampled on one) and to
        :data:`NO_REGULARISER` for networks evaluated at every step (``resolution=0``): :data:`REGULARISED` with
        those means the plain fit, so a configuration can change its kind. Likewise the optimiser defaults to
        :data:`MLP_OPTIMISER`'s learning rates for MLPs on a lattice, :data:`MLP_EVERY_STEP_OPTIMISER`'s for MLPs
        evaluated at every step."""
        groups = get_type_hints(OptimizeConfig)
        names = {name: {f.name for f in fields(group)} for name, group in groups.items()}
        unknown = sorted(set(options) - set(groups) - set().union(*names.values()))
        if unknown:
            raise ValueError(f"unknown option(s) {unknown}; optimize accepts "
                             f"{sorted(set().union(*names.values()))} and the groups {list(groups)}")
        # The field first: the regulariser's and the optimiser's defaults follow its kind.
        for name in sorted(groups, key=lambda name: name != "field"):
            group, given = groups[name], options.get(name)
            if name == "regulariser" and given in (None, REGULARISED):
                given = REGULARISED if self.field.on_lattice else NO_REGULARISER
            elif name == "optimiser" and self.field.kind == MLP.name and given in (None, Optimiser()):
                given = MLP_OPTIMISER if self.field.on_lattice else MLP_EVERY_STEP_OPTIMISER
            elif given is None:
                given = group()
            elif not isinstance(given, group):
                raise TypeError(f"'{name}' must be a {group.__name__}, got {type(given).__name__}")
            object.__setattr__(self, name, replace(given, **{k: v for k, v in options.items() if k in names[name]}))
        # Another kind's options, given for a kind that does not read them, would be dropped without a word.
        kind = kind_named(self.field.kind)
        others = set().union(*(names[name] for name in groups if name != "field"))
        foreign = sorted(set(options) & names["field"] - {"kind"} - kind.options.names() - others)
        if kind is not AUTO and foreign:
            readers = {name: [k.name for k in KINDS.values() if name in k.options.names()] for name in foreign}
            kinds = sorted({reader for names_ in readers.values() for reader in names_})
            raise ValueError(f"a '{kind.name}' field does not read "
                             + ", ".join(f"'{name}' ({' and '.join(r)}'s)" for name, r in readers.items())
                             + f"; leave {'it' if len(foreign) == 1 else 'them'} out, or give kind="
                             + " or ".join(kinds))
        self._check_across_groups()

    def _check_across_groups(self):
        if self.optimiser.deterministic and self.schedule.time_limit is not None:
            raise ValueError("a deterministic run repeats a fixed number of iterations, and a time limit ends it "
                             "wherever the clock says: drop the time limit (--minutes) or deterministic")
        if self.schedule.warm_start and self.model.method == TWO_STEP:
            raise ValueError("'warm_start' starts a joint fit (product, magnus4, linear) from the Two-step fit; "
                             "method 'two-step' is that fit already")
        trains_nodes = kind_named(self.field.kind).trains_nodes
        if self.schedule.start is not None and not trains_nodes:
            raise ValueError(f"a start field is fitted by grids only, and this field is a '{self.field.kind}' "
                             "(give kind='grid', or drop start)")
        if self.schedule.start is not None and self.schedule.warm_start:
            raise ValueError("'start' and 'warm_start' both say where the run starts: give one")
        if self.schedule.start is None and self.schedule.start_load_ratio != 1.0:
            raise ValueError("'start_load_ratio' scales a start field, and no start is given (give start, or drop "
                             "start_load_ratio)")
        if not trains_nodes and self.regulariser.equilibrium:
            raise ValueError(f"the equilibrium prior acts on grids only, and this field is a '{self.field.kind}' "
                             "(give kind='grid', or equilibrium=0)")
        if not self.field.on_lattice and self.regulariser.acts_on_gradients():
            # Silently ignored, a regulariser the user asked for would leave them comparing unlike runs.
            raise ValueError(f"the smoothness regulariser acts on a lattice's nodes, and this '{self.field.kind}' "
                             "field is evaluated at every step (resolution=0): give a resolution, or drop "
                             "smoothness, final_smoothness and smoothness_edge")

    def settled(self, kind: str, resolution: int) -> OptimizeConfig:
        """This configuration with the field's kind and resolution decided (what a run records)."""
        return OptimizeConfig(**{**self._groups(), "field": replace(self.field, kind=kind, resolution=resolution)})

    def _groups(self):
        return {name: getattr(self, name) for name in get_type_hints(OptimizeConfig)}

    def to_dict(self) -> dict:
        """The groups as plain JSON values (what ``reconstruction.json`` and checkpoints record)."""
        return json.loads(json.dumps(asdict(self)))

    @classmethod
    def from_dict(cls, record: dict) -> OptimizeConfig:
        """What :meth:`to_dict` wrote, or the flat options that results written before the groups recorded."""
        groups = get_type_hints(cls)
        if set(groups) <= set(record):
            # Records from before the neighbour loss fitted none.
            record = {**record, "optimiser": {"neighbour_loss": 0.0, **record["optimiser"]}}
            return cls(**{name: group(**record[name]) for name, group in groups.items()})
        # Before the groups: flat options, with the field's (and the regulariser's smoothness) under "field";
        # what they did not record was not done then (no regulariser).
        old = record.get("field", {})
        own = {f.name for f in fields(FieldConfig)}
        return cls(**{"regulariser": NO_REGULARISER, "neighbour_loss": 0.0,
                      **{k: v for k, v in record.items() if k != "field"},
                      "field": FieldConfig(**{k: v for k, v in old.items() if k in own}),
                      **{k: v for k, v in old.items() if k not in own}})


def option_names() -> list[str]:
    """The flat options :class:`OptimizeConfig` takes, every group's fields."""
    return sorted({f.name for group in get_type_hints(OptimizeConfig).values() for f in fields(group)})


def option_value(name: str, text: str) -> object:
    """``text`` (from a command line's ``--option NAME=VALUE``) as the type of option ``name``: ``none`` for
    an option that may be unset."""
    hints = {f.name: hint for group in get_type_hints(OptimizeConfig).values()
             for f, hint in zip(fields(group), get_type_hints(group).values())}
    if name not in hints:
        raise ValueError(f"unknown option '{name}'; the options are {', '.join(option_names())}")
    hint = hints[name]
    if text.strip().lower() == "none" and type(None) in getattr(hint, "__args__", ()):
        return None
    kind = next((t for t in (bool, int, float, str) if t is hint or t in getattr(hint, "__args__", ())), str)
    if kind is bool:
        if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
            raise ValueError(f"option '{name}' is true or false, got '{text}'")
        return text.lower() in ("true", "1", "yes")
    try:
        return kind(text)
    except ValueError:
        raise ValueError(f"option '{name}' takes {'an integer' if kind is int else 'a number'}, got '{text}'") from None
