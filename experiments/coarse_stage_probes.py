"""Changes to the coarse stages that might choose a dense case's branch: each is the defaults' run with one change.

The accuracy suite's dense cases (the 300 N disk) end on a wrong branch that the coarse stages choose
(``stage_attribution.py``). Each probe here is the defaults' run (as ``mi-nest reconstruct DATA -o OUT --minutes M``,
the schedule spread over M minutes) with one change to the coarse stages, stopped at ``--stop`` seconds, where the
32-node stage ends (the error there ranks the runs' ends: 10.5% to 14.8% for runs that end at 5.6% to 10.7%, 22.1%
for the control's 18.8%):

- ``control``: no change (``--stop 198``: the 16-node stage's end, a result for ``elastic_completion.py``);
- ``trim``: the coarse stages below ``--below`` nodes leave out of their loss the ``--share`` of each batch's pixels
  that their field fits worst (those whose fringes it cannot hold);
- ``ladder``: another ladder of grids, ``--ladder`` nodes beginning at the shares ``--starts`` of the run;
- ``unsmoothed``: the stage of ``--nodes`` nodes without its smoothness;
- ``lbfgs``: at ``--at`` seconds the field is handed to L-BFGS on one fixed set of ``--pixels`` pixels
  (``--samples`` rays each, the stage's smoothness included) for ``--evaluations`` loss evaluations; the error
  before and after is recorded (its time counts against the run).

Writes ``experiments/results/coarse_stage_probes.csv`` (a row per probe and setting, replacing the same one's
earlier row) with the error at each stage's end and at the stop, and the held-out PSNR:

    .venv/bin/python experiments/coarse_stage_probes.py control --stop 198
    .venv/bin/python experiments/coarse_stage_probes.py trim --share 0.2 --below 32
    .venv/bin/python experiments/coarse_stage_probes.py ladder --ladder 8,32,64 --starts 0,0.25,0.5
    .venv/bin/python experiments/coarse_stage_probes.py unsmoothed --nodes 32
    .venv/bin/python experiments/coarse_stage_probes.py lbfgs --at 296 --pixels 98304

The dataset is the accuracy suite's (``benchmarks/accuracy_suite.py``, simulated there first).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import scipy.optimize

import common

import mi_nest
from mi_nest.reconstruct import loop, losses, optimization
from mi_nest.reconstruct.forward import forward_step
from mi_nest.reconstruct.rays import stratified
from stage_attribution import stage_ends, suite_dataset

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "benchmarks"))
from accuracy_suite import CASES, read_rows  # noqa: E402
from reconstruction import cpu_name  # noqa: E402

TRACK_EVERY = 200
# The seed of the L-BFGS probe's fixed pixels and their rays' jitter.
LBFGS_SEED = 123


def per_pixel_error(q, targets: np.ndarray, pixel_samples: int, channels) -> np.ndarray:
    """The L1 error of each pixel's intensities (detached): what :func:`~mi_nest.reconstruct.losses.l1_loss`
    sums."""
    error = np.zeros(len(targets))
    for channel, predicted in enumerate(channels.intensities(q)):
        predicted = dr.detach(predicted)
        if pixel_samples > 1:
            predicted = dr.block_sum(predicted, pixel_samples) / pixel_samples
        error += np.abs(np.array(predicted) - targets[:, channel])
    return error


def probe_run(args) -> type[loop.Run]:
    """The defaults' :class:`~mi_nest.reconstruct.loop.Run` with ``args``' change, stopped at ``args.stop``; its
    ladder goes into ``ladder`` and what the L-BFGS probe measured into ``measured``."""

    class ProbeRun(loop.Run):
        ladder, measured = [], {}

        def _stages(self):
            stages = super()._stages()
            if args.probe == "ladder":
                stages = list(zip(args.starts, args.ladder))
            ProbeRun.ladder[:] = stages
            return stages

        def step(self, tracer):
            if args.probe == "unsmoothed" and self.field.config.resolution == args.nodes:
                # The field's own penalty, for this grid only: a refined grid comes with its own.
                self.field.smoothness_penalty = lambda *_, **__: None
            return super().step(tracer)

        def out_of_time(self) -> bool:
            if args.probe == "lbfgs" and not ProbeRun.measured and self.seconds >= args.at:
                self.lbfgs()
            if self.seconds >= args.stop:
                self.checkpoint()
                return True
            return super().out_of_time()

        def lbfgs(self) -> None:
            began = time.perf_counter()
            rng = np.random.default_rng(LBFGS_SEED)
            positions, rows, columns, targets = self.dataset.ray_batch(
                args.pixels, rng, views_per_batch=args.views, mask=self.config.optimiser.mask)
            pixel_rays = [np.repeat(a, args.samples) for a in (positions, rows, columns)]
            rays, right = self.view_rays.rays(*pixel_rays, jitter=stratified(len(rows), args.samples, rng))
            tracer, step_size = self.tracer(), forward_step(self.config, self.field)
            regulariser = self.config.regulariser
            weight = regulariser.smoothness_at(self.smoothness_decayed(), self._field_rms())
            shape = np.array(self.field.parameters()["grid"]).shape

            def loss_and_gradient(x):
                grid = mi.TensorXf(x.astype(np.float32).reshape(shape))
                dr.enable_grad(grid)
                self.field.assign({"grid": grid})
                traced = tracer.trace_rays(self.scene, rays, right, seed=LBFGS_SEED, field=self.field,
                                           step_size=step_size, view=self.channels.view, replayable=True)
                with dr.resume_grad():
                    leaf = tuple(mi.Float(x) for x in traced.state)
                    dr.enable_grad(leaf)
                    total = losses.l1_loss(traced.jones(leaf), targets, args.samples, None, self.channels)
                    penalty = self.field.smoothness_penalty(weight)
                    if penalty is not None:
                        total = total + penalty
                    dr.backward(total)
                    state_grad = dr.grad(leaf)
                tracer.backpropagate_rays(self.scene, rays, right, traced, state_grad, seed=LBFGS_SEED,
                                          field=self.field, step_size=step_size, view=self.channels.view)
                return float(total[0]), np.array(dr.grad(grid), dtype=np.float64).ravel()

            start = np.array(self.field.parameters()["grid"], dtype=np.float64).ravel()
            before_error = self.error_probe(self.field)
            before_loss = loss_and_gradient(start)[0]
            fit = scipy.optimize.minimize(loss_and_gradient, start, jac=True, method="L-BFGS-B",
                                          options={"maxfun": args.evaluations, "maxiter": args.evaluations})
            self.field.set_nodes(fit.x.reshape(-1, 5))
            self.optimizer = self._optimizer()
            spent = time.perf_counter() - began
            self.seconds += spent
            ProbeRun.measured.update(lbfgs_error_before=round(before_error, 4), lbfgs_loss_before=round(before_loss, 5),
                                     lbfgs_error_after=round(self.error_probe(self.field), 4),
                                     lbfgs_loss_after=round(float(fit.fun), 5), lbfgs_evaluations=int(fit.nfev),
                                     lbfgs_seconds=round(spent, 1))
            print(f"L-BFGS: {ProbeRun.measured}", flush=True)

    return ProbeRun


def trimming(args, run_class):
    """:func:`~mi_nest.reconstruct.losses.l1_loss` that, in the stages below ``args.below`` nodes, weighs out the
    ``args.share`` of each batch's pixels with the largest error."""
    plain = losses.l1_loss

    def trimmed(q, targets, pixel_samples=1, weights=None, channels=losses.NOMINAL):
        run = run_class.current
        if run is not None and run.field.config.resolution < args.below:
            targets = np.asarray(targets, dtype=np.float32)
            error = per_pixel_error(q, targets, pixel_samples, channels)
            counted = np.ones(len(targets)) if weights is None else np.array(weights, dtype=np.float64)
            kept = error <= np.quantile(error[counted > 0], 1.0 - args.share)
            weights = mi.Float((counted * kept).astype(np.float32))
        return plain(q, targets, pixel_samples, weights, channels)
    return trimmed


