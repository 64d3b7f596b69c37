"""Datasets rendered as tasks on Dask (issue 38): a LocalCluster of two worker processes renders the same channels
as one process; a killed worker loses no rotation and renders none twice; workers with other code are refused."""
import os
import signal

import numpy as np
import psutil
import pytest

from mi_nest.cli import main
from mi_nest.cluster import ClusterConfig, ClusterError, connect
from mi_nest.dataset import CameraModel, SimulationSettings, simulate
from mi_nest.io.exr import read_channels

TWO_WORKERS = ClusterConfig(workers=2)
# Noise seeded per rotation and several samples per pixel: what must come out the same wherever a rotation renders.
SETTINGS = SimulationSettings(azimuths=4, elevations=3, res=16, spp=2, camera=CameraModel(read_noise=0.01, seed=5))


def _rotation_files(directory):
    """The rotation files written whole: not the temporaries (``.NAME...``) a killed worker leaves mid-write."""
    return sorted(p for p in (directory / "rotations").glob("*.exr") if not p.name.startswith("."))


def _channels(directory):
    return {path.name: read_channels(path) for path in _rotation_files(directory)}


def _assert_same_channels(a, b):
    first, second = _channels(a), _channels(b)
    assert first.keys() == second.keys() and len(first) == SETTINGS.azimuths * SETTINGS.elevations
    for name, channels in first.items():
        assert channels.keys() == second[name].keys()
        for channel, values in channels.items():
            np.testing.assert_array_equal(values, second[name][channel], err_msg=f"{name}: {channel}")


@pytest.fixture(scope="module")
def one_process(tmp_path_factory):
    directory = tmp_path_factory.mktemp("one") / "disk"
    with pytest.warns(RuntimeWarning):
        simulate("disk_compression", directory, SETTINGS, progress=False)
    return directory


def test_a_sharded_dataset_equals_the_one_rendered_in_one_process(one_process, tmp_path, capsys):
    with pytest.warns(RuntimeWarning, match="denser than the pixel grid"):
        report = simulate("disk_compression", tmp_path / "disk", SETTINGS, progress=False, cluster=TWO_WORKERS)
    assert (report.rendered, report.kept) == (12, 0)
    _assert_same_channels(one_process, tmp_path / "disk")
    said = capsys.readouterr().out
    assert "cluster: 2 worker(s)" in said and "dashboard http" in said


def _assert_rerun_completes(one_process, directory, kept):
    """A rerun keeps the ``kept`` rotations written before, renders the rest, and equals the one-process dataset."""
    with pytest.warns(RuntimeWarning):
        report = simulate("disk_compression", directory, SETTINGS, progress=False, cluster=TWO_WORKERS)
    assert report.kept >= kept and report.rendered + report.kept == 12
    _assert_same_channels(one_process, directory)


def _worker_processes():
    return [p for p in psutil.Process().children(recursive=True)
            if "multiprocessing" in " ".join(p.cmdline()) and "resource_tracker" not in " ".join(p.cmdline())]


def _worker_killer():
    """``(killed, on_rotation)``: a callback that kills one of the two workers once, and the pids it killed."""
    killed = []

    def kill_a_worker(entry):
        if not killed and len(_worker_processes()) == 2:
            victim = _worker_processes()[0]
            os.kill(victim.pid, signal.SIGKILL)
            killed.append(victim.pid)
    return killed, kill_a_worker


def test_a_killed_worker_loses_no_rotation_and_renders_none_twice(one_process, tmp_path):
    killed, kill_a_worker = _worker_killer()
    with pytest.warns(RuntimeWarning):
        report = simulate("disk_compression", tmp_path / "disk", SETTINGS, progress=False, cluster=TWO_WORKERS,
                          on_rotation=kill_a_worker)
    assert killed
    # The scheduler gave the dead worker's tasks to the other, those whose results died with it too: each rotation
    # is reported once, and one already written is kept, not rendered again.
    assert report.rendered + report.kept == 12
    _assert_same_channels(one_process, tmp_path / "disk")
    written = {p.name: p.stat().st_mtime_ns for p in _rotation_files(tmp_path / "disk")}
    again = simulate("disk_compression", tmp_path / "disk", SETTINGS, progress=False, cluster=TWO_WORKERS)
    assert (again.rendered, again.kept) == (0, 12)
    assert {p.name: p.stat().st_mtime_ns for p in _rotation_files(tmp_path / "disk")} == written


