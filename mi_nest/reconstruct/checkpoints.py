"""What a reconstruction leaves on disk: checkpoints a rerun resumes from, and the saved result."""
from __future__ import annotations

import json
import zipfile
from contextlib import contextmanager
from dataclasses import dataclass, field as dataclass_field
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from ..dataset import Dataset
from ..io.atomic import atomic_path
from ..physics.aliasing import UNRESOLVED_BEAT_SHARE, UNRESOLVED_SHARE, bands_lost_phase, phase_lost
from ..render import RenderResult, render
from ..tracer import Tracer
from . import metrics
from .config import OptimizeConfig
from .fields import TrainableField, field_from_state
from .forward import make_tracer

CHECKPOINT = "checkpoint.npz"
# What every checkpoint holds; one without them was cut short or is not a checkpoint.
CHECKPOINT_KEYS = ("config", "dataset", "iteration", "iterates_averaged", "seconds", "history", "rng", "path_range")


class ReconstructionFileError(ValueError):
    """A file of a saved reconstruction (``reconstruction.json``, ``field.npz``) cannot be read."""


class CheckpointError(ValueError):
    """The output directory's checkpoint cannot be resumed from; ``problem`` says why, without the remedy
    (``resume=False`` here, ``--restart`` on the command line)."""

    def __init__(self, problem: str):
        super().__init__(f"{problem}; pass resume=False to start over")
        self.problem = problem


@dataclass
class Checkpoint:
    """A run's state between two iterations: what resuming needs to go on as if it had never stopped."""
    field: TrainableField
    adam: dict                       # parameter name -> Adam's (t, m, v) as NumPy arrays
    averages: dict                   # parameter name -> the sum of the averaged iterates (NumPy)
    iterates_averaged: int
    iteration: int
    seconds: float
    history: list
    rng: dict                        # the state of the batches' bit generator
    path_range: list | None          # the path curriculum's (shortest, longest), once measured

    def save(self, path: Path, config: OptimizeConfig, dataset: Dataset) -> None:
        """Write to ``path``, with the run's ``config`` and ``dataset``, which a resumed run must share."""
        state = {f"field.{k}": v for k, v in self.field.state().items()}
        for name, moments in self.adam.items():
            state.update({f"adam.{name}.{key}": value for key, value in zip("tmv", moments)})
        state.update({f"average.{name}": total for name, total in self.averages.items()})
        state.update({"iteration": self.iteration, "iterates_averaged": self.iterates_averaged,
                      "seconds": self.seconds, "history": json.dumps(self.history), "rng": json.dumps(self.rng),
                      "path_range": json.dumps(self.path_range), "config": json.dumps(config.to_dict()),
                      "dataset": str(dataset.directory.resolve()),
                      "dataset_content": dataset.fingerprint})
        with atomic_path(path, ".npz") as tmp:
            _save_npz(tmp, state)

    @classmethod
    def load(cls, path: Path, config: OptimizeConfig, dataset: Dataset) -> Checkpoint:
        """The checkpoint at ``path``; :class:`CheckpointError` if it is unreadable, cut short, or of a run
        with another ``config`` or ``dataset``."""
        state = _read_whole(path)
        other = _other_run(state, config, dataset)
        if other is not None:
            raise CheckpointError(f"{path} is a checkpoint of another run ({other}); choose another output "
                                  "directory")
        field_state = {k[len("field."):]: v for k, v in state.items() if k.startswith("field.")}
        field_state["config"] = json.loads(str(field_state["config"]))
        stress_field = field_from_state(field_state)
        adam = {name: tuple(state[f"adam.{name}.{key}"] for key in "tmv") for name in stress_field.parameters()}
        averages = {k[len("average."):]: v for k, v in state.items() if k.startswith("average.")}
        return cls(stress_field, adam, averages, int(state["iterates_averaged"]), int(state["iteration"]),
                   float(state["seconds"]), json.loads(str(state["history"])), json.loads(str(state["rng"])),
                   json.loads(str(state["path_range"])))


def _other_run(state, config, dataset):
    """How the run of a checkpoint's ``state`` differs from one with ``config`` on ``dataset``; None if not."""
    if OptimizeConfig.from_dict(json.loads(str(state["config"]))).to_dict() != config.to_dict():
        return "other options"
    if str(state["dataset"]) != str(dataset.directory.resolve()):
        return f"another dataset, {state['dataset']}"
    # Checkpoints from before the content was recorded have none: their dataset may have been replaced too.
    if str(state.get("dataset_content")) != dataset.fingerprint:
        return f"the dataset at {state['dataset']} as it was before it was replaced or changed"
    return None


