"""Sharded dataset rendering: one process against a Dask LocalCluster of 1 and of 2 workers (issue 38).

Renders the same dataset (the disk, read noise 0.01) three ways in one run, each into a fresh directory: in this
process, and as tasks on a LocalCluster of 1 and 2 worker processes (one task at a time each, Dr.Jit on the cores
divided among them, so the cores are not oversubscribed). Prints the wall times (the cluster's start apart), the
render and write seconds the tasks spent, the scheduling overhead per task (the wall time a cluster adds to its
workers' busy time, per rotation, and the round trip of an empty task), checks the datasets are the same channel
for channel, and projects what N machines would give from the per-task cost.

    python benchmarks/cluster.py                         # 16 x 16 rotations at 128 px
    python benchmarks/cluster.py --rotations 8 --res 64  # a quick look
"""
import argparse
import os
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from reconstruction import cpu_name


# Tasks that do nothing, timed to tell the scheduler's round trip.
EMPTY_TASKS = 200


def empty_task_round_trip(client, tasks: int = EMPTY_TASKS) -> float:
    """Seconds per task of submitting and gathering ``tasks`` tasks that do nothing."""
    start = time.perf_counter()
    client.gather(client.map(int, range(tasks), pure=False))
    return (time.perf_counter() - start) / tasks


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rotations", type=int, default=16, help="azimuths and elevations (default: 16)")
    parser.add_argument("--res", type=int, default=128, help="image width and height (default: 128)")
    args = parser.parse_args()

    from mi_nest.cluster import ClusterConfig, connect
    from mi_nest.dataset import CameraModel, SimulationSettings, simulate
    from mi_nest.dataset.sharded import render_on_cluster  # noqa: F401  (imported before the clock starts)
    from mi_nest.io.exr import read_channels

    settings = SimulationSettings(azimuths=args.rotations, elevations=args.rotations, res=args.res,
                                  camera=CameraModel(read_noise=0.01))
    rotations = args.rotations ** 2
    print(f"CPU: {cpu_name()}, {os.cpu_count()} cores; disk, {args.rotations} x {args.rotations} rotations at "
          f"{args.res} px", flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as scratch, warnings.catch_warnings():
        warnings.simplefilter("ignore")       # the oblique views alias; not what is timed
        for label, workers in (("one process", None), ("LocalCluster, 1 worker", 1), ("LocalCluster, 2 workers", 2)):
            output = Path(scratch) / label.replace(" ", "_").replace(",", "")
            start = started = time.perf_counter()
            if workers is None:
                report = simulate("disk_compression", output, settings, progress=False)
                round_trip = None
            else:
                # The cluster's start is timed apart: a sweep starts it once for all its datasets.
                with connect(ClusterConfig(workers=workers), say=lambda line: None) as cluster:
                    round_trip = empty_task_round_trip(cluster.client)
                    started = time.perf_counter()
                    report = simulate("disk_compression", output, settings, progress=False, cluster=cluster)
            wall = time.perf_counter() - started
            cluster_start = started - start - EMPTY_TASKS * round_trip if workers else 0.0
            rows.append((label, workers, cluster_start, wall, report, round_trip, output))
            print(f"{label}: {wall:.2f} s", flush=True)
        reference = {p.name: read_channels(p) for p in sorted((rows[0][6] / "rotations").glob("*.exr"))}
        for label, *_, output in rows[1:]:
            for name, channels in reference.items():
                other = read_channels(output / "rotations" / name)
                assert all(np.array_equal(v, other[k]) for k, v in channels.items()), f"{label}: {name} differs"
    print(f"\nEvery dataset the same as the one process's, channel for channel ({rotations} rotations).\n")
    print("| run | cluster start | wall | render (summed) | write (summed) | wall per rotation | speed-up |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for label, workers, start, wall, report, _, _ in rows:
        print(f"| {label} | {'' if workers is None else f'{start:.1f} s'} | {wall:.2f} s | "
              f"{report.render_seconds:.2f} s | {report.write_seconds:.2f} s | {1e3 * wall / rotations:.1f} ms | "
              f"{rows[0][3] / wall:.2f}x |")
    one_worker = rows[1]
    busy = one_worker[4].render_seconds + one_worker[4].write_seconds
    overhead = (one_worker[3] - busy) / rotations
    per_task = one_worker[3] / rotations
    print(f"\nScheduling overhead: {1e3 * overhead:.1f} ms per rotation on 1 worker (its wall time less its "
          f"render and write time); an empty task's round trip {1e3 * rows[1][5]:.2f} ms.")
    print(f"Per-task cost on 1 worker of this machine: {1e3 * per_task:.1f} ms. N such machines (a worker each) "
          f"would take about {per_task * rotations:.1f} s / N for this dataset, plus the cluster's start; the "
          f"paper's 32 x 32 rotations at 512 px, scaling the cost by the pixels, about "
          f"{per_task * 1024 * (512 / args.res) ** 2 / 60:.0f} min / N.")


if __name__ == "__main__":
    main()
