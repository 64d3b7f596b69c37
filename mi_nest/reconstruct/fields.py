"""Trainable stress fields: dense grid, multi-resolution hash grid, and the NeST MLP.

Every representation is trace-free (NeST): it stores the five deviatoric
components ``(xx, yy, yz, zx, xy)`` and sets ``zz = -xx - yy``. The mean stress
does not change birefringence, so nothing else could be recovered. Values are
stored in units of ``stress_scale`` (MPa), the stress that gives about one
fringe across the specimen, so that learning rates do not depend on the
material or the load. Fields are only ever evaluated inside the specimen (rays
march only there); :func:`sample_inside` and the metrics apply the occupancy.

The interface is :class:`StressField`'s ``eval(p)`` plus what an optimiser
needs: ``parameters()`` (name -> Dr.Jit array), ``assign(values)`` (attach the
optimiser's variables), ``state()``/``from_state()`` (NumPy, for checkpoints).
"""
from __future__ import annotations

from dataclasses import asdict, replace
from dataclasses import fields as dataclass_fields

import drjit as dr
import drjit.nn as nn
import mitsuba as mi
import numpy as np

from ..fields.base import StressField
from ..io.grid import grid_nodes
from ..physics.aliasing import UNRESOLVED_SHARE
from . import equilibrium
from .config import (DENSE_REGULARISED, NEIGHBOUR_WEIGHT, REGULARISED, STARTED_LEARNING_RATE, TWO_STEP, FieldConfig,
                     OptimizeConfig, Optimiser, Regulariser)
from .kinds import AUTO, GRID, HASHGRID, KINDS, MLP

DEVIATORIC = ("xx", "yy", "yz", "zx", "xy")
# Where DEVIATORIC's components sit in a six-vector (xx, yy, zz, yz, zx, xy): zz is the one left out.
DEVIATORIC_OF_SIX = [0, 1, 3, 4, 5]


def stored_components(deviator: np.ndarray, stress_scale: float = 1.0) -> np.ndarray:
    """``(..., 5)``: what a trainable field stores (:data:`DEVIATORIC`, in units of ``stress_scale``) for
    ``(..., 6)`` deviatoric stresses."""
    return np.asarray(deviator)[..., DEVIATORIC_OF_SIX] / stress_scale


# Above this many grid nodes a hash grid stores the same detail in less memory and fewer updates.
GRID_NODE_LIMIT = 2_000_000
# A grid's default nodes along the specimen's longest axis, the coarsest first, and the nodes it must put across
# the thinnest: the kitten (55 x 60 x 92 mm) met its target at 32 (20 nodes across), the 6 mm thick disk only
# at 64 (11 across its thickness; 6 at 32, where its best fit is three times as far from the truth).
DEFAULT_RESOLUTIONS = (32, 48, 64)
MIN_NODES_ACROSS = 10
# Data whose fringes alias in more than this share of the specimen's pixels get the finest default grid and
# DENSE_REGULARISED: the stacked disks at 300 N (19% aliased) ended at 26.5% error on 64 nodes against 41.4% on
# the 32 their shape gives (the accuracy suite, 10 minutes each).
# The share is the one past which reconstruct refuses a dataset without --allow-aliased.
DENSE_FRINGES_SHARE = UNRESOLVED_SHARE
# The pixels across at which that share is read. The same field aliases in fewer pixels of finer images, about as
# their size (the 300 N disk in 15.4% at 64 px and 7.2% at 128, the stacked disks in 19.4% and 8.0%), yet needs the
# same grid: at 128 px under the shape's defaults they ended at 39.0% and 41.6%, under these 19.5% and 12.5% (the
# accuracy suite, 10 minutes each). The share of finer images is therefore scaled to images this many pixels
# across; coarser images' share is taken as it is (already higher than it would be here; a few pixels across a
# part, as in the tests' 8-pixel datasets, do not follow the proportion).
DENSE_FRINGES_PIXELS = 64


def dense_fringes(aliased_share: float, pixels: int = DENSE_FRINGES_PIXELS) -> bool:
    """Whether data whose fringes alias in ``aliased_share`` of the specimen's pixels, in images ``pixels``
    across, take the dense-fringe defaults: past :data:`DENSE_FRINGES_SHARE` once scaled to
    :data:`DENSE_FRINGES_PIXELS` across."""
    return share_at_reference(aliased_share, pixels) > DENSE_FRINGES_SHARE


