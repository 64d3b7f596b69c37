"""Fringes denser than the pixel grid: the unwrapped order channel and the aliasing guard."""
import math
import warnings

import mi_nest
import numpy as np
import pytest

from mi_nest.physics.aliasing import NYQUIST, fringe_aliasing
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