def _read_whole(path):
    try:
        with np.load(path, allow_pickle=False) as data:
            state = {key: data[key] for key in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise CheckpointError(f"{path} is not a readable checkpoint ({error})") from error
    missing = [key for key in CHECKPOINT_KEYS if key not in state]
    if missing:
        raise CheckpointError(f"{path} is not a whole checkpoint (no {', '.join(missing)})")
    return state


def adam_moments(optimizer: dr.opt.Adam) -> dict:
    """Parameter name -> Adam's step count and first and second moments ``(t, m, v)``, as NumPy arrays."""
    moments = {}
    for name in optimizer.keys():
        _, _, _, extra = optimizer.state[name]
        moments[name] = tuple(np.array(x) for x in extra[:3])
    return moments


def restore_adam_moments(optimizer: dr.opt.Adam, moments: dict) -> None:
    """Give ``optimizer`` the ``(t, m, v)`` of :func:`adam_moments`."""
    for name in optimizer.keys():
        value, promoted, lr, extra = optimizer.state[name]
        t, m, v = (type(x)(saved) for x, saved in zip(extra[:3], moments[name]))
        optimizer.state[name] = (value, promoted, lr, (t, m, v, *extra[3:]))


@dataclass(repr=False)
class Reconstruction:
    """What :func:`~mi_nest.optimize` returns and ``mi-nest reconstruct`` writes: the reconstructed field, the
    configuration it was fitted with, its loss history, its metrics and where it came from.

    ``metrics`` holds ``test_psnr`` (dB, the 16 measurements of the held-out rotations over the specimen's
    pixels) and, for simulated data, ``deviatoric_error`` (relative, against the field the dataset was
    simulated from), ``principal_difference_error`` and for grids ``grid_floor`` (the lowest error any grid of
    this size can score). ``save(directory)`` writes ``field.npz`` and ``reconstruction.json``;
    ``Reconstruction.load(directory)`` reads them back; ``describe()`` is the summary the command prints;
    ``render(scene)`` renders the field in a scene's specimens.
    """
    field: TrainableField
    config: OptimizeConfig
    history: list                    # {iteration, loss, learning_rate, seconds}
    metrics: dict
    seconds: float
    source: dict = dataclass_field(default_factory=dict)   # the dataset and scene it was reconstructed from

    def __repr__(self) -> str:
        shown = {k: round(v, 4) for k, v in self.metrics.items() if k in ("deviatoric_error", "test_psnr")}
        return (f"Reconstruction({self.field.describe()}, {len(self.history)} iterations, {self.seconds:.1f} s"
                + "".join(f", {k}={v}" for k, v in shown.items()) + ")")

    def describe(self) -> str:
        """A few lines for a person: the field, the run, the errors and the held-out PSNR."""
        lines = [f"{self.field!r}: {self.field.parameter_count()} parameters, {len(self.history)} iterations in "
                 f"{self.seconds:.1f} s, final loss {self.history[-1]['loss']:.4f}" if self.history else ""]
        if "deviatoric_error" in self.metrics:
            floor = self.metrics.get("grid_floor")
            points = self.metrics.get("evaluation_points", 0)
            if floor is None:
                floor_text = ""
            elif metrics.floor_bounds_nothing(self.field, floor, points):
                floor_text = (f" (a grid of this size has as many nodes as the {points} evaluation points and can "
                              "pass through the truth at each: they set no floor)")
            else:
                floor_text = f" (the best any grid of this size can score: {100 * floor:.2f}%)"
            lines.append(f"relative deviatoric stress error {100 * self.metrics['deviatoric_error']:.2f}%{floor_text}, "
                         f"principal stress difference error {100 * self.metrics['principal_difference_error']:.2f}%")
        lines.append(self._aliasing_line())
        trust = self.metrics.get("trust")
        if trust and trust.get("nodes"):
            spread = "" if "seed_spread_median" not in trust else \
                (f", times one plus its seed spread over the median {trust['seed_spread_median']:.3g} MPa "
                 f"({len(trust['seed_spread_from'])} other run(s))")
            second_seed = "" if spread else \
                ("; where the error is the seed's it ranks it better once a second run (--option seed=1) is given "
                 "to mi-nest spread")
            lines.append(f"uncertainty (where to trust it; trust.npz: the equilibrium imbalance over the share of "
                         f"each node's cells inside the part{spread}): median {trust['uncertainty_median']:.3g}, "
                         f"95th percentile {trust['uncertainty_p95']:.3g} stress scales per box length{second_seed}")
        if "test_psnr" in self.metrics:
            lines.append(f"held-out PSNR {self.metrics['test_psnr']:.2f} dB over {self.metrics['test_views']} "
                         "rotations")
        return "\n".join(line for line in lines if line)

    def _aliasing_line(self) -> str:
        """What the data's fringe density says about this result: UNRELIABLE where the phase is lost; for bands
        whose fringes alias each alone, that their beat tells the orders apart; else nothing."""
        share, beat = self.metrics.get("aliased_share", 0.0), self.metrics.get("beat_aliased_share")
        if beat is None:
            if not phase_lost(share):
                return ""
            return (f"UNRELIABLE: the dataset's fringes are denser than the pixels in {100 * share:.0f}% of the "
                    f"specimen's pixels (over {100 * UNRESOLVED_SHARE:.0f}% loses the phase): expect large errors")
        if phase_lost(share, beat):
            return f"UNRELIABLE: in the dataset {bands_lost_phase(share, beat)}: expect large errors"
        if phase_lost(share):
            return (f"the fringes of each band are denser than the pixels in {100 * share:.0f}% of the specimen's "
                    f"pixels, their slowest beat in {100 * beat:.1f}% (up to {100 * UNRESOLVED_BEAT_SHARE:.0f}%): "
                    "the bands tell the fringe orders apart")
        return ""

    def save(self, directory: str | Path) -> Path:
        """Write ``field.npz`` and ``reconstruction.json`` into ``directory`` (atomically) and return it."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        with atomic_path(directory / "field.npz", ".npz") as tmp:
            _save_npz(tmp, self.field.state())
        record = {"config": self.config.to_dict(), "metrics": self.metrics, "seconds": self.seconds,
                  "field": self.field.describe(), "parameters": self.field.parameter_count(),
                  "source": self.source, "history": self.history}
        _write_record(directory, record)
        return directory

    @classmethod
    def load(cls, directory: str | Path) -> Reconstruction:
        """The reconstruction saved in ``directory`` (by :meth:`save` or ``mi-nest reconstruct``)."""
        directory = Path(directory)
        for name in ("field.npz", "reconstruction.json"):
            if not (directory / name).is_file():
                raise FileNotFoundError(f"{directory} is not a reconstruction: {name} missing")
        with _damaged_file(directory / "reconstruction.json"):
            record = json.loads((directory / "reconstruction.json").read_text())
            config = OptimizeConfig.from_dict(record["config"])
            history, metrics, seconds = record["history"], record["metrics"], record["seconds"]
        with _damaged_file(directory / "field.npz"):
            stress_field = load_field(directory / "field.npz")
        return cls(stress_field, config, history, metrics, seconds, record.get("source", {}))

    def tracer(self, scene: mi.Scene) -> Tracer:
        """The tracer this reconstruction renders ``scene`` with."""
        return make_tracer(self.config, self.field, scene)

    def render(self, scene: mi.Scene, **options) -> RenderResult:
        """Render ``scene`` with this field in place of its specimens' stress (see ``mi_nest.render``)."""
        return render(scene, field=self.field, **options)


def record_separation(directory: str | Path, entry: dict) -> None:
    """Add ``entry`` (a separation of this reconstruction: where it was written and how) to
    ``directory/reconstruction.json``'s ``separations``, replacing one written to the same ``output``. A run that
    resumes writes the record anew, without them: its field is no longer the one separated."""
    path = Path(directory) / "reconstruction.json"
    with _damaged_file(path):
        record = json.loads(path.read_text())
    record["separations"] = [kept for kept in record.get("separations", []) if kept.get("output") != entry["output"]]
    record["separations"].append(entry)
    _write_record(directory, record)


def record_trust(directory: str | Path, summary: dict) -> None:
    """Replace ``directory/reconstruction.json``'s trust summary (its ``metrics.trust``) with ``summary``: its
    trust map was written again (``mi-nest spread``)."""
    path = Path(directory) / "reconstruction.json"
    with _damaged_file(path):
        record = json.loads(path.read_text())
        record["metrics"]["trust"] = summary
    _write_record(directory, record)


def _write_record(directory: str | Path, record: dict) -> None:
    with atomic_path(Path(directory) / "reconstruction.json", ".json") as tmp:
        Path(tmp).write_text(json.dumps(record, indent=1))


@contextmanager
def _damaged_file(path):
    """A saved reconstruction's ``path`` that cannot be read (cut short, edited, another program's) as a
    :class:`ReconstructionFileError` naming it."""
    try:
        yield
    except (ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as error:
        reason = f"no {error}" if isinstance(error, KeyError) else str(error)
        raise ReconstructionFileError(f"{path} is damaged and cannot be read ({reason}); restore it from a copy, or "
                                      "run the mi-nest reconstruct command that wrote it again") from error


def load_field(path: str | Path) -> TrainableField:
    """The field of a saved reconstruction (``field.npz``)."""
    with np.load(path, allow_pickle=False) as data:
        state = {key: data[key] for key in data.files}
    state["config"] = json.loads(str(state["config"]))
    return field_from_state(state)


def _save_npz(path, state: dict) -> None:
    """``state`` as an ``.npz``, its dictionaries as JSON strings."""
    np.savez(path, **{k: (json.dumps(v) if isinstance(v, dict) else v) for k, v in state.items()})
