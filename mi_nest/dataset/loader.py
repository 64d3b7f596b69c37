"""``mi_nest.Dataset``: lazy access to a multi-axis polariscope dataset on disk.

Views are decoded from their EXR on first use and kept in an LRU cache of
bounded size (by default half the memory free when the dataset is opened, and
at least 1 GiB: a dataset that fits is decoded once, the shipped scene's 1024
views at 256 x 256 included), so a dataset larger than memory streams.
Training draws random rays across rotations; evaluation reads whole views.
"""
from __future__ import annotations

import warnings
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import replace
from functools import cached_property
from pathlib import Path

import numpy as np

from ..physics import MEASUREMENTS
from ..physics.polariscope import Polariscope, Polarizer, Waveplate
from . import format as fmt



# The least memory the decoded views may hold by default; they may take half of what is free.
MIN_CACHE_BYTES = 1 << 30
# Relative distance below full scale that still reads as full scale: half-float rotation files round
# values within 2^-11 of 1 to 1.
FULL_SCALE_ROUNDING = 1e-3


def default_cache_bytes() -> int:
    """Half the memory free now, and at least :data:`MIN_CACHE_BYTES`."""
    import psutil
    return max(MIN_CACHE_BYTES, psutil.virtual_memory().available // 2)


class _DecodedView:
    """One rotation's images, its measurements stacked as ``(H, W, C)`` and its mask pixels."""

    def __init__(self, images, channels):
        self.measured = np.stack([images[n] for n in channels], axis=-1)
        self.measured.flags.writeable = False   # shared by every caller
        self.measured_pixels = self.measured.reshape(-1, len(channels))     # a view: (H * W, C)
        # The measurements' images are slices of their stack, not a second copy: a view held twice its size.
        self.images = {**images, **{n: self.measured[..., i] for i, n in enumerate(channels)}}
        self.mask_pixels = {}
        # Bytes held: the stacked measurements, the other images (masks) and the pixel indices of the masks
        # asked for so far.
        self.nbytes = self.measured.nbytes + sum(a.nbytes for n, a in images.items() if n not in channels)

    def pixels_inside(self, mask: str | None) -> np.ndarray:
        """Flat indices of the pixels where ``mask`` is set (None: all)."""
        if mask not in self.mask_pixels:
            self.mask_pixels[mask] = (np.arange(self.measured.shape[0] * self.measured.shape[1]) if mask is None
                                      else np.flatnonzero(self.images[mask] > 0.5))
            self.nbytes += self.mask_pixels[mask].nbytes
        return self.mask_pixels[mask]


class Dataset:
    """A multi-axis polariscope dataset on disk (``dataset.json`` and one EXR per rotation), simulated by
    ``mi-nest simulate`` or captured by ``mi-nest acquire``: docs/datasets.md.

    Views are read when first asked for and kept in a cache of at most ``cache_bytes`` (default: half the
    memory free now, at least 1 GiB). ``rotations`` lists each rotation's record (angles, camera ``to_world``,
    ``split``: ``train`` or ``test``); ``index`` is the whole ``dataset.json`` (its ``source`` names the scene
    and defines a simulation was rendered from); ``resolution`` is ``(width, height)``; ``channels`` the 16
    measurements' names (of each band, for a dataset of several: ``bands``). A dataset that an interrupted run
    left incomplete is refused unless ``allow_incomplete``.

    >>> dataset = mi_nest.Dataset("data/disk")
    >>> images = dataset.view(0)                    # {channel: (H, W) image} of the first rotation
    >>> dataset.split("test")                       # positions of the held-out rotations
    """

    def __init__(self, directory: str | Path, allow_incomplete: bool = False, cache_bytes: int | None = None):
        self.directory = Path(directory)
        self.index = fmt.read_index(self.directory)
        if not self.index["complete"] and not allow_incomplete:
            raise fmt.DatasetError(f"{self.directory}: incomplete dataset (an interrupted run?); rerun the "
                                   "simulation or acquisition to finish it, or pass allow_incomplete=True")
        self.rotations = [r for r in self.index["rotations"] if (self.directory / r["file"]).is_file()]
        missing = [r["file"] for r in self.index["rotations"] if r not in self.rotations]
        if missing and self.index["complete"] and not allow_incomplete:
            raise fmt.DatasetError(f"{self.directory}: {len(missing)} rotation EXR file(s) missing: {missing[:5]}")
        self.resolution = tuple(self.index["resolution"])        # (width, height)
        self.channels = tuple(self.index["channels"])
        self.bands = fmt.dataset_bands(self.index)        # None: one wavelength
        self._cache = OrderedDict()
        self._splits = {}
        self._cache_bytes = default_cache_bytes() if cache_bytes is None else int(cache_bytes)

    @property
    def cache_bytes(self) -> int:
        """The most bytes of decoded views kept in memory."""
        return self._cache_bytes

    @cached_property
    def fingerprint(self) -> str:
        """The dataset as it stood when first asked: its index and each rotation file's size and modification
        time (what a checkpoint records of the data it was fitted to)."""
        return fmt.content_fingerprint(self.directory, self.index)

    def __len__(self):
        """The number of rotations whose files are present."""
        return len(self.rotations)

    def __repr__(self):
        return (f"Dataset({str(self.directory)!r}: {len(self)} rotations, {self.resolution[0]}x{self.resolution[1]}, "
                f"{len(self.split('train'))} train / {len(self.split('test'))} test)")

    def split(self, name: str) -> list[int]:
        """Positions (into ``rotations``) of the ``train`` or ``test`` rotations."""
        return self._split_positions(name).tolist()

    def _split_positions(self, name: str) -> np.ndarray:
        if name not in ("train", "test"):
            raise ValueError(f"split must be 'train' or 'test', got '{name}'")
        if name not in self._splits:
            self._splits[name] = np.array([i for i, r in enumerate(self.rotations) if r["split"] == name], dtype=int)
        return self._splits[name]

    def polariscopes(self) -> tuple[Polariscope, ...]:
        """The polariscope each channel was measured with, in ``channels`` order.

        Nominal unless the capture was calibrated: acquisition then turns both
        waveplates to their nominal angles minus the fitted offsets, so what
        remains is the analyser's offset (the camera's micro-polarisers cannot
        be turned) and the two retardances.
        """
        calibration = self.index.get("calibration")
        scopes = [MEASUREMENTS[fmt.measurement_of(name)] for name in self.channels]
        if not calibration:
            return tuple(scopes)
        return tuple(_calibrated(scope, calibration["analyzer_offset"], calibration["qwp1_retardance"],
                                 calibration["qwp2_retardance"]) for scope in scopes)

    def channel_bands(self) -> tuple[int, ...] | None:
        """Per channel, in ``channels`` order, the index of its band in ``bands`` (None: one wavelength)."""
        if self.bands is None:
            return None
        return tuple(self.bands.names.index(fmt.band_of(name)) for name in self.channels)

    def to_world(self, position: int) -> np.ndarray:
        """The 4x4 camera-to-world matrix of rotation ``position`` (the camera turned about the specimen)."""
        return np.array(self.rotations[position]["to_world"])

    def view(self, position: int, channels: Sequence[str] | None = None) -> dict[str, np.ndarray]:
        """``{name: (H, W) float32}`` of rotation ``position``: measurements and masks."""
        names = list(self.channels) if channels is None else list(channels)
        self._require_channels(names)
        images = self._decoded(position).images
        return {n: images[n] for n in names}

    def _require_channels(self, names):
        unknown = [n for n in names if n not in self.channels and n not in self.index.get("mask_channels", ())]
        if unknown:
            raise ValueError(f"unknown channel(s) {unknown}; the dataset has {list(self.channels)} and masks "
                             f"{self.index.get('mask_channels', [])}")

    def _decoded(self, position):
        if position in self._cache:
            self._cache.move_to_end(position)
            return self._cache[position]
        entry = self.rotations[position]
        decoded = fmt.read_rotation(self.directory, entry, self.index)
        height_width = (self.resolution[1], self.resolution[0])
        shapes = {a.shape for a in decoded.values()}
        if shapes != {height_width}:
            raise fmt.DatasetError(f"{entry['file']}: images are {sorted(shapes)}, the dataset says "
                                   f"{self.resolution[0]}x{self.resolution[1]}")
        missing = [n for n in self.channels if n not in decoded]
        if missing:
            raise fmt.DatasetError(f"{entry['file']}: missing channel(s) {missing}")
        view = _DecodedView(decoded, self.channels)
        fmt.check_measurements(view.measured, self.channels, self.directory / entry["file"])
        self._cache[position] = view
        self._keep_within_budget()
        return view

    def _pixels_inside(self, position, mask):
        view = self._decoded(position)
        known = mask in view.mask_pixels
        pixels = view.pixels_inside(mask)
        if not known:
            self._keep_within_budget()
        return view, pixels

    def _keep_within_budget(self):
        # Each view knows its own size (it grows when a mask's pixels are first asked for): summing a few
        # integers per call, where summing every array of every view made reading a dataset quadratic in its views.
        cached_bytes = sum(v.nbytes for v in self._cache.values())
        while cached_bytes > self._cache_bytes and len(self._cache) > 1:
            cached_bytes -= self._cache.popitem(last=False)[1].nbytes

    def check_measurements(self, mask: str | None = "mask.dolp") -> None:
        """Decode every view, so that NaN, inf or all-zero measurements raise :class:`DatasetError` now,
        and warn once about views whose specimen (``mask``) is saturated."""
        level = fmt.full_scale(self.index)
        saturated = []
        for position in range(len(self)):
            view, pixels = self._pixels_inside(position, mask if mask in self._decoded(position).images else None)
            values = view.measured.reshape(-1, len(self.channels))[pixels]
            if level is not None and values.size and \
                    np.mean(values >= level * (1 - FULL_SCALE_ROUNDING)) > fmt.SATURATED_SHARE:
                saturated.append(self.rotations[position]["index"])
        if saturated:
            warnings.warn(f"{self.directory}: in {len(saturated)} of {len(self)} views (rotations "
                          f"{', '.join(map(str, saturated[:8]))}{', ...' if len(saturated) > 8 else ''}) more than "
                          f"{100 * fmt.SATURATED_SHARE:g}% of the specimen's measurements sit at the camera's full "
                          f"scale ({level:.4g}): clipped intensities bias the fit there; capture with less exposure "
                          "or light (or a higher white_level)", RuntimeWarning, stacklevel=2)

    def measurements(self, position: int) -> np.ndarray:
        """``(H, W, 16)`` in the order of ``channels`` (the cached array: do not modify it)."""
        return self._decoded(position).measured

    def ray_batch(self, size: int, rng: np.random.Generator, split: str = "train", views_per_batch: int = 8,
                  mask: str | None = "mask.dolp") -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Random pixels across rotations: ``(positions, rows, columns, targets (N, 16))``.

        Each batch draws from ``views_per_batch`` random rotations, so a batch
        decodes few files however large the dataset; pixels come from ``mask``
        (None: anywhere).
        """
        pool = self._split_positions(split)
        if not pool.size:
            raise ValueError(f"the dataset has no '{split}' rotations")
        chosen = rng.choice(pool, size=min(views_per_batch, len(pool)), replace=False)
        per_view = np.diff(np.linspace(0, size, len(chosen) + 1).round().astype(int))
        if mask is not None:
            self._require_channels([mask])
        views = [(position, count, *self._pixels_inside(position, mask)) for position, count in zip(chosen, per_view)]
        views = [view for view in views if view[3].size]
        if not views:
            raise ValueError(f"no pixel inside '{mask}' in the chosen rotations")
        positions, counts, decoded, candidates = zip(*views)
        # One draw for the whole batch: the same numbers as one rng.choice(candidates, count) per view in turn.
        draws = rng.integers(0, np.repeat([c.size for c in candidates], counts))
        ends = np.cumsum(counts)
        picked = [c[draws[end - count:end]] for c, count, end in zip(candidates, counts, ends)]
        targets = np.concatenate([view.measured_pixels[p] for view, p in zip(decoded, picked)])
        rows, columns = np.divmod(np.concatenate(picked), self.resolution[0])
        return np.repeat(positions, counts), rows, columns, targets


def _calibrated(scope: Polariscope, analyzer_offset: float, input_retardance: float,
                output_retardance: float) -> Polariscope:
    """The rig's ``scope`` as calibrated: its analyser (the camera's polariser) turned by ``analyzer_offset``, its
    waveplates' retardances the fitted ones (the light's QWP1, the camera's QWP2)."""
    light = tuple(replace(e, retardance=input_retardance) if isinstance(e, Waveplate) else e for e in scope.light)
    camera = tuple(replace(e, retardance=output_retardance) if isinstance(e, Waveplate)
                   else replace(e, angle=e.angle + analyzer_offset) if isinstance(e, Polarizer) else e
                   for e in scope.camera)
    return Polariscope(light, camera)