def share_at_reference(aliased_share: float, pixels: int) -> float:
    """About the share of the specimen's pixels the same fringes would alias in at :data:`DENSE_FRINGES_PIXELS`
    across, from ``aliased_share`` at ``pixels`` across (as it is from coarser images)."""
    return aliased_share * max(pixels, DENSE_FRINGES_PIXELS) / DENSE_FRINGES_PIXELS


def default_resolution(extent: np.ndarray, aliased_share: float = 0.0, pixels: int = DENSE_FRINGES_PIXELS) -> int:
    """The grid resolution for a specimen of bounding-box ``extent`` (mm): the coarsest of
    :data:`DEFAULT_RESOLUTIONS` with :data:`MIN_NODES_ACROSS` nodes across its thinnest side (the finest
    where none has, or where the data's fringes, ``aliased_share`` of the pixels of images ``pixels`` across, are
    dense: :func:`dense_fringes`)."""
    if dense_fringes(aliased_share, pixels):
        return DEFAULT_RESOLUTIONS[-1]
    for resolution in DEFAULT_RESOLUTIONS:
        if min(grid_shape(resolution, extent)) >= MIN_NODES_ACROSS:
            return resolution
    return DEFAULT_RESOLUTIONS[-1]


def choose_kind(config: FieldConfig, extent: np.ndarray) -> str:
    """The cheapest representation for a specimen of bounding-box ``extent`` (mm).

    A dense grid is the cheapest per sample (one trilinear lookup) and per
    update; it is chosen unless its node count at the requested resolution
    exceeds :data:`GRID_NODE_LIMIT`, where a hash grid is used. The MLP is the
    most expensive per sample and never chosen automatically.
    """
    if config.kind != AUTO.name:
        return config.kind
    resolution = default_resolution(extent) if config.resolution is None else config.resolution
    nodes = np.prod(grid_shape(resolution, extent))
    return GRID.name if nodes <= GRID_NODE_LIMIT else HASHGRID.name


def settle(config: OptimizeConfig, extent: np.ndarray, aliased_share: float = 0.0,
           ease_default_smoothness: bool = True, slow_started_steps: bool = True,
           pixels: int = DENSE_FRINGES_PIXELS, neighbours_apply: bool = True) -> OptimizeConfig:
    """``config`` with its field's kind and resolution decided for a specimen of bounding-box ``extent`` and data
    whose fringes alias in ``aliased_share`` of the specimen's pixels in images ``pixels`` across; on dense fringes
    (:func:`dense_fringes`) a grid's default regulariser becomes :data:`~.config.DENSE_REGULARISED` (unless
    ``ease_default_smoothness`` is off: the user gave it). A run with a start field has one stage, and the default
    learning rate becomes :data:`~.config.STARTED_LEARNING_RATE` (unless ``slow_started_steps`` is off: the user
    gave one). A neighbour loss left to the defaults weighs :data:`~.config.NEIGHBOUR_WEIGHT` where
    :func:`default_neighbour_loss` takes it (``neighbours_apply``: the scene and the data allow it), else 0."""
    resolution = config.field.resolution
    if resolution is None:
        resolution = default_resolution(extent, aliased_share, pixels)
    kind = choose_kind(replace(config.field, resolution=resolution), extent)
    if config.field.kind == AUTO.name and kind != GRID.name:
        if config.schedule.start is not None:
            raise ValueError(f"a start field is fitted by grids only, and a grid at {resolution} nodes would be too "
                             f"large here (auto chose '{kind}'): give a lower --resolution")
        # Chosen for a grid too large to hold, a network is evaluated at every step: a lattice as large would not fit.
        resolution = 0
    settled = config.settled(kind, resolution)
    if ease_default_smoothness and dense_fringes(aliased_share, pixels) and settled.regulariser == REGULARISED:
        settled = replace(settled, regulariser=DENSE_REGULARISED)
    if settled.optimiser.neighbour_loss is None:
        weight = NEIGHBOUR_WEIGHT if default_neighbour_loss(settled, aliased_share, pixels, neighbours_apply) else 0.0
        settled = replace(settled, optimiser=replace(settled.optimiser, neighbour_loss=weight))
    if settled.schedule.start is not None:
        # The start has chosen the branch that the coarse stages and the path curriculum are there to choose.
        settled = replace(settled, schedule=replace(settled.schedule, coarse_to_fine=False, path_curriculum=0.0))
        optimiser = settled.optimiser
        if slow_started_steps and optimiser.learning_rate == Optimiser().learning_rate:
            rate = max(STARTED_LEARNING_RATE, optimiser.final_learning_rate)
            settled = replace(settled, optimiser=replace(optimiser, learning_rate=rate))
    return settled


