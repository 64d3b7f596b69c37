"""The seed spread of several reconstructions of one dataset (``mi-nest spread``): each run's trust map gains the
deviator's spread over the others at its nodes, and its uncertainty counts it.

Where a reconstruction's error is mostly the seed's (its batches, its start), one run's imbalance cannot see it:
on the disks in air and in water two runs rank each other's error at only 0.27 to 0.30 in 3 minutes. The
difference between two runs shares each run's own error; counted in the uncertainty it ranks the actual error at
0.53 to 0.56 there, against 0.40 to 0.45 without it, and at 0.52 to 0.84 on all sixteen results of eight suite
cases, above the uncertainty alone on each; at the suite's 10 minutes, 0.51 to 0.62 on the networks and the
refracting disks, against 0.44 to 0.58 (``benchmarks/trust_ranking.py``, docs/reconstruction.md "Where to trust
it").
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from scipy.stats import spearmanr

from .. import occupancy
from ..dataset import Dataset
from ..dataset.truth import recorded_truth
from ..io.lock import locked_directory
from ..scene import specimen_shapes
from .checkpoints import Reconstruction, record_trust
from .trust import READ_ERRORS, TRUST_FILE, TrustMap, error_map, seed_spread

# Fewer runs than this have no spread.
FEWEST_RUNS = 2


@dataclass
class SpreadResult:
    """One run's share of a spread: its directory, its trust map's new summary, and for a run scored against a
    simulated dataset's truth the Spearman rank correlations of its uncertainty with its actual deviatoric error at
    the nodes inside the part, with the spread and without it."""
    directory: Path
    summary: dict
    ranking: tuple[float, float] | None = None


def error_ranking(result: Reconstruction, trust: TrustMap) -> tuple[float, float] | None:
    """How the uncertainty with and without its seed spread ranks ``result``'s actual error (None for a run
    not scored against a truth)."""
    if "deviatoric_error" not in result.metrics:
        return None
    scene, truth = recorded_truth(Dataset(result.source["dataset"]))
    nodes = trust.nodes()
    with_spread, without = trust.uncertainty.ravel(), replace(trust, seed_spread=None).uncertainty.ravel()
    inside = occupancy.inside(scene, specimen_shapes(scene), nodes) & np.isfinite(with_spread)
    error = error_map(result.field, truth, nodes[inside])
    return tuple(float(spearmanr(uncertainty[inside], error).statistic) for uncertainty in (with_spread, without))


def write_seed_spread(directories: list[str | Path]) -> list[SpreadResult]:
    """Give each reconstruction in ``directories`` (two or more, one dataset) its :attr:`TrustMap.seed_spread`
    over the others, in its ``trust.npz`` and its ``reconstruction.json``'s trust summary. Every directory is
    checked before any is written, and each is held against other writers while it is."""
    paths = [Path(directory) for directory in directories]
    if len(paths) < FEWEST_RUNS:
        raise ValueError(f"a seed spread compares two or more reconstructions of one dataset, got {len(paths)}: run "
                         "mi-nest reconstruct on the same data again with --option seed=1 -o OTHER and give both")
    resolved = [path.resolve() for path in paths]
    repeated = next((path for path, where in zip(paths, resolved) if resolved.count(where) > 1), None)
    if repeated is not None:
        raise ValueError(f"{repeated} is given twice: a run's spread is over the other runs")
    results = [Reconstruction.load(path) for path in paths]
    datasets = [Path(result.source.get("dataset", "")).resolve() for result in results]
    for path, dataset in zip(paths[1:], datasets[1:]):
        if dataset != datasets[0]:
            raise ValueError(f"{paths[0]} was reconstructed from {datasets[0]} and {path} from {dataset}: a seed "
                             "spread compares runs of one dataset")
    maps = []
    for path in paths:
        if not (path / TRUST_FILE).is_file():
            raise ValueError(f"{path} has no trust map ({TRUST_FILE}): run the mi-nest reconstruct command that "
                             "wrote it again")
        try:
            maps.append(TrustMap.load(path / TRUST_FILE))
        except READ_ERRORS as error:
            raise ValueError(f"{path / TRUST_FILE} is damaged and cannot be read ({error}); run the mi-nest "
                             "reconstruct command that wrote it again") from error
    spreads = []
    for index, (path, result, trust) in enumerate(zip(paths, results, maps)):
        others = [other.field for position, other in enumerate(results) if position != index]
        measured = np.isfinite(trust.imbalance.ravel())
        spread = np.full(trust.imbalance.size, np.nan)
        spread[measured] = seed_spread(result.field, others, trust.nodes()[measured])
        if not np.nanmedian(spread[measured]) > 0:
            raise ValueError(f"{path} holds the same field as the other runs at most of its nodes (the same seed, "
                             "or a copy): run mi-nest reconstruct again with another --option seed=N")
        spreads.append(spread)
    written = []
    with contextlib.ExitStack() as held:
        for path in paths:
            held.enter_context(locked_directory(path))
        for path, where, trust, spread in zip(paths, resolved, maps, spreads):
            trust.seed_spread = spread.reshape(trust.imbalance.shape)
            trust.save(path / TRUST_FILE)
            summary = trust.summary() | {"seed_spread_from": [str(other) for other in resolved if other != where]}
            record_trust(path, summary)
            written.append(SpreadResult(path, summary))
    for entry, result, trust in zip(written, results, maps):
        entry.ranking = error_ranking(result, trust)
    return written
