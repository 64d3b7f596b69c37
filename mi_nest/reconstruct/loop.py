"""The optimisation loop: batches, the curriculum, averaging, divergence, checkpoints and Ctrl-C.

Each iteration draws a batch of pixels across training rotations, marches
their rays through the trainable field (no derivatives kept), takes the L1
loss of the 16 normalised intensities, and replays the march backwards to push
the loss gradient into the field (constant memory, see
``Tracer.backpropagate_rays``); Adam updates the field. Joint
phase unwrapping and tensor tomography happen together: nothing is unwrapped
per view.
"""
from __future__ import annotations

import collections
import math
import time
from dataclasses import replace
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import interrupts
from ..dataset import Dataset
from ..fields.base import sample
from ..render import require_memory
from ..scene import scene_origin, specimen_shapes
from ..tracer import Tracer
from . import equilibrium, metrics
from .free_surface import FreeSurfacePrior
from .channels import ChannelModel
from .checkpoints import CHECKPOINT, Checkpoint, Reconstruction, adam_moments, restore_adam_moments
from .config import TWO_STEP, OptimizeConfig
from .kinds import KINDS
from .evaluation import SampledViewLoss
from .fields import make_field, refined
from .forward import forward_step, make_tracer
from .losses import generator_loss, l1_loss
from .neighbours import NeighbourPairs, NeighbourTargets
from .rays import ViewRays, stratified
from .repair import refill
from .start import SCALE_VIEWS, best_scale, start_field, starting_nodes
from .trust import imbalance
from .two_step import RetardanceTargets

# Nodes along the longest axis of the first coarse-to-fine stage.
COARSEST_GRID = 8
# A gradient this many times the median of the RECENT_GRADIENTS before it counts as exploding.
EXPLODING_FACTOR = 1e4
RECENT_GRADIENTS = 20
# Peak memory of an iteration per ray: 240 to 390 bytes measured for batches of 2^18 and 2^20 rays on grids (every
# method) and hash grids, 470 for an MLP at 2^18.
BYTES_PER_RAY = 512
# A field beyond this many stress scales (each about one fringe across the specimen) per pixel across the
# dataset's images has run away: 40 times the Nyquist limit, no image could tell its phase. The true fields
# of the shipped scenes stay below 3 per pixel at any resolution their datasets use.
RUNAWAY_ORDERS_PER_PIXEL = 20
# Points per axis of the lattice inside the specimen where the field's magnitude is checked.
MAGNITUDE_POINTS = 16
# Iterations between solves of the mean stress that balances the deviator (equilibrium prior): the deviator moves
# little in between.
BALANCE_EVERY = 25
# Iterations between read-backs of the field's RMS for a regulariser relative to it.
FIELD_RMS_EVERY = 50
# The last share of the run at which a branch repair may refill: a refilled region needs the rest to fit again
# (the 90-degree disk's took 3 minutes of the 10).
LAST_REPAIR = 0.7


class DivergenceError(RuntimeError):
    """The optimisation produced a non-finite loss or an exploding gradient."""