def default_neighbour_loss(config: OptimizeConfig, aliased_share: float, pixels: int, neighbours_apply: bool) -> bool:
    """Whether the defaults fit the neighbour loss: where the scene and the data allow it (``neighbours_apply``), the
    fringes are resolved (not :func:`dense_fringes`) and the run descends (not the Two-step baseline)."""
    return neighbours_apply and not dense_fringes(aliased_share, pixels) and config.model.method != TWO_STEP


def grid_shape(resolution: int, extent: np.ndarray) -> tuple[int, int, int]:
    """``(nx, ny, nz)``: ``resolution`` nodes along the longest axis, at least 2 on each."""
    extent = np.asarray(extent, dtype=np.float64)
    spacing = extent.max() / (resolution - 1)
    return tuple(int(max(2, np.ceil(e / spacing - 1e-9) + 1)) for e in extent)


class TrainableField(StressField):
    kind = ""                   # a name of kinds.KINDS

    @property
    def lattice(self) -> bool:
        """Whether the rays march through values at the nodes of a lattice (``shape``): a grid, or a network
        sampled on one (:attr:`~.config.FieldConfig.on_lattice`)."""
        return self.config.on_lattice

    def __init__(self, config: FieldConfig, bbox_min: np.ndarray, bbox_max: np.ndarray, stress_scale: float):
        self.config = config                                # what the run recorded
        self.options = KINDS[self.kind].options.of(config)  # the part of it this kind reads
        self.bbox_min = np.asarray(bbox_min, dtype=np.float64)
        self.bbox_max = np.asarray(bbox_max, dtype=np.float64)
        if not np.all(self.bbox_max > self.bbox_min):
            raise ValueError(f"field bounding box is empty: {self.bbox_min} .. {self.bbox_max}")
        if not (np.isfinite(stress_scale) and stress_scale > 0):
            raise ValueError(f"stress_scale must be a positive number of MPa, got {stress_scale}")
        self.stress_scale = float(stress_scale)
        self._scale = mi.ScalarVector3f(1.0 / (self.bbox_max - self.bbox_min))
        self._offset = mi.ScalarVector3f(-self.bbox_min / (self.bbox_max - self.bbox_min))

    def unit_coordinates(self, p: mi.Point3f) -> mi.Point3f:
        """``p`` mapped to [0, 1]^3 over the bounding box."""
        return dr.fma(mi.Point3f(p), self._scale, self._offset)

    def eval(self, p: mi.Point3f) -> tuple[mi.Float, ...]:
        xx, yy, yz, zx, xy = (self.stress_scale * c for c in self.deviatoric(p))
        return xx, yy, -(xx + yy), yz, zx, xy

    def deviatoric(self, p: mi.Point3f) -> tuple[mi.Float, ...]:
        """The five stored components at ``p``, in units of ``stress_scale``."""
        raise NotImplementedError

    def parameters(self) -> dict:
        raise NotImplementedError

    def assign(self, values: dict) -> None:
        raise NotImplementedError

    def finish_backward(self) -> None:
        """Carry into the parameters the gradients that the rays and the penalties left on values computed from
        them (a network's lattice samples); called once an iteration, after every backward pass."""

    def smoothness_penalty(self, weight: float, edge: float | None = None) -> mi.Float | None:
        """``weight`` times the mean squared gradient, growing only linearly above the gradient ``edge``
        (None: quadratic throughout); a term of the loss. None where the weight is 0 or the representation
        has no gradient to penalise."""
        return None

    def equilibrium_penalty(self, weight: float, stencil: equilibrium.CellStencil) -> mi.Float | None:
        """``weight`` times the mean squared equilibrium residual over ``stencil``'s cells
        (:mod:`~mi_nest.reconstruct.equilibrium`); None where the weight is 0 or the representation carries no
        mean stress."""
        return None

    def state(self) -> dict:
        """Everything needed to rebuild the field, as NumPy arrays and plain values."""
        return {"kind": self.kind, "config": asdict(self.config), "bbox_min": self.bbox_min,
                "bbox_max": self.bbox_max, "stress_scale": self.stress_scale,
                **{f"param.{name}": np.array(value) for name, value in self.parameters().items()}}

    def load_parameters(self, state: dict) -> None:
        values = {}
        for name, current in self.parameters().items():
            stored = np.asarray(state[f"param.{name}"], dtype=np.float32)
            expected = tuple(current.shape)
            if stored.shape != expected:
                raise ValueError(f"stored parameter '{name}' has shape {stored.shape}, the field expects {expected}")
            values[name] = type(current)(stored)
        self.assign(values)

    def __repr__(self):
        return (f"{type(self).__name__}({self.describe()}, bbox {self.bbox_min.round(3).tolist()} .. "
                f"{self.bbox_max.round(3).tolist()} mm, scale {self.stress_scale:.3g} MPa)")

    def describe(self) -> str:
        return self.kind

    def parameter_count(self) -> int:
        return int(sum(np.prod(v.shape) for v in self.parameters().values()))


