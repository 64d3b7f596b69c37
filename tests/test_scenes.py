"""Every shipped scene loads and renders fringes at 16x16 with its $res/$spp/$step defaults."""
import numpy as np
import pytest

import mi_nest
from mi_nest.tracer.film import CHANNELS

SHIPPED = sorted(p.stem for p in mi_nest.scene_path("disk_compression").parent.glob("*.xml"))
# Scenes that take more than a second or two to load or render at 16x16.
SLOW = {"kitten", "square_hole_disk"}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in SHIPPED])
def test_shipped_scene_renders_fringes_at_16x16(name):
    result = mi_nest.render(mi_nest.load_scene(name, res=16, spp=1))
    assert set(result.channels) == {"Y", *CHANNELS}
    assert result.main.shape == (16, 16)
    assert np.all(np.isfinite(result.main)) and result.main.std() > 0.02
    norm = sum(result.channels[f"jones.{c}"] ** 2 for c in "abcd")
    np.testing.assert_allclose(norm, 1.0, atol=1e-4)


def test_every_scene_takes_res_spp_and_step():
    for name in SHIPPED:
        text = mi_nest.scene_path(name).read_text()
        for parameter in ("res", "spp", "step"):
            assert f'<default name="{parameter}"' in text, f"{name}.xml lacks ${parameter}"