def test_a_rotation_whose_workers_all_died_stops_the_run_in_one_line_and_keeps_what_was_written(one_process,
                                                                                                   tmp_path):
    import dask
    killed, kill_a_worker = _worker_killer()
    # No retries: the first worker to die while holding a rotation is every worker that rotation had.
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}), warnings_ignored(), \
            pytest.raises(ClusterError, match="was running on every worker that died") as error:
        simulate("disk_compression", tmp_path / "disk", SETTINGS, progress=False, cluster=TWO_WORKERS,
                 on_rotation=kill_a_worker)
    assert killed and "\n" not in str(error.value) and "run the same command again to resume" in str(error.value)
    kept = len(_rotation_files(tmp_path / "disk"))
    assert 1 <= kept < 12
    _assert_rerun_completes(one_process, tmp_path / "disk", kept)


def test_an_interrupted_sharded_run_keeps_what_it_wrote_and_resumes(one_process, tmp_path):
    def interrupt(entry):
        if len(_rotation_files(tmp_path / "disk")) >= 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt), warnings_ignored():
        simulate("disk_compression", tmp_path / "disk", SETTINGS, progress=False, cluster=TWO_WORKERS,
                 on_rotation=interrupt)
    kept = len(_rotation_files(tmp_path / "disk"))
    assert 3 <= kept < 12
    _assert_rerun_completes(one_process, tmp_path / "disk", kept)


def warnings_ignored():
    import warnings
    manager = warnings.catch_warnings()
    manager.__enter__()
    warnings.simplefilter("ignore")

    class Leave:
        def __enter__(self):
            return self

        def __exit__(self, *exc):
            manager.__exit__(*exc)
    return Leave()


@pytest.mark.parametrize("change, refusal", [
    ("import mi_nest.version as v; v.__version__ = '0.0.9'", r"runs mi_nest 0\.0\.9 .* this process 0\.1\.0"),
    ("import mi_nest.cluster as c; c.source_digest = lambda: 'elsewhere'", "with other source files"),
    ("import sys; sys.modules['mi_nest.cluster'] = None", "cannot import mi_nest"),
], ids=["version", "source", "missing"])
def test_workers_that_run_other_code_are_refused_before_any_task(change, refusal):
    from distributed import Client, LocalCluster
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        one = sorted(client.nthreads())[0]
        client.run(exec, change, {}, workers=[one])
        with pytest.raises(ClusterError, match=f"1 of 2 worker\\(s\\) cannot run this mi_nest: {one} .*{refusal}"):
            with connect(ClusterConfig(cluster.scheduler_address)):
                pass


def test_bad_cluster_options_get_one_line(tmp_path, capsys, monkeypatch):
    for bad, message in (({"workers": 0}, "workers"), ({"scheduler": "tcp://host:8786", "workers": 2}, "local cluster"),
                         ({"scheduler": " "}, "scheduler")):
        with pytest.raises(ValueError, match=message):
            ClusterConfig(**bad)
    assert main(["simulate", "disk_compression", "-o", str(tmp_path / "a"), "--workers", "2"]) == 2
    assert "add --scheduler local" in capsys.readouterr().err
    import mi_nest.cluster
    monkeypatch.setattr(mi_nest.cluster, "CONNECT_TIMEOUT", 2)
    assert main(["simulate", "disk_compression", "-o", str(tmp_path / "b"), "--azimuth", "2", "--elevation", "2",
                 "--res", "8", "--scheduler", "tcp://127.0.0.1:9"]) == 2
    error = capsys.readouterr().err
    assert error.startswith("mi-nest: error: no Dask scheduler answers at tcp://127.0.0.1:9") and error.count("\n") == 1


def test_a_scheduler_without_workers_is_refused(monkeypatch):
    import mi_nest.cluster
    from distributed import LocalCluster
    monkeypatch.setattr(mi_nest.cluster, "CONNECT_TIMEOUT", 1)
    with LocalCluster(n_workers=0, processes=True, dashboard_address=None) as empty:
        with pytest.raises(ClusterError, match=f"the scheduler at {empty.scheduler_address} has no workers after 1 s: "
                                               "start them with 'dask worker ADDRESS --nthreads 1'"):
            with connect(ClusterConfig(empty.scheduler_address)):
                pass


def test_cli_simulates_on_a_local_cluster(tmp_path, capsys):
    with pytest.warns(RuntimeWarning, match="denser than the pixel grid"):
        status = main(["simulate", "disk_compression", "-o", str(tmp_path / "disk"), "--azimuth", "2",
                       "--elevation", "2", "--res", "8", "--scheduler", "local", "--workers", "2"])
    assert status == 0
    said = capsys.readouterr().out
    assert "cluster: 2 worker(s)" in said and "4 rotations rendered" in said
    assert len(_rotation_files(tmp_path / "disk")) == 4