class DeviatoricGrid(TrainableField):
    """Five components on a regular nodal grid over the bounding box, trilinear (a 5-channel ``mi.Texture3f``)."""
    kind = GRID.name

    def __init__(self, config: FieldConfig, bbox_min: np.ndarray, bbox_max: np.ndarray, stress_scale: float):
        super().__init__(config, bbox_min, bbox_max, stress_scale)
        self.shape = grid_shape(self.options.resolution, self.bbox_max - self.bbox_min)      # (nx, ny, nz)
        nx, ny, nz = self.shape
        self.texture = mi.Texture3f(mi.TensorXf(np.zeros((nz, ny, nx, 5), dtype=np.float32)),
                                    filter_mode=dr.FilterMode.Linear, wrap_mode=dr.WrapMode.Clamp)
        # Nodes sit on the bounding box faces: map [0, 1] onto the first/last texel centres.
        nodes = mi.ScalarVector3f(nx, ny, nz)
        self._texel_scale = (nodes - 1) / nodes
        self._texel_offset = 0.5 / nodes
        self._pairs = None
        # The mean stress at the nodes (stress scales) that balances the deviator where equilibrium is a prior:
        # solved from the deviator, not optimised, and never in the images.
        self.mean = None

    def deviatoric(self, p: mi.Point3f) -> tuple[mi.Float, ...]:
        uvw = dr.fma(self.unit_coordinates(p), self._texel_scale, self._texel_offset)
        return tuple(self.texture.eval(uvw))

    def parameters(self) -> dict:
        return {"grid": self.texture.tensor()}

    def assign(self, values: dict) -> None:
        self.texture.set_tensor(values["grid"])

    @property
    def node_counts(self) -> tuple[int, int, int]:
        """``(nx, ny, nz)``: the nodes along each axis (as a stress grid field names them)."""
        return self.shape

    def nodes(self) -> np.ndarray:
        """``(nx * ny * nz, 5)``: the stored components node by node, x fastest (as ``metrics.fitted_nodes``)."""
        return np.array(self.texture.tensor()).reshape(-1, 5)

    def set_nodes(self, nodes: np.ndarray) -> None:
        """Assign what :meth:`nodes` reads."""
        self.assign({"grid": mi.TensorXf(np.asarray(nodes, dtype=np.float32).reshape(*self.shape[::-1], 5))})

    def state(self) -> dict:
        return {**super().state(), **({} if self.mean is None else {"mean": np.array(self.mean)})}

    def rms(self) -> float:
        """Root mean square of the stored components over the nodes (stress scales)."""
        return float(dr.sqrt(dr.mean(dr.square(self.texture.tensor().array)))[0])

    def smoothness_penalty(self, weight: float, edge: float | None = None) -> mi.Float | None:
        """``weight`` times the mean over neighbouring nodes of the squared difference per node spacing (lengths
        in units of the box's longest side: the mean squared gradient, the same for one field at every
        resolution, so coarse-to-fine stages are not smoothed harder than the final grid); with ``edge``, the
        Charbonnier penalty ``2 edge^2 (sqrt(1 + (d / edge)^2) - 1)``: the squared gradient below the edge,
        growing only linearly above it, so stress concentrations keep their flanks while gentle ripples (poorly
        observed directions) are smoothed."""
        if weight == 0:
            return None
        if self._pairs is None:
            self._pairs = _neighbour_pairs(self.shape)
        # Opaque, the weight and the edge: ones that decay or follow the field's scale would rebuild the kernels.
        edge_squared = None if edge is None else dr.opaque(mi.Float, edge ** 2)
        return dr.custom(_Smoothness, self.texture.tensor().array, self._pairs, self.shape,
                         float(self.options.resolution - 1), dr.opaque(mi.Float, weight), edge_squared)

    def equilibrium_penalty(self, weight: float, stencil: equilibrium.CellStencil) -> mi.Float | None:
        if weight == 0 or self.mean is None:
            return None
        # Opaque: a weight that follows the field's scale would rebuild the kernels.
        return equilibrium.penalty(self.texture.tensor().array, dr.detach(self.mean.array), stencil,
                                   dr.opaque(mi.Float, weight))

    def describe(self) -> str:
        return f"grid {'x'.join(map(str, self.shape))}"


