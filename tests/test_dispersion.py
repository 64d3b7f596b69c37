"""The stress-optic coefficient's dispersion (issue 37): closed forms, a table, and views at other wavelengths."""
import numpy as np
import pytest

import mi_nest
from mi_nest.physics.dispersion import Cauchy, Constant, Table, parse_dispersion
from mi_nest.render import ViewError, phase_scale
from mi_nest.tracer import View
from scenes import box, medium, scene


def test_dispersions_read_from_text_and_give_their_closed_forms():
    assert parse_dispersion("constant") == Constant()
    cauchy = parse_dispersion("cauchy 2.5e6")
    assert cauchy == Cauchy(2.5e6)
    # C = A + B / lambda^2 with A fixed by C = 50 at 532 nm.
    a = 50.0 - 2.5e6 / 532.0 ** 2
    for wavelength in (450.0, 532.0, 650.0):
        assert cauchy.coefficient(wavelength, 532.0, 50.0) == pytest.approx(a + 2.5e6 / wavelength ** 2, rel=1e-14)
    table = parse_dispersion("table 450 56 532 50 650 46")
    assert table == Table((450.0, 532.0, 650.0), (56.0, 50.0, 46.0))
    assert table.coefficient(491.0) == pytest.approx(53.0) and table.coefficient(650.0) == 46.0
    with pytest.raises(ValueError, match="covers 450 to 650 nm; 700 nm is outside it"):
        table.coefficient(700.0)
    with pytest.raises(ValueError, match="C must stay positive"):
        Cauchy(-1e8).coefficient(400.0, 532.0, 50.0)
    for text, message in (("cauchy", "write 'constant', 'cauchy B'"), ("table 450 56 532", "write 'constant'"),
                          ("table 500 50 450 56", "increasing"), ("table 450 -1 532 50", "positive Brewster"),
                          ("cauchy x", "give numbers"), ("cauchy inf", "finite"), ("sellmeier 1", "write"),
                          ("  ", "dispersion is empty")):
        with pytest.raises(ValueError, match=message):
            parse_dispersion(text)


def _slab(**material):
    return scene([box((20, 20, 4), interior=medium(xx=0.2, **material))], res=2)


def _retardance(loaded, wavelength=None):
    view = View(None, phase_scale(loaded, 1.0, wavelength))
    return float(np.mean(mi_nest.render(loaded, view=view).channels["char.delta"]))


def test_a_view_at_another_wavelength_scales_the_phase_by_c_over_lambda():
    """A uniform slab's retardance at 650 nm: 532/650 of its own with a constant C, and C(650)/C(532) times that
    with a Cauchy dispersion; a table gives C at the medium's wavelength itself."""
    constant, dispersive = _slab(), _slab(dispersion="cauchy 2.5e6")
    own = _retardance(constant)
    assert _retardance(constant, 650.0) == pytest.approx(own * 532.0 / 650.0, rel=1e-6)
    c650 = 50.0 + 2.5e6 * (1 / 650.0 ** 2 - 1 / 532.0 ** 2)
    assert _retardance(dispersive, 650.0) == pytest.approx(own * 532.0 / 650.0 * c650 / 50.0, rel=1e-6)
    tabled = scene([box((20, 20, 4), interior={"type": "stress", "model": "uniform", "xx": 0.2,
                                                "dispersion": "table 450 56 532 50 650 46"})], res=2)
    assert _retardance(tabled) == pytest.approx(own, rel=1e-6)
    assert _retardance(tabled, 650.0) == pytest.approx(own * 532.0 / 650.0 * 46.0 / 50.0, rel=1e-6)
    with pytest.raises(ViewError, match="covers 450 to 650 nm; 700 nm is outside it"):
        phase_scale(tabled, 1.0, 700.0)


@pytest.mark.parametrize("material, message", [
    ({"dispersion": "table 450 56 650 46", "stress_optic_coefficient": 50.0}, "leave out 'stress_optic_coefficient'"),
    ({"dispersion": "table 600 56 650 46"}, "600 to 650 nm; 532 nm is outside it"),
    ({"dispersion": "sellmeier 2", "stress_optic_coefficient": 50.0}, "write 'constant', 'cauchy B'")])
def test_a_dispersion_that_cannot_hold_is_refused_with_the_scene(material, message):
    with pytest.raises(Exception, match=message):
        scene([box((2, 2, 2), interior={"type": "stress", "model": "uniform", "xx": 1.0, **material})])
