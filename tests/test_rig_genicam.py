"""The GenICam camera back-end: configuration, import guard, and the raw mosaic it demosaicks.

The camera itself is not here; what can run without it is tested."""
import importlib.util

import numpy as np
import pytest

from mi_nest.cli import main
from mi_nest.dataset.camera import CameraModel, demosaic, mosaic_mask, raw_frame
from mi_nest.physics.bands import narrow_bands
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
    with pytest.raises(ValueError, match="multiples of 2"):
        demosaic(np.zeros((5, 4)))


def test_a_colour_raw_frame_is_split_by_polariser_cell_and_colour_filter():
    """The IMX250MYR: one colour filter over each 2x2 polariser cell, the cells in a Bayer pattern. A frame made
    of smooth images comes back exact inside (bilinear over every 4th pixel), as the camera model's mosaic does."""
    colours = ["blue", "green", "red"]
    images = {a: np.stack([image * (1 + 0.1 * k) for k in range(3)]) for a, image in _smooth_images((24, 32)).items()}
    raw = raw_frame(images, colours)
    assert raw[0, 0] == images[90][2, 0, 0] and raw[0, 2] == images[90][1, 0, 2] and raw[2, 2] == images[90][0, 2, 2]
    split = demosaic(raw, colours)
    for analyser, image in images.items():
        assert split[analyser].shape == (3, 24, 32)
        np.testing.assert_allclose(split[analyser][:, 4:-4, 4:-4], image[:, 4:-4, 4:-4], atol=1e-12)
    bands = narrow_bands([450.0, 532.0, 650.0])
    simulated = CameraModel(mosaic=True).capture({f"{band}.analyzer.{a}": image[k] for a, image in images.items()
                                                 for k, band in enumerate(bands.names)}, 0, bands)
    for analyser in images:
        for k, band in enumerate(bands.names):
            np.testing.assert_allclose(simulated[f"{band}.analyzer.{analyser}"], split[analyser][k], atol=1e-6)
    with pytest.raises(ValueError, match="multiples of 4"):
        demosaic(np.zeros((6, 8)), colours)


def test_a_colour_genicam_camera_reads_raw_bayer_frames():
    camera = {**GENICAM_RIG["camera"], "bands": "rgb"}
    assert parse({**GENICAM_RIG, "camera": camera}).camera.raw_format == "BayerRG12"
    assert parse(GENICAM_RIG).camera.raw_format == "Mono12"
    assert parse({**GENICAM_RIG, "camera": {**camera, "pixel_format": "BayerRG16"}}).camera.raw_format == "BayerRG16"
    with pytest.raises(RigConfigError, match="red, green and blue filters"):
        parse({**GENICAM_RIG, "camera": {**camera, "bands": "532"}})


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
