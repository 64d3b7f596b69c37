"""Does a reconstruction's trust map rank its actual error? (issue 34, "where to trust it")

For each finished reconstruction given (``mi-nest reconstruct`` output directories of simulated datasets, such as
the accuracy suite's), computes its trust map (``mi_nest.reconstruct.trust``) and the deviatoric error norm against
the field the dataset was simulated from at the map's nodes inside the specimen, and prints the Spearman rank
correlation of each trust term and of the uncertainty with the error, with the CPU and the seconds the map took.
Where the same case's result with the other seed lies beside it (the suite's ``CASE`` and ``CASE_seed1``), also
the rank correlation of the two runs' actual error maps (``rho_twin_error``): how much of the error repeats
from run to run, a yardstick for the trust terms where the error is mostly the seed's; that of the seed spread
the twin gives (``rho_seed_spread``, ``mi_nest.reconstruct.trust.seed_spread``) with this run's error; and that
of the uncertainty counting it, as ``mi-nest spread`` writes it (``rho_uncertainty_with_spread``). ``rho_imbalance_bulk``: the
imbalance's rank correlation over the 80% of the nodes where it is lowest.
Each result's ``trust.npz`` is written again with the map computed here (its curvature spread from the Adam
moments of its ``checkpoint.npz``; results made before runs wrote their trust map get one).

    python benchmarks/trust_ranking.py experiments/out/accuracy_suite/accuracy_suite/*

Writes ``experiments/results/trust_ranking.csv``.
"""
from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

import mi_nest  # noqa: F401  (sets the variant)
from mi_nest import occupancy
from mi_nest.dataset import Dataset
from mi_nest.dataset.truth import recorded_truth
from mi_nest.reconstruct import Reconstruction
from mi_nest.reconstruct.evaluation import heldout_predictions
from mi_nest.reconstruct.trust import TRUST_FILE, error_map, seed_spread, trust_map
from mi_nest.scene import specimen_shapes
from reconstruction import cpu_name

HERE = Path(__file__).resolve().parents[1]
TERMS = ("uncertainty", "imbalance", "curvature_spread", "heldout_residual", "coverage", "direction_spread")
BULK = 0.8      # the share of the nodes, lowest imbalance first, whose ranking is reported on its own


def rank(directory: Path) -> dict:
    result = Reconstruction.load(directory)
    dataset = Dataset(result.source["dataset"])
    scene, truth = recorded_truth(dataset)
    start = time.perf_counter()
    predictions = heldout_predictions(scene, dataset, result.field, result.tracer(scene),
                                      result.config.reporting.evaluate_views)
    second_moment = None
    if (directory / "checkpoint.npz").is_file() and result.field.kind == "grid":
        with np.load(directory / "checkpoint.npz") as checkpoint:
            second_moment = checkpoint["adam.grid.v"]
    trust = trust_map(scene, dataset, result.field, predictions, result.config.optimiser.mask, second_moment)
    seconds = time.perf_counter() - start
    trust.save(directory / TRUST_FILE)
    nodes = trust.nodes()
    inside = occupancy.inside(scene, specimen_shapes(scene), nodes)
    error = error_map(result.field, truth, nodes[inside])
    row = {"case": directory.name, "nodes": int(inside.sum()), "trust_s": round(seconds, 1),
           "deviatoric_error": round(result.metrics.get("deviatoric_error", float("nan")), 4),
           "error_cv": round(float(np.std(error) / np.mean(error)), 3)}
    inside_values = {term: getattr(trust, term).ravel()[inside] for term in TERMS if getattr(trust, term) is not None}
    for term in TERMS:
        if term not in inside_values:  # a network keeps no Adam moments per node: no curvature spread
            row[f"rho_{term}"] = float("nan")
            continue
        values = inside_values[term]
        finite = np.isfinite(values)
        row[f"rho_{term}"] = round(float(spearmanr(values[finite], error[finite]).statistic), 3)
    # Below the imbalance's 80th percentile: away from where it concentrates, does anything still rank the error?
    imbalance = inside_values["imbalance"]
    bulk = np.isfinite(imbalance) & (imbalance < np.nanquantile(imbalance, BULK))
    row["rho_imbalance_bulk"] = round(float(spearmanr(imbalance[bulk], error[bulk]).statistic), 3)
    twin = seed_twin(directory, result)
    row["rho_twin_error"] = row["rho_seed_spread"] = row["rho_uncertainty_with_spread"] = float("nan")
    if twin is not None:
        row["rho_twin_error"] = round(float(spearmanr(error_map(twin.field, truth, nodes[inside]), error).statistic), 3)
        # As mi-nest spread writes it: at the nodes whose imbalance is measured.
        measured = inside & np.isfinite(trust.imbalance.ravel())
        spread = np.full(len(nodes), np.nan)
        spread[measured] = seed_spread(result.field, [twin.field], nodes[measured])
        row["rho_seed_spread"] = round(float(spearmanr(spread[measured], error[measured[inside]]).statistic), 3)
        trust.seed_spread = spread.reshape(trust.imbalance.shape)
        uncertainty = trust.uncertainty.ravel()[inside]
        both = np.isfinite(uncertainty)
        row["rho_uncertainty_with_spread"] = round(float(spearmanr(uncertainty[both], error[both]).statistic), 3)
    row["cpu"] = cpu_name()
    return row


def seed_twin(directory: Path, result: Reconstruction) -> Reconstruction | None:
    """The same case's result with the other seed beside ``directory`` (the suite's ``CASE`` and ``CASE_seed1``,
    same dataset), or None. How well its actual error map ranks this one's is the share of the error that
    repeats from run to run; the rest is the seed's, which a map computed from one run cannot foresee."""
    name = directory.name
    other = directory.parent / (name.removesuffix("_seed1") if name.endswith("_seed1") else f"{name}_seed1")
    if not (other / "field.npz").is_file():
        return None
    twin = Reconstruction.load(other)
    return twin if twin.source["dataset"] == result.source["dataset"] else None


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", nargs="+", type=Path)
    parser.add_argument("--csv", type=Path, default=HERE / "experiments" / "results" / "trust_ranking.csv")
    args = parser.parse_args()
    rows = []
    for directory in args.results:
        row = rank(directory)
        print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)
        rows.append(row)
    args.csv.parent.mkdir(parents=True, exist_ok=True)
    with open(args.csv, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
