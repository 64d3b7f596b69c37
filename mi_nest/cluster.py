"""Work beyond one process, on Dask distributed: an embedded ``LocalCluster`` by default, a real cluster by its
scheduler's address.

mi_nest hands a cluster tasks that name their inputs by file (a scene's XML, a dataset's directory) and write
their results as today's atomic files: Mitsuba objects never travel, a worker loads what it needs itself, and a
task that a dead worker left half done is simply done again. Before any task, every worker must import the same
mi_nest as this process (version and source), or the run is refused: a worker with other code would write
other numbers into the same dataset.
"""
from __future__ import annotations

import hashlib
import logging
import os
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path

from .arguments import whole_number
from . import version

# The scheduler option's value that starts an embedded cluster on this machine.
LOCAL = "local"
# Seconds to wait for a remote scheduler to answer, and for a cluster to have its first worker.
CONNECT_TIMEOUT = 30


class ClusterError(ValueError):
    """A cluster that cannot be used: unreachable, without workers, or with workers running other code."""


@dataclass(frozen=True)
class ClusterConfig:
    """Where tasks run: ``scheduler`` is :data:`LOCAL` (a ``LocalCluster`` of ``workers`` processes on this
    machine, one task at a time each) or a Dask scheduler's address (``tcp://host:8786``), whose workers are
    started with ``dask worker ADDRESS --nthreads 1``."""
    scheduler: str = LOCAL
    workers: int | None = None       # LocalCluster processes (default: this machine's cores); not for an address

    def __post_init__(self):
        if not self.scheduler or not self.scheduler.strip():
            raise ValueError("the scheduler must be 'local' or a Dask scheduler's address such as tcp://host:8786")
        if self.workers is not None:
            whole_number("workers", self.workers)
            if self.scheduler != LOCAL:
                raise ValueError("--workers sets the processes of a local cluster; a remote cluster has the workers "
                                 "started on its machines (dask worker ADDRESS)")

    @property
    def local_workers(self) -> int:
        return self.workers or max(1, os.cpu_count() or 1)


@dataclass
class Cluster:
    """A connected client and how each worker should use its cores: ``drjit_threads`` is Dr.Jit's thread pool per
    worker (None: all of its machine's cores, a remote worker's own)."""
    client: object
    drjit_threads: int | None
    dashboard: str | None


def source_digest() -> str:
    """A short hash of mi_nest's Python sources as this process imports them: two installs that would compute
    differently hash differently, whatever their version says."""
    from importlib.util import find_spec
    package = Path(__file__).resolve().parent
    # The plugins are a package of their own in a checkout (plugins/, installed as mi_nest.plugins).
    plugins = Path(find_spec("mi_nest.plugins").origin).resolve().parent
    digest = hashlib.sha256()
    for root, name in ((package, "mi_nest"), (plugins, "mi_nest.plugins")):
        for path in sorted(root.rglob("*.py")):
            digest.update(f"{name}/{path.relative_to(root)}".encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def worker_identity() -> dict:
    """What a worker imports as mi_nest (run on each worker)."""
    return {"version": version.__version__, "source": source_digest(), "path": str(Path(__file__).resolve().parent)}


def require_same_mi_nest(client) -> None:
    """Raise :class:`ClusterError` naming every worker whose mi_nest is missing or is not this process's."""
    ours = {"version": version.__version__, "source": source_digest()}
    answers = client.run(worker_identity, on_error="return")
    wrong = []
    for address, answer in sorted(answers.items()):
        if isinstance(answer, BaseException):
            wrong.append(f"{address} cannot import mi_nest ({type(answer).__name__}: {answer})")
        elif answer["version"] != ours["version"]:
            wrong.append(f"{address} runs mi_nest {answer['version']} (from {answer['path']}), this process "
                         f"{ours['version']}")
        elif answer["source"] != ours["source"]:
            wrong.append(f"{address} runs mi_nest {answer['version']} from {answer['path']} with other source files")
    if wrong:
        raise ClusterError(f"{len(wrong)} of {len(answers)} worker(s) cannot run this mi_nest: {'; '.join(wrong)}. "
                           "Install the same mi_nest (pip install -e . from the same checkout) on every worker and "
                           "restart them")


@contextmanager
def connect(config: ClusterConfig, say: Callable[[str], None] = print) -> Iterator[Cluster]:
    """A :class:`Cluster` for the block: a ``LocalCluster`` started for it, or the scheduler at
    ``config.scheduler``; its workers checked (:func:`require_same_mi_nest`) and the dashboard's address said."""
    from distributed import Client, LocalCluster
    local = None
    try:
        if config.scheduler == LOCAL:
            workers = config.local_workers
            # One task at a time per process, each process's Dr.Jit on its share of the cores: no oversubscription.
            local = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                                 silence_logs=logging.ERROR)
            client = Client(local)
            drjit_threads = max(1, (os.cpu_count() or 1) // workers)
        else:
            try:
                client = Client(config.scheduler, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError) as error:
                raise ClusterError(f"no Dask scheduler answers at {config.scheduler} ({error}): start one with "
                                   "'dask scheduler' and give its address, or use --scheduler local") from None
            drjit_threads = None
        with client:
            try:
                client.wait_for_workers(1, timeout=CONNECT_TIMEOUT)
            except TimeoutError:
                raise ClusterError(f"the scheduler at {config.scheduler} has no workers after {CONNECT_TIMEOUT} s: "
                                   "start them with 'dask worker ADDRESS --nthreads 1'") from None
            require_same_mi_nest(client)
            dashboard = client.dashboard_link
            say(f"cluster: {len(client.nthreads())} worker(s) at {client.scheduler.address}"
                + (f"; dashboard {dashboard}" if dashboard else ""))
            yield Cluster(client, drjit_threads, dashboard)
    finally:
        if local is not None:
            local.close()


def cluster_for(cluster: ClusterConfig | Cluster | None, work: bool,
                say: Callable[[str], None] = print) -> AbstractContextManager[Cluster | None]:
    """What a run with ``cluster`` uses for the block: a config connected for it (:func:`connect`), a cluster
    connected already as it is (not closed at the end), or None where there is no ``work`` to give it (nothing
    started) or no cluster (this process)."""
    if not work or cluster is None:
        return nullcontext(None)
    return connect(cluster, say) if isinstance(cluster, ClusterConfig) else nullcontext(cluster)
