"""The GenICam camera back-end: configuration, import guard, and the raw mosaic it demosaicks.

The camera itself is not here; what can run without it is tested."""
import importlib.util

import numpy as np
import pytest

from mi_nest.cli import main
from mi_nest.dataset.camera import CameraModel, demosaic, mosaic_mask
from mi_nest.physics.polariscope import ANALYZERS
from mi_nest.rig.config import RigConfigError, parse

GENICAM_RIG = {
    "devices": {"azimuth": "/dev/ttyUSB0", "elevation": "/dev/ttyUSB1", "qwp2": "/dev/ttyUSB2"},
    "camera": {"kind": "genicam", "cti": "/opt/lucid/ArenaTL.cti", "scene": "disk_compression",
               "resolution": [32, 32], "serial": "213900123", "white_level": 3900.0},
}


def _smooth_images(shape=(16, 20)):
    y, x = np.mgrid[0:shape[0], 0:shape[1]]
    return {a: 0.3 + 0.01 * x + 0.004 * y + 0.001 * a for a in ANALYZERS}


def test_a_raw_frame_is_split_by_the_imx250mzr_cell():
    images = _smooth_images()
    raw = sum(np.where(mosaic_mask(a, image.shape), image, 0.0) for a, image in images.items())
    assert raw[0, 0] == images[90][0, 0] and raw[0, 1] == images[45][0, 1]
    assert raw[1, 0] == images[135][1, 0] and raw[1, 1] == images[0][1, 1]
    split = demosaic(raw)
    for analyser, image in images.items():
        np.testing.assert_allclose(split[analyser][2:-2, 2:-2], image[2:-2, 2:-2], atol=1e-12)
    # The same demosaicking as the dataset camera model's simulated mosaic.
    simulated = CameraModel(mosaic=True).capture({f"a.{a}": image for a, image in images.items()}, 0)
    for analyser in images:
        np.testing.assert_allclose(simulated[f"a.{analyser}"], split[analyser], atol=1e-6)
    with pytest.raises(ValueError, match="even size"):
        demosaic(np.zeros((5, 4)))


def test_a_genicam_rig_file_is_read_and_checked():
    config = parse(GENICAM_RIG)
    assert config.camera.kind == "genicam" and config.camera.resolution == (32, 32)
    assert config.to_dict()["camera"]["serial"] == "213900123"
    with pytest.raises(RigConfigError, match="missing 'cti'"):
        parse({**GENICAM_RIG, "camera": {k: v for k, v in GENICAM_RIG["camera"].items() if k != "cti"}})
    with pytest.raises(RigConfigError, match="white_level"):
        parse({**GENICAM_RIG, "camera": {**GENICAM_RIG["camera"], "white_level": 0}})
    with pytest.raises(RigConfigError, match="'genicam'"):
        parse({**GENICAM_RIG, "camera": {**GENICAM_RIG["camera"], "kind": "aravis"}})


@pytest.mark.skipif(importlib.util.find_spec("harvesters") is not None, reason="harvesters is installed")
def test_without_harvesters_the_camera_says_how_to_get_it(tmp_path, capsys):
    path = tmp_path / "rig.toml"
    camera = GENICAM_RIG["camera"]
    path.write_text('[devices]\nazimuth = "/dev/null"\nelevation = "/dev/null"\nqwp2 = "/dev/null"\n'
                    f'[camera]\nkind = "genicam"\ncti = "{camera["cti"]}"\nscene = "disk_compression"\n')
    assert main(["acquire", str(path), "-o", str(tmp_path / "capture"), "--yes", "--quiet",
                 "--unverified-handedness"]) == 2
    assert "pip install 'mi_nest[genicam]'" in capsys.readouterr().err
