"""The digital twin's camera and the polariscope calibration fitted from its free-space captures."""
import warnings

import numpy as np
import pytest

import mi_nest
from mi_nest.dataset import CameraModel
from mi_nest.physics import su2
from mi_nest.physics.polariscope import (INPUT_QWP_SETTINGS, OUTPUT_QWP_SETTINGS, measurement_name,
                                         quarter_wave_plate, waveplate)
from mi_nest.rig.calibration import PARAMETERS, Exposure, background_mask, expected_exposures, fit
from mi_nest.rig.twin import Optics, SimulatedCamera, free_space, scene_renderer

TRUE_OPTICS = Optics(analyzer_offset=1.3, qwp1_offset=-0.8, qwp2_offset=2.1, qwp1_retardance=87.0,
                     qwp2_retardance=93.5)


def _sweep(jones_of, optics, camera=CameraModel(), resolution=(16, 16)):
    state = {"qwp2": 0.0}
    twin = SimulatedCamera(jones_of, lambda: (0.0, 0.0, state["qwp2"]), optics, camera, resolution)
    exposures = []
    for qwp1, qwp2 in expected_exposures():
        twin.qwp1, state["qwp2"] = qwp1, qwp2
        exposures.append(Exposure(qwp1, qwp2, twin.capture()))
    return exposures


def test_waveplates_of_any_retardance():
    np.testing.assert_allclose(waveplate(30.0, 90.0), quarter_wave_plate(30.0))
    np.testing.assert_allclose(waveplate(30.0, 180.0), quarter_wave_plate(30.0) @ quarter_wave_plate(30.0),
                               atol=1e-15)
    np.testing.assert_allclose(waveplate(17.0, 0.0), np.eye(2), atol=1e-15)


def test_noiseless_free_space_gives_the_optics_back_exactly():
    calibration = fit(_sweep(free_space, TRUE_OPTICS))
    for name in PARAMETERS:
        assert getattr(calibration.optics, name) == pytest.approx(getattr(TRUE_OPTICS, name), abs=1e-4)
    assert calibration.light_level == pytest.approx(1.0, abs=1e-6) and calibration.residual_rms < 1e-5


def test_offsets_within_a_fifth_of_a_degree_under_noise_and_the_mosaic():
    camera = CameraModel(read_noise=0.01, bits=12, mosaic=True, seed=5)
    calibration = fit(_sweep(free_space, TRUE_OPTICS, camera, resolution=(32, 32)))
    for name in PARAMETERS:
        error = abs(getattr(calibration.optics, name) - getattr(TRUE_OPTICS, name))
        assert error < 0.2, name
        assert error < 6 * calibration.standard_errors[name] + 0.01, name    # the reported uncertainty is honest
    assert "qwp2_offset = 2.1" in calibration.describe()


def test_a_birefringent_object_in_view_is_masked_out():
    size = 32
    patch = np.zeros((size, size), dtype=bool)
    patch[8:20, 10:26] = True
    retarder = su2.retarder(np.where(patch, 1.7, 0.0), np.full((size, size), 0.4))

    def with_object(azimuth, elevation):
        return [tuple(np.asarray(x, dtype=np.float64) for x in retarder)], 1

    exposures = _sweep(with_object, TRUE_OPTICS, resolution=(size, size))
    mask = background_mask(exposures)
    assert not mask[patch].any() and mask[~patch].all()
    calibration = fit(exposures)
    assert calibration.background_fraction == pytest.approx(1 - patch.mean())
    assert abs(calibration.optics.qwp2_offset - TRUE_OPTICS.qwp2_offset) < 1e-3


def test_measured_angles_a_few_counts_off_still_find_the_background():
    exposures = _sweep(free_space, TRUE_OPTICS)
    for exposure in exposures:
        exposure.qwp2 += 0.004            # an ELL14 reading, not the nominal angle
    assert background_mask(exposures).all()


def test_calibration_refuses_an_incomplete_sweep():
    exposures = [e for e in _sweep(free_space, Optics()) if e.qwp1 == 45.0]
    with pytest.raises(ValueError, match="both QWP1 settings"):
        fit(exposures)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_the_twin_sees_what_the_renderer_renders():
    """Ideal optics at the nominal settings: the twin's exposures are the dataset's channels."""
    jones_of = scene_renderer("disk_compression", {"load": 150, "contact_width": 4}, (24, 24), supersample=1)
    state = {"qwp2": 0.0}
    twin = SimulatedCamera(jones_of, lambda: (20.0, 10.0, state["qwp2"]), Optics(), resolution=(24, 24))
    from mi_nest.dataset.schedule import Rotation, camera_to_world
    from mi_nest.scene import pose, reference_pose
    scene = mi_nest.load_scene("disk_compression", res=24, spp=1, load=150, contact_width=4)
    pose(scene, camera_to_world(reference_pose(scene), Rotation(0, 20.0, 10.0, "train"), [0.0, 0.0, 0.0]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        channels = mi_nest.render(scene).channels
    assert channels["path.length"].max() > 0
    for qwp1 in INPUT_QWP_SETTINGS:
        for qwp2 in OUTPUT_QWP_SETTINGS:
            twin.qwp1, state["qwp2"] = qwp1, qwp2
            for analyzer, image in twin.capture().items():
                np.testing.assert_allclose(image, channels[measurement_name(qwp1, qwp2, analyzer)], atol=2e-5)
    # Imperfect optics change what it sees.
    twin.optics = TRUE_OPTICS
    assert np.abs(twin.capture()[0] - channels["pol.90.45.0"]).max() > 0.01