def setting(args) -> str:
    """The probe's setting, as the CSV's key names it."""
    return {"control": lambda: "none",
            "trim": lambda: f"share {args.share:g} below {args.below}",
            "ladder": lambda: f"{','.join(map(str, args.ladder))} from {','.join(f'{s:g}' for s in args.starts)}",
            "unsmoothed": lambda: f"{args.nodes} nodes",
            "lbfgs": lambda: (f"at {args.at:g} s, {args.pixels} pixels of {args.views} views x {args.samples}, "
                             f"{args.evaluations} evaluations")
            }[args.probe]()


def ended_stages(history: list[dict], stages: list[tuple[float, int]], seconds: float, stop: float) -> dict:
    """:func:`stage_ends` of the stages that ended before the run stopped at ``stop`` seconds."""
    ends = stage_ends(history, stages, seconds)
    ended = {resolution for (_, resolution), following in zip(stages, [s for s, _ in stages[1:]] + [1.0])
             if following * seconds <= stop + 1.0}
    return {key: value for key, value in ends.items() if int(key.rsplit("_", 1)[1]) in ended}


def numbers(text: str, kind=int) -> list:
    try:
        return [kind(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a comma-separated list of numbers") from None


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    by_name = {case.name: case for case in CASES}
    parser.add_argument("probe", choices=("control", "trim", "ladder", "unsmoothed", "lbfgs"))
    parser.add_argument("--case", default="disk_300N", choices=sorted(by_name), metavar="CASE",
                        help="an accuracy suite case (default: disk_300N)")
    parser.add_argument("--minutes", type=float, default=10.0, help="of the schedule (default: 10)")
    parser.add_argument("--stop", type=float, default=322.0,
                        help="seconds after which the run stops (default 322: the 32-node stage's end in 10 minutes)")
    parser.add_argument("--share", type=float, default=0.2, help="trim: the share of each batch left out")
    parser.add_argument("--below", type=int, default=32, help="trim: in the stages of fewer nodes than this")
    parser.add_argument("--ladder", type=numbers, default=[8, 32, 64], help="ladder: nodes of each stage")
    parser.add_argument("--starts", type=lambda t: numbers(t, float), default=[0.0, 0.25, 0.5],
                        help="ladder: the share of the run at which each stage begins")
    parser.add_argument("--nodes", type=int, default=32, help="unsmoothed: the stage")
    parser.add_argument("--at", type=float, default=296.0, help="lbfgs: seconds into the run")
    parser.add_argument("--pixels", type=int, default=98_304, help="lbfgs: fixed pixels")
    parser.add_argument("--views", type=int, default=32, help="lbfgs: training rotations the pixels come from")
    parser.add_argument("--samples", type=int, default=4, help="lbfgs: rays a pixel")
    parser.add_argument("--evaluations", type=int, default=150, help="lbfgs: loss evaluations")
    parser.add_argument("--output", type=Path, default=HERE / "experiments" / "out" / "coarse_stage_probes")
    args = parser.parse_args()
    if not args.minutes > 0 or not args.stop > 0:
        raise SystemExit("--minutes and --stop must be positive")
    if not 0 < args.share < 1:
        raise SystemExit(f"--share must lie in (0, 1), got {args.share:g}")
    if args.probe == "ladder" and (len(args.ladder) != len(args.starts) or args.starts[0] != 0
                                   or sorted(args.starts) != args.starts):
        raise SystemExit("--starts needs one rising share per --ladder stage, the first 0")
    case = by_name[args.case]
    dataset, scene, _ = suite_dataset(case)
    run_class = probe_run(args)

    class Tracked(run_class):
        current = None

        def __init__(self, *arguments, **options):
            Tracked.current = self
            super().__init__(*arguments, **options)
    if args.probe == "trim":
        loop.l1_loss = trimming(args, Tracked)
    optimization.Run = Tracked
    print(f"CPU: {cpu_name()}", flush=True)
    result = mi_nest.optimize(scene, dataset, output=args.output / f"{case.name}_{args.probe}_{args.stop:g}s", resume=False,
                              progress=False, time_limit=60.0 * args.minutes, iterations=10 ** 9,
                              track_error_every=TRACK_EVERY)
    row = {"case": case.name, "probe": args.probe, "setting": f"{setting(args)}; stop {args.stop:g} s",
           "ladder": " ".join(str(r) for _, r in run_class.ladder),
           **ended_stages(result.history, run_class.ladder, 60.0 * args.minutes, args.stop), **run_class.measured,
           "error_at_stop": round(result.metrics["deviatoric_error"], 4), "stop_s": args.stop,
           "test_psnr": round(result.metrics["test_psnr"], 2), "iterations": len(result.history),
           "minutes": args.minutes, "cpu": cpu_name()}
    table = HERE / "experiments" / "results" / "coarse_stage_probes.csv"
    rows = [r for r in read_rows(table) if (r["case"], r["probe"], r["setting"]) !=
            (row["case"], row["probe"], row["setting"])]
    common.write_table(rows + [row], table)
    print(row, flush=True)


if __name__ == "__main__":
    main()