def _neighbour_pairs(shape):
    """Flat indices of every pair of neighbouring nodes (all five channels) in a (z, y, x, 5) array."""
    nx, ny, nz = shape
    index = np.arange(nz * ny * nx * 5, dtype=np.uint32).reshape(nz, ny, nx, 5)
    first, second = [], []
    for axis in range(3):
        count = index.shape[axis]
        first.append(np.take(index, range(count - 1), axis=axis).ravel())
        second.append(np.take(index, range(1, count), axis=axis).ravel())
    return mi.UInt32(np.concatenate(first)), mi.UInt32(np.concatenate(second))


def _charbonnier(squared, edge_squared):
    """``2 e^2 (sqrt(1 + d^2 / e^2) - 1)`` of ``squared = d^2``, written without the cancellation of small ``d``."""
    return 2.0 * squared / (dr.sqrt(1.0 + squared / edge_squared) + 1.0)


class _Smoothness(dr.CustomOp):
    """A grid's smoothness penalty (:meth:`DeviatoricGrid.smoothness_penalty`) with its gradient gathered per
    node from its up to six neighbours, in one kernel: differentiated automatically, every pair scattered its
    derivative to its two nodes by atomic adds (4.6 ms of a 50 ms iteration on the disk's 64-node grid)."""

    def eval(self, values, pairs, shape, per_length, weight, edge_squared):
        self.values, self.shape, self.per_length = values, shape, per_length
        self.weight, self.edge_squared, self.count = weight, edge_squared, dr.width(pairs[0])
        first, second = pairs
        difference = (dr.gather(mi.Float, values, first) - dr.gather(mi.Float, values, second)) * per_length
        squared = dr.square(difference)
        penalty = squared if edge_squared is None else _charbonnier(squared, edge_squared)
        return weight * dr.mean(penalty)

    def slope(self, difference):
        """The penalty's derivative in a pair's difference per spacing."""
        if self.edge_squared is None:
            return 2.0 * difference
        return 2.0 * difference / dr.sqrt(1.0 + dr.square(difference) / self.edge_squared)

    def backward(self):
        values = self.values
        nx, ny, nz = self.shape
        index = dr.arange(mi.UInt32, dr.width(values))
        node = index // 5
        coordinates = (node % nx, (node // nx) % ny, node // (nx * ny))
        gradient = dr.zeros(mi.Float, dr.width(values))
        # A node is the first of the pair with its next neighbour and the second of the pair with its previous.
        for coordinate, count, stride in zip(coordinates, (nx, ny, nz), (5, 5 * nx, 5 * nx * ny)):
            has_next, has_previous = coordinate + 1 < count, coordinate > 0
            following = dr.gather(mi.Float, values, index + stride, has_next)
            preceding = dr.gather(mi.Float, values, index - stride, has_previous)
            gradient += dr.select(has_next, self.slope((values - following) * self.per_length), 0.0)
            gradient -= dr.select(has_previous, self.slope((preceding - values) * self.per_length), 0.0)
        self.set_grad_in("values", self.grad_out() * self.weight * self.per_length / self.count * gradient)

    def name(self):
        return "Smoothness"


class SiLU(nn.Module):
    """``x sigmoid(x) = h + h tanh(h)`` with ``h = x / 2``: the NeST activation (``drjit.nn`` has none)."""
    DRJIT_STRUCT = {}

    def __call__(self, x: nn.CoopVec) -> nn.CoopVec:
        half = x * 0.5
        return half + half * dr.tanh(half)


def _network(options, inputs, hidden_layers, encoding=None):
    layers = [] if encoding is None else [encoding]
    for _ in range(hidden_layers):
        layers += [nn.Linear(-1, options.width, bias=True), SiLU()]
    layers.append(nn.Linear(-1, 5, bias=True))
    net = nn.Sequential(*layers).alloc(mi.TensorXf, inputs, rng=dr.rng(seed=options.seed))
    return nn.pack(net, layout="training")


def _gathered(view: nn.MatrixView, shape: tuple[int, ...]) -> mi.TensorXf:
    """The row-major ``view``'s entries as a tensor of ``shape`` (a matrix, or a vector read contiguously),
    gathered from its buffer: gradients flow back into it."""
    index = dr.arange(mi.UInt32, int(np.prod(shape)))
    columns = shape[-1]
    return mi.TensorXf(dr.gather(mi.Float, view.buffer, view.offset + index // columns * view.stride
                                 + index % columns), shape)


def _tensor_mode(packed: nn.Module) -> nn.Sequential:
    """``packed``'s layers with the weights gathered from its buffer as plain tensors, to evaluate on a tensor of
    inputs (matrix products) rather than on cooperative vectors: on the LLVM backend the latter's backward pass
    accumulates the weights' gradients point by point (the MLP's pass 4.1 times slower on the disk's 64 x 64 x 11
    lattice, benchmarks/network_lattice.py)."""
    unpacked = nn.unpack(packed)
    layers = []
    for layer in unpacked.layers:
        if isinstance(layer, nn.Linear):
            plain = nn.Linear(*layer.config)
            plain.weights = _gathered(layer.weights, tuple(layer.weights.shape))
            plain.bias = None if layer.bias is None else _gathered(layer.bias, (layer.bias.shape[0],))
            layer = plain
        layers.append(layer)
    return nn.Sequential(*layers)


# Adam steps that fit a network on a new, finer lattice to the coarser one's field (_NeuralField._keep_field).
KEEP_STEPS = 200


class _NeuralField(TrainableField):
    """A network of the position; with a resolution, sampled once an iteration at the nodes of a lattice
    (:attr:`samples`, a :class:`DeviatoricGrid`) that the rays then march through as through a grid's: a lookup per
    step instead of the network's evaluation and its backward pass, on the grid's coarse-to-fine stages and
    regulariser. The network's parameters stay what is trained; their gradient is the lattice's, carried back
    through the samples (:meth:`finish_backward`)."""

    def __init__(self, config: FieldConfig, bbox_min: np.ndarray, bbox_max: np.ndarray, stress_scale: float):
        super().__init__(config, bbox_min, bbox_max, stress_scale)
        self.samples = None
        self._sampled = None    # the samples as computed from the parameters (their graph), flat
        self._positions = None

    def _lattice_for(self, resolution: int) -> None:
        config = replace(self.config, kind=GRID.name, resolution=resolution)
        self.samples = DeviatoricGrid(config, self.bbox_min, self.bbox_max, self.stress_scale)
        self._positions = mi.Point3f(grid_nodes(self.bbox_min, self.bbox_max, self.samples.shape).T
                                     .astype(np.float32))

    def sample_on(self, resolution: int, learning_rate: float) -> None:
        """Sample the network on a lattice of ``resolution`` nodes along the longest axis from now on (coarse to
        fine), first fitted there to the coarser lattice's trilinear field (:meth:`_keep_field`)."""
        coarse = self.samples
        self.config = replace(self.config, resolution=int(resolution))
        self.options = KINDS[self.kind].options.of(self.config)
        self._lattice_for(self.options.resolution)
        if coarse is not None:
            self._keep_field(coarse, learning_rate)
        self._sample()

    def _keep_field(self, coarse: DeviatoricGrid, learning_rate: float) -> None:
        """Fit the network at the new lattice's nodes to ``coarse``'s trilinear field there by :data:`KEEP_STEPS`
        of Adam (its own moments), as a grid's refinement keeps its field. The rays saw the network only at the
        coarser nodes; between them it holds whatever its initial weights and the fit left."""
        target = [dr.detach(value) for value in coarse.deviatoric(self._positions)]
        self.fit_at_nodes(target, dr.opt.Adam(lr=learning_rate, params=self.parameters()), KEEP_STEPS)

    def fit_at_nodes(self, target: list[mi.Float], optimizer: dr.opt.Optimizer, steps: int) -> float:
        """``steps`` of ``optimizer`` (over :meth:`parameters`) on the mean squared difference, summed over the five
        components, between the network at the lattice's nodes and ``target`` there; the parameters end as the
        optimizer's (the samples are not taken again). Returns the last step's loss."""
        loss = mi.Float(0.0)
        for _ in range(steps):
            self._set_parameters(optimizer)
            with dr.resume_grad():
                values = self.network_at_all(self._positions)
                loss = sum(dr.mean(dr.square(value - wanted)) for value, wanted in zip(values, target))
                dr.backward(loss)
            optimizer.step()
        self._set_parameters(optimizer)
        return float(loss[0])

    @property
    def shape(self) -> tuple[int, int, int] | None:
        """``(nx, ny, nz)`` of the lattice it is sampled on (None: evaluated at every step)."""
        return None if self.samples is None else self.samples.shape

    @property
    def texture(self) -> mi.Texture3f:
        """The lattice's samples, as a grid holds its nodes."""
        return self.samples.texture

    def nodes(self) -> np.ndarray:
        return self.samples.nodes()

    def rms(self) -> float:
        return self.samples.rms()

    def deviatoric(self, p: mi.Point3f) -> tuple[mi.Float, ...]:
        return self.network(p) if self.samples is None else self.samples.deviatoric(p)

    def network(self, p: mi.Point3f) -> tuple[mi.Float, ...]:
        """The network's five components at ``p`` (stress scales)."""
        return tuple(mi.Float(x) for x in self.net(nn.CoopVec(*self._features(p))))

    def network_at_all(self, p: mi.Point3f) -> tuple[mi.Float, ...]:
        """:meth:`network` at every point of ``p`` at once, by matrix products (the lattice's samples)."""
        features = self._features(p)
        inputs = mi.TensorXf(dr.concat([mi.Float(x) for x in features]), (len(features), dr.width(features[0])))
        outputs = _tensor_mode(self.net)(inputs)
        return tuple(outputs[component].array for component in range(outputs.shape[0]))

    def _features(self, p: mi.Point3f) -> list:
        """What the decoding layers take at ``p``."""
        raise NotImplementedError

    def assign(self, values: dict) -> None:
        self._set_parameters(values)
        self._sample()

    def _set_parameters(self, values) -> None:
        self.net["weights"] = values["weights"]

    def _sample(self) -> None:
        if self.options.resolution == 0:
            return
        if self.samples is None:
            self._lattice_for(self.options.resolution)
        with dr.resume_grad():
            values = self.network_at_all(self._positions)
            count = dr.width(values[0])
            sampled = dr.zeros(mi.Float, 5 * count)
            node = dr.arange(mi.UInt32, count)
            for component, value in enumerate(values):
                dr.scatter(sampled, value, 5 * node + component)
        nodes = mi.Float(dr.detach(sampled))
        dr.eval(nodes)
        self._sampled = sampled if dr.grad_enabled(sampled) else None
        if self._sampled is not None:
            # The march's and the penalties' gradients collect here, to go back through the network at once.
            dr.enable_grad(nodes)
        nx, ny, nz = self.samples.shape
        self.samples.assign({"grid": mi.TensorXf(nodes, (nz, ny, nx, 5))})

    def finish_backward(self) -> None:
        if self._sampled is None:
            return
        gradient = dr.grad(self.samples.texture.tensor().array)
        with dr.resume_grad():
            dr.backward_from(dr.sum(self._sampled * gradient))

    def smoothness_penalty(self, weight: float, edge: float | None = None) -> mi.Float | None:
        return None if self.samples is None else self.samples.smoothness_penalty(weight, edge)

    def _sampled_on(self) -> str:
        return "" if self.samples is None else f", sampled on {'x'.join(map(str, self.samples.shape))} nodes"


class MLPField(_NeuralField):
    """The NeST field: sinusoidal encoding of the position, SiLU MLP, five outputs."""
    kind = MLP.name

    def __init__(self, config: FieldConfig, bbox_min: np.ndarray, bbox_max: np.ndarray, stress_scale: float):
        super().__init__(config, bbox_min, bbox_max, stress_scale)
        # Shifted octaves keep the encoding's extrema off a common lattice.
        options = self.options
        self.net = _network(options, 3, options.layers, nn.SinEncode(options.octaves, shift=0.25))
        self._sample()

    def _features(self, p: mi.Point3f) -> list:
        return list(self.unit_coordinates(p))

    def parameters(self) -> dict:
        return {"weights": self.net["weights"]}

    def describe(self) -> str:
        return f"mlp {self.options.layers}x{self.options.width}, {self.options.octaves} octaves{self._sampled_on()}"


class HashGridField(_NeuralField):
    """Multi-resolution hash encoding (``drjit.nn.HashGridEncoding``) and a one-layer SiLU decoder."""
    kind = HASHGRID.name

    def __init__(self, config: FieldConfig, bbox_min: np.ndarray, bbox_max: np.ndarray, stress_scale: float):
        super().__init__(config, bbox_min, bbox_max, stress_scale)
        options = self.options
        self.encoding = nn.HashGridEncoding(
            mi.Float, 3, n_levels=options.levels, n_features_per_level=options.features_per_level,
            hashmap_size=options.hashmap_size, base_resolution=options.base_resolution,
            per_level_scale=options.level_scale, init_scale=1e-2, rng=dr.rng(seed=options.seed + 1))
        self.net = _network(options, options.levels * options.features_per_level, 1)
        self._sample()

    def _features(self, p: mi.Point3f) -> list:
        # The encoding reads outside its tables for coordinates outside [0, 1] (values of 1e26 seen), and
        # samples on the specimen's surface can round a hair outside the bounding box.
        return list(self.encoding(dr.clip(self.unit_coordinates(p), 0.0, 1.0)))

    def parameters(self) -> dict:
        return {"encoding": self.encoding.data, "weights": self.net["weights"]}

    def _set_parameters(self, values) -> None:
        self.encoding.data = values["encoding"]
        super()._set_parameters(values)

    def describe(self) -> str:
        return (f"hashgrid {self.options.levels} levels x {self.options.features_per_level} features, "
                f"2^{int(np.log2(self.options.hashmap_size))} entries{self._sampled_on()}")


FIELDS = {cls.kind: cls for cls in (DeviatoricGrid, HashGridField, MLPField)}


def make_field(config: FieldConfig, bbox_min: np.ndarray, bbox_max: np.ndarray, stress_scale: float) -> TrainableField:
    extent = np.asarray(bbox_max) - np.asarray(bbox_min)
    if config.resolution is None:
        config = replace(config, resolution=default_resolution(extent))
    return FIELDS[choose_kind(config, extent)](config, bbox_min, bbox_max, stress_scale)


def field_from_state(state: dict) -> TrainableField:
    """Rebuild a field saved by :meth:`TrainableField.state`."""
    kind = str(state["kind"])
    if kind not in FIELDS:
        raise ValueError(f"unknown field kind '{kind}' in saved state")
    config = state["config"]
    if not isinstance(config, FieldConfig):
        # Fields saved before the regulariser had its own group recorded its options with them.
        regulariser_options = ({f.name for f in dataclass_fields(Regulariser)}
                               - {f.name for f in dataclass_fields(FieldConfig)})
        config = FieldConfig(**{k: (v.item() if hasattr(v, "item") else v) for k, v in dict(config).items()
                                if k not in regulariser_options})
    field = FIELDS[kind](config, state["bbox_min"], state["bbox_max"], float(state["stress_scale"]))
    field.load_parameters(state)
    if "mean" in state:
        field.mean = mi.TensorXf(np.asarray(state["mean"], dtype=np.float32))
    return field


def refined(field: DeviatoricGrid, resolution: int) -> DeviatoricGrid:
    """``field`` resampled onto a grid of ``resolution`` nodes along the longest axis (coarse to fine)."""
    config = replace(field.config, kind=GRID.name, resolution=int(resolution))
    finer = DeviatoricGrid(config, field.bbox_min, field.bbox_max, field.stress_scale)
    nodes = mi.Point3f(grid_nodes(field.bbox_min, field.bbox_max, finer.shape).T.astype(np.float32))
    with dr.suspend_grad():
        finer.set_nodes(np.stack([np.array(c) for c in field.deviatoric(nodes)], axis=-1))
    return finer
