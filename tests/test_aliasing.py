"""Fringes denser than the pixel grid: the unwrapped order channel and the aliasing guard."""
import math
import warnings

import mi_nest
import numpy as np
import pytest

from mi_nest.physics.aliasing import (NYQUIST, UNRESOLVED_BANDS_SHARE, UNRESOLVED_BEAT_SHARE, UNRESOLVED_SHARE,
                                      beat_factor, fringe_aliasing, phase_lost, unresolved_dataset)
from scenes import BREWSTER, WAVELENGTH, box, medium, scene


def disk_mask(n):
    y, x = np.mgrid[:n, :n] - (n - 1) / 2
    return np.hypot(x, y) < 0.4 * n


@pytest.mark.parametrize("slope", [0.2, 0.49, 0.51, 3.0])
def test_density_is_the_order_step_between_neighbours(slope):
    inside = disk_mask(40)
    x = np.arange(40.0)
    report = fringe_aliasing(slope * (x[None, :] - x[:, None]), inside)
    assert report.densest == pytest.approx(slope, rel=1e-5)
    assert report.aliased == (report.pixels if slope > NYQUIST else 0)
    assert report.resolution_factor == max(1, math.ceil(slope / NYQUIST))


def test_percentile_is_numpys():
    inside = disk_mask(40)
    y, x = np.mgrid[:40, :40]
    report = fringe_aliasing(0.01 * x ** 2 + 0.003 * y ** 2, inside)
    assert report.percentile_99 == pytest.approx(np.quantile(report.densities, 0.99, method="lower"))
    assert report.densest == report.densities.max() and report.densities.size == report.pixels


def test_the_silhouette_is_not_a_fringe():
    inside = disk_mask(40)
    report = fringe_aliasing(np.where(inside, 12.0, 0.0), inside)
    assert report.pixels > 0 and report.densest == 0.0 and report.aliased == 0
    with pytest.raises(ValueError, match="one 2D shape"):
        fringe_aliasing(np.zeros((4, 4)), np.ones((4, 5), dtype=bool))


def test_a_scaled_report_is_the_report_on_the_scaled_order():
    inside = disk_mask(40)
    columns = np.mgrid[:40, :40][1].astype(np.float64)
    order = 0.1 * columns + 0.002 * columns ** 2       # 0.1 to 0.26 orders per pixel, growing across
    for factor in (2.5, 3.0, 4.0):      # some of the pixels alias at each, not all
        expected = fringe_aliasing(factor * order, inside)
        scaled = fringe_aliasing(order, inside).scaled(factor)
        assert (scaled.pixels, scaled.aliased) == (expected.pixels, expected.aliased)
        assert 0 < expected.aliased < expected.pixels
        assert scaled.densest == pytest.approx(expected.densest, rel=1e-5)      # the order is float32
        assert scaled.densities == pytest.approx(expected.densities, rel=1e-5)


def test_the_slowest_beat_is_the_closest_two_bands_difference():
    # Constant C: a band's phase goes as 1 / lambda; the guard reads the shortest wavelength's order.
    scales = [532.0 / w for w in (450.0, 532.0, 650.0)]
    # 532 and 650 nm are the closest in 1 / lambda (0.1815 against 0.1822 for 450 and 532).
    assert beat_factor(scales, scales[0]) == pytest.approx(450.0 * (1 / 532.0 - 1 / 650.0), rel=1e-12)
    assert beat_factor(scales[::-1], scales[0]) == beat_factor(scales, scales[0])
    assert beat_factor(scales[:1], scales[0]) is None


def test_bands_lose_the_phase_by_their_beat_and_one_band_by_its_own_share():
    assert phase_lost(UNRESOLVED_SHARE + 0.01) and not phase_lost(UNRESOLVED_SHARE - 0.01)
    assert not phase_lost(UNRESOLVED_BANDS_SHARE - 0.01, UNRESOLVED_BEAT_SHARE - 0.001)
    assert phase_lost(0.0, UNRESOLVED_BEAT_SHARE + 0.001) and phase_lost(UNRESOLVED_BANDS_SHARE + 0.01, 0.0)
    one_band = {"views": 10, "of": 10, "mean_fraction": 0.19, "max_fraction": 0.5, "densest": 5.5}
    assert "fringes are denser than the pixels in 19%" in unresolved_dataset(one_band, "DATA")
    resolved_beat = {**one_band, "beat": {"views": 1, "of": 10, "mean_fraction": 0.004, "max_fraction": 0.06,
                                          "densest": 0.85}}
    assert unresolved_dataset(resolved_beat, "DATA") is None
    aliased_beat = {**one_band, "beat": {**resolved_beat["beat"], "mean_fraction": UNRESOLVED_BEAT_SHARE + 0.01}}
    problem = unresolved_dataset(aliased_beat, "DATA")
    assert problem.startswith("DATA: even the slowest beat between its bands") and "\n" not in problem


def test_fringe_order_channel_is_unwrapped_where_the_retardance_folds():
    order, thickness = 7.3, 5.0
    difference = order * WAVELENGTH / (BREWSTER * thickness)
    shapes = [box((20, 20, thickness), interior=medium(xx=difference))]
    channels = mi_nest.render(scene(shapes, res=2, step=1.0)).channels
    assert channels["fringe.order"] == pytest.approx(np.full((2, 2), order), rel=1e-5)
    folded = np.minimum(channels["char.delta"], 2 * math.pi - channels["char.delta"])   # delta ~ 2 pi - delta
    assert folded == pytest.approx(np.full((2, 2), 2 * math.pi * (order - 7)), abs=1e-4)


def beam_scene(res, orders_per_pixel, view=20.0, spp=1):
    """A beam in pure bending seen through its width: the order grows linearly across it."""
    width, height = 10.0, 30.0
    pixel = 2 * view / res
    moment = orders_per_pixel / pixel * (width * height ** 3 / 12) * WAVELENGTH / (BREWSTER * width)
    beam = medium("beam_bending", width=width, height=height, moment=moment)
    return scene([box((120, height, width), interior=beam)], res=res, view=view, step=10.0, spp=spp)


def beam_render(res, orders_per_pixel, view=20.0):
    loaded = beam_scene(res, orders_per_pixel, view)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = mi_nest.render(loaded)
    return result.aliasing, [str(w.message) for w in caught], result


def test_guard_warns_exactly_when_fringes_pass_nyquist():
    aliased, messages, result = beam_render(32, 0.8)
    assert aliased.densest == pytest.approx(0.8, rel=0.02)
    assert aliased.fraction > 0.9
    assert any("denser than the pixel grid" in m and "2x the resolution" in m for m in messages)
    assert result.warnings == messages

    sampled, messages, result = beam_render(64, 0.4)
    assert sampled.densest == pytest.approx(0.4, rel=0.02)
    assert sampled.aliased == 0 and messages == [] and result.warnings == []


@pytest.mark.parametrize("spp", [1, 4])
def test_guard_measures_the_rendered_order(spp):
    # The render hands the guard its own copy of the two channels, read in the march's kernel.
    loaded = beam_scene(24, 0.3, spp=spp)
    result = mi_nest.render(loaded, passes=1)
    channels, report = result.channels, result.aliasing
    expected = fringe_aliasing(channels["fringe.order"], channels["path.length"] > 0)
    assert 0 < expected.pixels < 24 * 24
    assert (report.pixels, report.aliased) == (expected.pixels, expected.aliased)
    assert report.densest == pytest.approx(expected.densest, rel=1e-6)
    assert report.densities == pytest.approx(expected.densities, rel=1e-6, abs=1e-7)
