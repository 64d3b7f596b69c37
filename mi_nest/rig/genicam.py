"""A real polarisation camera (LUCID Phoenix, Sony IMX250MZR or the colour IMX250MYR) through GenICam: an optional
extra.

``pip install 'mi_nest[genicam]'`` installs harvesters; the camera maker's
GenTL producer (a ``.cti`` file) must be installed separately. Each exposure is
one raw Mono12 frame behind the 2x2 micro-polariser cell (90 45 over 135 0);
it is normalised by the counts of free space between parallel polarisers
(``white_level``) and demosaicked into the four analyser images, exactly as
the dataset camera model does for simulated captures. A colour polarisation
camera (``bands`` in the rig file) sends one raw Bayer frame (``BayerRG12``
unless ``pixel_format`` says otherwise) with one colour filter over each 2x2
polariser cell; it is demosaicked into each band's four analyser images.

Written against harvesters' documented API (``Harvester``, ``create``,
``fetch``); nobody here has the camera, so this path is not exercised by the
tests beyond its import guard, its configuration and the demosaicking.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..dataset.camera import demosaic, filter_colours
from .clock import Clock
from .config import camera_bands
from .errors import CommunicationError, RigError

if TYPE_CHECKING:
    from .config import KnownSpecimen, RigConfig

INSTALL = ("the GenICam camera back-end needs harvesters (pip install 'mi_nest[genicam]') and the camera maker's "
           "GenTL producer (.cti)")


def harvester_class() -> type:
    try:
        from harvesters.core import Harvester
    except ImportError as error:
        raise RigError(INSTALL, device="camera") from error
    return Harvester


class GenICamBackend:
    """Exposures of a GenICam polarisation camera as ``{analyser: image}`` normalised intensities (``(bands, H, W)``
    images from a colour camera)."""

    def __init__(self, config: RigConfig) -> None:
        camera = config.camera
        self.config = config
        self.white_level = float(camera.white_level)
        self.harvester = harvester_class()()
        self.harvester.add_file(str(camera.cti))
        self.harvester.update()
        if not self.harvester.device_info_list:
            raise CommunicationError(f"no GenICam camera found through {camera.cti}", device="camera")
        self.acquirer = self.harvester.create({"serial_number": camera.serial} if camera.serial else 0)
        nodes = self.acquirer.remote_device.node_map
        nodes.PixelFormat.value = camera.raw_format
        bands = camera_bands(camera)
        self.colours = None if bands is None else filter_colours(bands)
        nodes.ExposureTime.value = camera.exposure * 1e6       # microseconds
        self.acquirer.start()

    def set_qwp1(self, reading: float) -> None:
        """The operator turns the real plate; nothing to do here."""

    def put_in_view(self, specimen: KnownSpecimen) -> None:
        """The operator places the real specimen; nothing to do here."""

    def capture(self, frame_number: int, clock: Clock) -> dict[int, np.ndarray]:
        width, height = self.config.camera.resolution
        with self.acquirer.fetch(timeout=max(5.0, 10 * self.config.camera.exposure)) as buffer:
            component = buffer.payload.components[0]
            raw = np.array(component.data, dtype=np.float64).reshape(component.height, component.width)
        if raw.shape != (height, width):
            raise RigError(f"the camera sends {raw.shape[1]}x{raw.shape[0]} frames, the rig file says "
                           f"{width}x{height}", device="camera")
        return demosaic(raw / self.white_level, self.colours)

    def close(self) -> None:
        self.acquirer.stop()
        self.acquirer.destroy()
        self.harvester.reset()
