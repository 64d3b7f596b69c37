"""The speed-vs-accuracy benchmark machinery (the chart itself is made by `mi-nest bench accuracy`)."""
import csv
import math

import numpy as np

from mi_nest import bench


def test_pareto_front_keeps_only_undominated_points():
    points = [(1.0, 0.5), (2.0, 0.1), (1.5, 0.6), (3.0, 0.1), (0.5, 0.9), (4.0, 0.01)]
    assert bench.pareto_front(points) == [4, 0, 1, 5]


def test_a_small_sweep_writes_csv_and_chart_with_converging_errors(tmp_path, monkeypatch):
    monkeypatch.setitem(bench.CASES, "tiny", bench.Case("twisted, tiny", "twisted_block", (5.0, 1.25)))
    rows = bench.run_accuracy(("tiny",), res=8, progress=False)
    assert len(rows) == 2 * len(bench.CURVES)
    by_method = {(r["method"], r["step_mm"]): r for r in rows}
    for method in ("product, midpoint", "magnus4"):
        assert by_method[(method, 1.25)]["error"] < by_method[(method, 5.0)]["error"] / 4
    assert all(r["megaray_steps"] > 0 and r["seconds"] > 0 for r in rows)
    csv_path, png_path = bench.write_results(rows, tmp_path)
    assert len(list(csv.DictReader(open(csv_path)))) == len(rows) and png_path.stat().st_size > 10_000
    assert bench._shown(math.nan) == bench.ERROR_CEILING and bench._blew_up(1e30)


def test_unknown_bench_case_is_named(capsys):
    from mi_nest.cli import main
    assert main(["bench", "accuracy", "--scenes", "disk,teapot", "-o", "unused"]) == 2
    assert "unknown bench case(s) ['teapot']" in capsys.readouterr().err


def test_a_method_that_blows_up_is_recorded_and_the_sweep_goes_on(monkeypatch):
    """rk4 near the disk's load points renders NaN pixels, which render() refuses: the sweep marks that point
    blown up (its time kept for the chart's cross) instead of ending with the refusal."""
    monkeypatch.setitem(bench.CASES, "singular", bench.Case("disk, load points", "disk_compression", (6.0, 0.375)))
    rows = bench.run_accuracy(("singular",), res=16, progress=False)
    by_point = {(r["method"], r["step_mm"]): r for r in rows}
    assert by_point[("rk4", 0.375)]["error"] == float("inf")
    assert all(np.isfinite(r["error"]) for r in rows if r["method"] != "rk4")
    assert all(r["seconds"] > 0 and r["megaray_steps"] > 0 for r in rows)