class Run:
    """The state of one optimisation: field, optimiser, random state, history; checkpoints."""

    def __init__(self, scene: mi.Scene, dataset: Dataset, config: OptimizeConfig, low: np.ndarray, high: np.ndarray,
                 scale: float, output: str | Path | None, progress: bool):
        self.scene, self.dataset, self.config = scene, dataset, config
        self.output = None if output is None else Path(output)
        self.show_progress = progress
        self.kind = config.field.kind       # settled by optimize (fields.settle)
        self.stages = self._stages()
        self.field = make_field(replace(config.field, kind=self.kind, resolution=self.stages[0][1]), low, high,
                                scale)
        self.view_rays = ViewRays(scene, dataset)
        self.finest_pixel_samples = int(config.optimiser.pixel_samples or min(4, int(dataset.index.get("spp", 1))))
        self.coarse_pixel_samples = int(config.optimiser.coarse_pixel_samples or self.finest_pixel_samples)
        samples = max(self.finest_pixel_samples, self.coarse_pixel_samples)
        require_memory(config.optimiser.batch_size * samples * BYTES_PER_RAY,
                       f"a batch of {config.optimiser.batch_size} pixels, {samples} ray(s) each,",
                       "lower batch_size (mi-nest reconstruct --option batch_size=N) or pixel_samples")
        self.rng = np.random.default_rng(config.optimiser.seed)
        self.iteration = 0
        self._rms = None
        self.history = []
        self.seconds = 0.0
        self.gradient_norms = collections.deque(maxlen=RECENT_GRADIENTS)    # bounded: memory stays flat
        self.optimizer = self._optimizer()
        self.last_good = None
        self.iterate_sums, self.iterates_averaged = {}, 0
        self.retardance = (RetardanceTargets(dataset, config.optimiser.mask)
                           if config.model.method == TWO_STEP or config.schedule.warm_start else None)
        self.error_probe = None
        self.channels = ChannelModel.of(dataset, scene, config.model.spectral_step)
        self.neighbour_targets = None   # the neighbour loss's recovered Jones matrices, view by view
        self.path_range = None          # (shortest, longest) path of the curriculum, from the first batch
        self.magnitude_points = None    # where _require_sane_field samples the field, chosen at its first call
        self._balance = None            # the mean stress solver on the current grid (prior and branch repair)
        self._free = None               # the free-surface prior's points
        self.began_at = {}              # where a start began (start_from): recorded with the first iteration
        self.repaired = {}              # what the last branch repair refilled: recorded with the next iteration
        self._last_check = 0.0          # the progress at the last branch repair's check

    def _stages(self):
        """``[(progress at which it starts, lattice resolution)]``: coarse to fine on a lattice (a grid, or a network
        sampled on one), one stage otherwise."""
        resolution = self.config.field.resolution
        if not self.config.field.on_lattice or not self.config.schedule.coarse_to_fine:
            return [(0.0, resolution)]
        resolutions = sorted({r for r in (max(4, resolution // 4), max(4, resolution // 2)) if r < resolution})
        # Fine grids start coarser still: from 16 nodes the disk at 64 stuck in a wrapped minimum at 80%
        # error; from 8 at 32 it went on down.
        while resolutions and resolutions[0] // 2 >= COARSEST_GRID:
            resolutions.insert(0, resolutions[0] // 2)
        resolutions.append(resolution)
        # The finest stage gets its share at the end (by default half: it has the most unknowns); the coarser
        # stages split the rest evenly.
        coarse = 1.0 - self.config.schedule.finest_stage
        starts = [coarse * i / (len(resolutions) - 1) for i in range(len(resolutions))] if len(resolutions) > 1 \
            else [0.0]
        return list(zip(starts, resolutions))

    def start_from(self, source: str) -> None:
        """Begin at ``source``'s field (:mod:`.start`), scaled to the load factor the training views prefer;
        the time it takes counts against the run's budget, and where it began goes into the first iteration's
        record (``began_at``)."""
        began = time.perf_counter()
        nodes = starting_nodes(self.field, start_field(source), self.scene, specimen_shapes(self.scene), source)
        nodes = self.config.schedule.start_load_ratio * nodes
        spread = self.config.schedule.start_scale_range
        factor = 1.0
        if spread > 0:
            loss = SampledViewLoss(self.scene, self.dataset, self.tracer(), self.config.optimiser.mask, "train",
                                   SCALE_VIEWS, self.finest_pixel_samples)
            factor = best_scale(self.field, nodes, loss, spread)
        self.field.set_nodes(factor * nodes)
        self.optimizer = self._optimizer()
        spent = time.perf_counter() - began
        self.seconds += spent
        self.began_at = {"start": source, "start_factor": factor * self.config.schedule.start_load_ratio,
                         "start_seconds": round(spent, 2)}

    def progress(self) -> float:
        """How far the run is, in [0, 1]: by iterations, or by time when a time limit comes first."""
        schedule = self.config.schedule
        done = self.iteration / schedule.iterations
        if schedule.time_limit is not None:
            done = max(done, self.seconds / schedule.time_limit)
        return min(done, 1.0)

    def _optimizer(self):
        optimizer = dr.opt.Adam(lr=self.config.optimiser.learning_rate, params=self.field.parameters())
        self.field.assign(optimizer)
        return optimizer

    def fitting_retardance(self) -> bool:
        """Whether this iteration fits the Two-step's unwrapped data (the baseline, or a warm start)."""
        return self.config.model.method == TWO_STEP or self.progress() < self.config.schedule.warm_start

    def tracer(self) -> Tracer:
        """The tracer of this iteration's forward model (the Two-step's linear one while it fits retardance)."""
        return make_tracer(self.config, self.field, self.scene, TWO_STEP if self.fitting_retardance() else None)

    def learning_rate(self) -> float:
        """Geometric decay from ``learning_rate`` to ``final_learning_rate`` over the run."""
        optimiser = self.config.optimiser
        ratio = optimiser.final_learning_rate / optimiser.learning_rate
        return optimiser.learning_rate * ratio ** self.progress()

    def pixel_samples(self) -> int:
        """Rays per pixel now: the coarse stages choose a branch, which a point sample of each pixel tells as
        well; the finest stage fits the pixels as the camera integrated them."""
        return self.finest_pixel_samples if self.in_finest_stage() else self.coarse_pixel_samples

    def in_finest_stage(self) -> bool:
        return self.progress() >= self.stages[-1][0]

    def averaging(self) -> bool:
        """Whether iterates now enter the averaged result: the run's last ``average_last``, finest stage only."""
        share = self.config.regulariser.average_last
        return share > 0 and self.in_finest_stage() and self.progress() >= 1.0 - share

    def _add_to_average(self):
        # Polyak averaging: near the end Adam's iterates wander around the minimum, most along the
        # directions the data constrain least; their mean lies closer to it than any one of them.
        for name in self.optimizer.keys():
            value = dr.detach(self.optimizer[name])
            self.iterate_sums[name] = value if name not in self.iterate_sums else self.iterate_sums[name] + value
        dr.eval(self.iterate_sums)
        self.iterates_averaged += 1

    def _field_rms(self) -> float:
        # Read back every FIELD_RMS_EVERY iterations (a reduction and a sync): the scale moves slowly.
        if self.iteration % FIELD_RMS_EVERY == 0 or self._rms is None:
            self._rms = self.field.rms()
        return self._rms

    def smoothness_decayed(self) -> float:
        """How far the smoothness weight has decayed (0 to 1): over the finest stage, once the coarse stages
        have chosen the branch that the regulariser is there to choose."""
        start = self.stages[-1][0]
        return min(1.0, max(0.0, (self.progress() - start) / (1.0 - start)))

    def loop(self) -> None:
        schedule, reporting = self.config.schedule, self.config.reporting
        tracer = self.tracer()
        phase = self.fitting_retardance()
        bar = None
        if self.show_progress:
            from tqdm import tqdm
            # Against a time limit the bar counts seconds: the iteration count would not say when it ends.
            timed = schedule.time_limit is not None
            bar = tqdm(total=schedule.time_limit if timed else schedule.iterations,
                       initial=min(self.seconds, schedule.time_limit) if timed else self.iteration,
                       desc=f"reconstruct ({self.field.kind})", unit="s" if timed else "it", mininterval=0.5,
                       bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s [{elapsed}<{remaining}{postfix}]" if timed
                       else None)
        try:
            while self.iteration < schedule.iterations and not self.out_of_time():
                interrupts.check()
                self._refine_if_due()
                self._repair_if_due()
                if self.fitting_retardance() != phase:
                    # Warm start over: the joint fit starts from its field with fresh moments for its own loss.
                    phase = self.fitting_retardance()
                    tracer = self.tracer()
                    self.optimizer = self._optimizer()
                start = time.perf_counter()
                loss = self.step(tracer)
                elapsed = time.perf_counter() - start
                self.seconds += elapsed
                self.history.append({"iteration": self.iteration, "loss": loss,
                                     "learning_rate": self.learning_rate(),
                                     "seconds": round(self.seconds, 4),
                                     **(self.began_at if self.iteration == 0 else {}), **self.repaired})
                self.repaired = {}
                if self.error_probe is not None and self.iteration % reporting.track_error_every == 0:
                    # Outside the timed step: following the error does not slow the run's clock.
                    self.history[-1]["deviatoric_error"] = self.error_probe(self.field)
                self.iteration += 1
                if self.iteration % reporting.checkpoint_every == 0 or self.iteration == schedule.iterations:
                    self.checkpoint()
                if bar is not None:
                    rays = self.config.optimiser.batch_size * self.pixel_samples()
                    bar.set_postfix(loss=f"{loss:.4f}", rays_per_s=f"{rays / elapsed:.3g}", refresh=False)
                    bar.update(min(elapsed, schedule.time_limit - bar.n) if timed else 1)
            if self.error_probe is not None and self.history and "deviatoric_error" not in self.history[-1]:
                # The run's last point too, however the tracking interval fell.
                self.history[-1]["deviatoric_error"] = self.error_probe(self.field)
        except KeyboardInterrupt:
            self.checkpoint()
            where = "" if self.output is None else f", checkpoint in {self.output / CHECKPOINT}"
            raise interrupts.Interrupted(f"stopped after iteration {self.iteration}{where}; run it again to resume "
                                         "from there") from None
        finally:
            if bar is not None:
                bar.close()

    def out_of_time(self) -> bool:
        time_limit = self.config.schedule.time_limit
        if time_limit is None or self.seconds < time_limit:
            return False
        self.checkpoint()
        return True

    def _refine_if_due(self) -> None:
        """Move to the coarse-to-fine stage the progress has reached."""
        resolution = [r for start, r in self.stages if start <= self.progress()][-1]
        if not self.field.lattice or self.field.config.resolution == resolution:
            return
        if KINDS[self.kind].trains_nodes:
            self.field = refined(self.field, resolution)
            self.optimizer = self._optimizer()
        else:
            # A network is fitted on the finer lattice to the coarser field; Adam keeps its moments.
            self.field.sample_on(resolution, self.config.optimiser.learning_rate)
            for name, value in self.field.parameters().items():
                self.optimizer[name] = value

    def _repair_if_due(self) -> None:
        """Every ``branch_repair`` of the run on the final grid, up to :data:`LAST_REPAIR`, refill the regions
        that unbalanced nodes enclose (:mod:`.repair`), with fresh moments for the refilled field; the check's
        time counts against the run's budget."""
        every = self.config.schedule.branch_repair
        if (every <= 0 or not KINDS[self.kind].trains_nodes or self.fitting_retardance() or not self.in_finest_stage()
                or self.averaging()):
            return
        due = math.floor(self.progress() / every + 1e-9)
        if due <= math.floor(self._last_check / every + 1e-9) or self.progress() > LAST_REPAIR:
            return
        began = time.perf_counter()
        self._last_check = self.progress()
        balance = imbalance(self.scene, self.field, self.field.shape, self._mean_solver())
        nodes, share, regions = refill(self.field.nodes(), balance)
        if regions:
            self.field.set_nodes(nodes)
            self.optimizer = self._optimizer()
            self.repaired = {"repair": {"share": round(share, 4), "regions": regions,
                                        "median_imbalance": round(float(np.nanmedian(balance)), 4),
                                        "progress": round(self.progress(), 3)}}
        self.seconds += time.perf_counter() - began

    def step(self, tracer: Tracer) -> float:
        optimiser = self.config.optimiser
        positions, rows, columns, targets = self.dataset.ray_batch(
            optimiser.batch_size, self.rng, views_per_batch=optimiser.views_per_batch, mask=optimiser.mask)
        samples = self.pixel_samples()
        fitting_retardance = self.fitting_retardance()
        if fitting_retardance:
            targets = self.retardance.at(positions, rows, columns)
        pairs = self._neighbour_pairs(positions, rows, columns) if self.neighbour_loss_acts() else None
        pixel_rays = [np.repeat(a, samples) for a in (positions, rows, columns)]
        jitter = stratified(len(rows), samples, self.rng)
        if pairs is not None:
            # Traced in one batch with the pixels' own rays, through the pixel centres.
            pixel_rays = [np.concatenate([a, b]) for a, b in zip(pixel_rays, pairs.pixels)]
            jitter = np.concatenate([jitter, np.full((len(pairs.pixels[0]), 2), 0.5)])
        rays, right = self.view_rays.rays(*pixel_rays, jitter=jitter)
        self.optimizer.set_learning_rate(self.learning_rate())
        seed = optimiser.seed * 1_000_003 + self.iteration
        # The step follows the grid's spacing as it stands (coarse-to-fine).
        step_size = forward_step(self.config, self.field)
        traced = tracer.trace_rays(self.scene, rays, right, seed=seed, field=self.field, step_size=step_size,
                                   view=self.channels.view, replayable=True)
        own_rays = len(rows) * samples
        length = traced.length if pairs is None else _head(traced.length, own_rays)
        admitted = None
        limit = self.path_limit(length, samples)
        if limit is not None:
            # Opaque: a literal limit would rebuild the kernel every iteration.
            admitted = dr.select(dr.block_sum(length, samples) <= dr.opaque(mi.Float, samples * limit), 1.0, 0.0)
        with dr.resume_grad():
            leaf = tuple(mi.Float(x) for x in traced.state)
            dr.enable_grad(leaf)
            if fitting_retardance:
                loss = generator_loss(leaf, targets, samples)
            else:
                jones = traced.jones(leaf)
                own = jones if pairs is None else type(jones)(_head(x, own_rays) for x in jones)
                loss = l1_loss(own, targets, samples, admitted, self.channels)
            total = loss
            if pairs is not None:
                total = total + optimiser.neighbour_loss * pairs.loss(jones, own_rays)
            regulariser = self.config.regulariser
            # Coarse stages smooth plainly to choose the branch; the finest spares stress concentrations.
            # The scale is read only where it changes a weight: a grid's smoothness, relative to the field.
            relative = regulariser.relative_to is not None and self.field.lattice \
                and (regulariser.acts_on_gradients() or bool(regulariser.equilibrium)
                     or bool(regulariser.free_surface))
            field_rms = self._field_rms() if relative else None
            penalty = self.field.smoothness_penalty(regulariser.smoothness_at(self.smoothness_decayed(), field_rms),
                                                    regulariser.edge_at(field_rms) if self.in_finest_stage() else None)
            if penalty is not None:
                total = total + penalty
            balance = None
            if regulariser.equilibrium and KINDS[self.kind].trains_nodes:
                self._balance_mean()
                balance = self.field.equilibrium_penalty(regulariser.equilibrium_at(field_rms),
                                                         self._balance.stencil)
            if balance is not None:
                total = total + balance
            dr.backward(total)
            state_grad = dr.grad(leaf)
        tracer.backpropagate_rays(self.scene, rays, right, traced, state_grad, seed=seed, field=self.field,
                                  step_size=step_size, view=self.channels.view)
        value = float(total[0])
        if regulariser.free_surface:
            # Its own backward, after the rays': taken in one backward with the rays' loss, the texture lookups'
            # gradients left the rays' out of the step (the field stayed at zero).
            with dr.resume_grad():
                surface = self._free_surface().penalty(self.field, regulariser.free_surface_at(field_rms))
                dr.backward(surface)
            value += float(surface[0])
        self.field.finish_backward()
        self._check_divergence(value)
        self.optimizer.step()
        # The field follows the optimiser's new values at once: checkpoints and the result hold this step.
        self.field.assign(self.optimizer)
        if self.averaging():
            self._add_to_average()
        return value

    def neighbour_loss_acts(self) -> bool:
        """Whether this iteration adds the neighbour loss: over its share of the run, in the joint fit."""
        optimiser = self.config.optimiser
        return bool(optimiser.neighbour_loss) and not self.fitting_retardance() \
            and self.progress() < optimiser.neighbour_share

    def _neighbour_pairs(self, positions: np.ndarray, rows: np.ndarray, columns: np.ndarray) -> NeighbourPairs:
        """Every other pixel of the batch and a neighbour of each (:mod:`.neighbours`)."""
        if self.neighbour_targets is None:
            self.neighbour_targets = NeighbourTargets(self.dataset)
        return self.neighbour_targets.pairs(positions[::2], rows[::2], columns[::2], self.rng)

    def _free_surface(self) -> FreeSurfacePrior:
        """The free-surface prior's points, found once, about a 64th of the box apart."""
        if self._free is None:
            self._free = FreeSurfacePrior(self.scene, float(np.max(self.field.bbox_max - self.field.bbox_min)) / 64,
                                          self.config.optimiser.seed)
        return self._free

    def _mean_solver(self) -> equilibrium.MeanStressSolver:
        """The specimen's mean stress solver on the current grid, set up once per grid (the equilibrium prior
        and branch repair's checks share it)."""
        if self._balance is None or self._balance.stencil.shape != self.field.shape:
            self._balance = equilibrium.MeanStressSolver(equilibrium.specimen_stencil(
                self.scene, self.field.shape, self.field.bbox_min, self.field.bbox_max))
        return self._balance

    def _balance_mean(self) -> None:
        """Every :data:`BALANCE_EVERY` iterations and on a new grid, the mean stress that best balances the
        deviator (the equilibrium penalty's minimum over it: by the envelope theorem the penalty's gradient in
        the deviator is then its gradient with the mean held); the grid's cells whose centres lie inside the
        specimen are where it is asked."""
        solver = self._mean_solver()
        # A refined grid comes without one; a resumed run keeps its checkpoint's, as the run it resumes did.
        if self.field.mean is None or self.iteration % BALANCE_EVERY == 0:
            start = None if self.field.mean is None else np.array(self.field.mean)
            mean, _ = solver.solve(np.array(self.field.texture.tensor(), dtype=np.float64), start,
                                   solver.PRACTICAL_TOLERANCE)
            self.field.mean = mi.TensorXf(mean.astype(np.float32))

    def path_limit(self, length: mi.Float, samples: int) -> float | None:
        """The longest path (mm) whose pixels enter the loss now; None: all.

        Retardance, and with it phase wrapping, grows with the path through the
        specimen. Fitting short paths first gives the longer ones a field that
        is already nearly right, instead of the wrapped local minima a fit of
        all paths at once falls into. The limit grows geometrically over the
        first ``path_curriculum`` of the run, from the path that a tenth of the
        pixels stay under to the longest, both measured on the first batch
        (``length``: per ray, ``samples`` rays per pixel): the specimen's shape
        sets them, not its bounding box, whose thinnest side can exceed most
        paths (the kitten's does). The Two-step fit has unwrapped targets and a
        convex loss: no curriculum.
        """
        span = self.config.schedule.path_curriculum
        if self.progress() >= span or self.fitting_retardance():
            return None
        if self.path_range is None:
            paths = np.array(dr.block_sum(length, samples)) / samples
            paths = paths[paths > 0]
            if paths.size == 0:
                return None
            self.path_range = (float(np.quantile(paths, 0.1)), float(paths.max()) * 1.01)
        shortest, longest = self.path_range
        return shortest * (longest / shortest) ** (self.progress() / span)

    def _check_divergence(self, loss):
        norm = math.sqrt(sum(float(dr.sum(dr.square(_flat(dr.grad(self.optimizer[k]))))[0])
                             for k in self.optimizer.keys()))
        reason = None
        if not math.isfinite(loss):
            reason = f"the loss is {loss}"
        elif not math.isfinite(norm):
            reason = f"the gradient norm is {norm}"
        elif len(self.gradient_norms) == RECENT_GRADIENTS and norm > EXPLODING_FACTOR * np.median(self.gradient_norms):
            reason = (f"the gradient norm {norm:.3g} is {norm / np.median(self.gradient_norms):.3g} times the "
                      "recent median (exploding)")
        if reason is None:
            self.gradient_norms.append(norm)
            return
        self._diverged(reason)

    def _require_sane_field(self):
        """Raise :class:`DivergenceError` if the field holds NaN or inf, or has run away to stresses that
        no image of the dataset could resolve (:data:`RUNAWAY_ORDERS_PER_PIXEL`): the intensity loss is
        bounded, so a fit that flies off (a learning rate far too high) does not show in it."""
        if not all(np.isfinite(np.array(value)).all() for value in self.field.parameters().values()):
            self._diverged("the field's parameters hold NaN or inf")
        if self.magnitude_points is None:
            self.magnitude_points = metrics.evaluation_points(self.scene, specimen_shapes(self.scene),
                                                              MAGNITUDE_POINTS)
        largest = float(np.abs(sample(self.field, self.magnitude_points)).max(initial=0.0)) / self.field.stress_scale
        limit = RUNAWAY_ORDERS_PER_PIXEL * max(self.dataset.resolution)
        if not largest <= limit:
            self._diverged(f"the field ran away to {largest:.3g} stress scales (a scale, {self.field.stress_scale:.3g} "
                           f"MPa, gives about one fringe across the specimen), beyond the {limit:g} that "
                           f"{max(self.dataset.resolution)}-pixel images could ever resolve")

    def _diverged(self, reason):
        kept = "no checkpoint was written yet"
        if self.last_good is not None:
            kept = f"the last good checkpoint (iteration {self.last_good}) is kept"
            if self.output is not None:
                kept += f" in {self.output / CHECKPOINT}"
        raise DivergenceError(f"optimisation diverged at iteration {self.iteration}: {reason}; {kept}. Lower the "
                              "learning_rate or the step_size")

    def checkpoint(self) -> None:
        self._require_sane_field()      # a checkpoint is a good state to come back to
        self.last_good = self.iteration
        if self.output is None:
            return
        self.output.mkdir(parents=True, exist_ok=True)
        saved = Checkpoint(self.field, adam_moments(self.optimizer),
                           {name: np.array(total) for name, total in self.iterate_sums.items()},
                           self.iterates_averaged, self.iteration, self.seconds, self.history,
                           self.rng.bit_generator.state, self.path_range)
        saved.save(self.output / CHECKPOINT, self.config, self.dataset)

    def restore(self, path: Path) -> None:
        saved = Checkpoint.load(path, self.config, self.dataset)
        self.field = saved.field
        self.optimizer = self._optimizer()
        restore_adam_moments(self.optimizer, saved.adam)
        self.iteration, self.seconds, self.history = saved.iteration, saved.seconds, saved.history
        self.rng.bit_generator.state = saved.rng
        self.path_range = saved.path_range
        self.last_good = self.iteration
        self._last_check = self.progress()
        self.began_at = {k: v for k, v in (self.history[0] if self.history else {}).items()
                         if k in ("start", "start_factor", "start_seconds")}
        parameters = self.field.parameters()
        self.iterate_sums = {name: type(parameters[name])(total) for name, total in saved.averages.items()}
        self.iterates_averaged = saved.iterates_averaged

    def second_moment(self) -> np.ndarray | None:
        """A grid's Adam second moment (its nodes' five components, flat), the trust map's curvature; None for
        networks."""
        if not KINDS[self.kind].trains_nodes:
            return None
        return adam_moments(self.optimizer)["grid"][2]

    def result(self) -> Reconstruction:
        """The reconstruction: the field holds the mean of the averaged iterates where there are any."""
        if self.iterates_averaged:
            self.field.assign({name: total / self.iterates_averaged for name, total in self.iterate_sums.items()})
            self._require_sane_field()      # the last checkpoint checked the last iterate, not their mean
        origin = scene_origin(self.scene)
        source = {"dataset": str(self.dataset.directory.resolve()), "scene": self.scene.id(),
                  "dataset_source": self.dataset.index.get("source", {})}
        if origin is not None:
            source.update(scene_file=str(origin[0]), defines=origin[1])
        return Reconstruction(self.field, self.config, self.history, {}, self.seconds, source)


def _head(values: mi.Float, count: int) -> mi.Float:
    """The first ``count`` entries of ``values`` (differentiable)."""
    return dr.gather(mi.Float, values, dr.arange(mi.UInt32, count))


def _flat(values):
    return values.array if isinstance(values, mi.TensorXf) else values


