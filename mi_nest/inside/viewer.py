"""``mi-nest view``: an interactive viewer in the browser, built on viser (the viewer nerfstudio uses).

Dragging in the 3D view turns the camera about the part; mi_nest renders every frame on the server, through
the same render as ``mi-nest render`` (or ``mi-nest slice`` in slice mode), at a lower resolution while the
view moves and at full resolution once it rests. The frame fills the 3D view's background and also shows, at
full resolution, as an image in the control panel. Sliders set the slice plane and thickness, the polariscope,
a load scale and the wavelength.

Viser's callbacks only record what changed; one thread renders, so Mitsuba and Dr.Jit are driven from a
single thread.
"""
from __future__ import annotations

import threading
import time
import warnings
from dataclasses import dataclass, replace

import numpy as np

from ..physics.polariscope import POLARISCOPE_FIELDS, POLARISCOPE_KINDS, polariscope_setting
from ..scene import SceneError, specimen_bounds, specimen_media, specimen_shapes
from .slicing import AXES, Plane, SliceError, Slicer, SliceSpec
from .source import open_source
from .views import render_pose

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
# A view that has not moved for this long is rendered at full resolution.
SETTLE_SECONDS = 0.25
MODES = ("part", "slice")


@dataclass(frozen=True)
class ViewState:
    """Everything a frame depends on besides the camera."""
    mode: str = "part"
    axis: str = "z"
    offset: float = 0.0
    thickness: float = 1.0
    polariscope: str = "circular"
    field: str = "dark"
    angle: float = 0.0
    load_scale: float = 1.0
    wavelength: float | None = None

    def scope(self):
        return polariscope_setting(self.polariscope, self.field, self.angle)


@dataclass
class Frame:
    """A rendered frame: what it shows and how it was made."""
    image: np.ndarray           # (H, W) float32 intensity
    state: ViewState
    to_world: np.ndarray        # the camera (part mode)
    resolution: int
    seconds: float


class FrameRenderer:
    """Frames of a source at two resolutions: the full one, and a lower one while the view moves."""

    def __init__(self, source: str, defines: dict | None = None, resolution: int = 256, moving_resolution: int = 128):
        defines = dict(defines or {})
        self.resolution, self.moving_resolution = resolution, moving_resolution
        try:
            self.sources = {r: open_source(source, {**defines, "res": str(r)})
                            for r in sorted({resolution, moving_resolution})}
        except SceneError as error:
            raise SceneError(f"{error} (mi-nest view sets the scene's $res: give the scene a "
                             '<default name="res" value="256"/>)') from None
        full = self.sources[resolution]
        self.name = full.name
        low, high = specimen_bounds(specimen_shapes(full.scene))
        self.bounds = (low, high)
        self.reference = full.reference
        self.center = full.center
        self.wavelength = specimen_media(full.scene)[0].wavelength
        self.slicers = {r: Slicer(source.scene) for r, source in self.sources.items()}

    def pose_of_camera(self, wxyz: np.ndarray, look_at: np.ndarray, distance: float | None = None) -> np.ndarray:
        """The scene camera's ``to_world`` for a viewer camera of orientation ``wxyz`` (OpenCV axes: x right,
        y down, z forward) looking at ``look_at``; ``distance`` from it scales the orthographic view (zoom)."""
        w, x, y, z = np.asarray(wxyz, dtype=np.float64) / np.linalg.norm(wxyz)
        rotation = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                             [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                             [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        right, down, forward = rotation.T
        scale = np.linalg.norm(self.reference[:3, :3], axis=0)
        if distance is not None:
            scale = scale * distance / self.reference_distance()
        to_world = np.eye(4)
        # Mitsuba's cameras: x is image left, y up, z forward.
        to_world[:3, 0], to_world[:3, 1], to_world[:3, 2] = -right * scale[0], -down * scale[1], forward * scale[2]
        to_world[:3, 3] = np.asarray(look_at) - forward * self.reference_distance()
        return to_world

    def reference_distance(self) -> float:
        return float(np.linalg.norm(self.reference[:3, 3] - self.center))

    def reference_camera(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(position, look_at, up)`` of a viewer camera that sees what the scene's camera sees."""
        forward = self.reference[:3, 2] / np.linalg.norm(self.reference[:3, 2])
        up = self.reference[:3, 1] / np.linalg.norm(self.reference[:3, 1])
        return self.center - forward * self.reference_distance(), self.center, up

    def render(self, state: ViewState, to_world: np.ndarray, resolution: int) -> Frame:
        """The frame of ``state`` seen from ``to_world`` (part mode) at ``resolution``."""
        start = time.perf_counter()
        source = self.sources[resolution]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # aliasing at a preview's resolution is expected
            if state.mode == "slice":
                spec = SliceSpec(Plane(AXES[state.axis], state.offset), state.thickness, resolution=resolution,
                                 polariscope=state.scope(), load_scale=state.load_scale, wavelength=state.wavelength)
                image = self.slicers[resolution].render(spec, source.field).main
            else:
                image = render_pose(source, to_world, state.scope(), state.load_scale, state.wavelength, spp=1).main
        return Frame(np.asarray(image, dtype=np.float32), state, to_world, resolution, time.perf_counter() - start)



def to_rgb(image: np.ndarray) -> np.ndarray:
    """8-bit grey RGB of an intensity image (0 to 1)."""
    grey = np.round(255.0 * np.clip(image, 0.0, 1.0)).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=-1)


def padded_to_aspect(rgb: np.ndarray, aspect: float, fill: int) -> np.ndarray:
    """``rgb`` centred on a canvas of ``aspect`` (width / height), so that the 3D view does not stretch it."""
    height, width = rgb.shape[:2]
    if not np.isfinite(aspect) or aspect <= 0:
        return rgb
    target_width = max(width, int(round(height * aspect)))
    target_height = max(height, int(round(target_width / aspect)))
    canvas = np.full((target_height, target_width, 3), fill, dtype=np.uint8)
    top, left = (target_height - height) // 2, (target_width - width) // 2
    canvas[top:top + height, left:left + width] = rgb
    return canvas


class Viewer:
    """The viser server, its controls and the render thread (``start``, ``stop``)."""

    def __init__(self, frames: FrameRenderer, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT):
        self.frames = frames
        self.host, self.port = host, port
        low, high = frames.bounds
        self._state = ViewState(offset=round(float(0.5 * (low[2] + high[2])), 1),
                                thickness=max(round(float(max(high - low) / 20), 1), 0.1), wavelength=frames.wavelength)
        self._to_world = frames.reference
        self._aspect = 1.0
        self._version = 0
        self._changed_at = 0.0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None
        self.server = None
        self.last_frame: Frame | None = None        # the last full-resolution frame shown
        self.frames_drawn = 0
        self._shown_version = -1                    # the version of the last full-resolution frame shown

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.server.get_port() if self.server else self.port}"

    def start(self) -> None:
        import viser
        self.server = viser.ViserServer(host=self.host, port=self.port, label="mi_nest", verbose=False)
        self._controls(self.server)
        self.server.on_client_connect(self._on_connect)
        self._thread = threading.Thread(target=self._loop, name="mi_nest-view-render", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=30)
        if self.server is not None:
            self.server.stop()

    @property
    def settled(self) -> bool:
        """Whether the frame shown at full resolution is of the view as it stands (nothing left to render)."""
        with self._lock:
            return self._shown_version == self._version

    def _changed(self, **changes) -> None:
        with self._lock:
            self._state = replace(self._state, **changes)
            self._version += 1
            self._changed_at = time.monotonic()

    def _controls(self, server) -> None:
        gui = server.gui
        low, high = self.frames.bounds
        low, high = np.floor(10 * low) / 10, np.ceil(10 * high) / 10       # slider ends in tenths of a mm
        extent = float(max(high - low))
        state = self._state
        gui.add_markdown(f"**{self.frames.name}**: drag in the view to turn the part")
        mode = gui.add_dropdown("view", MODES, initial_value=state.mode)
        mode.on_update(lambda event: self._changed(mode=mode.value))
        with gui.add_folder("slice"):
            axis = gui.add_dropdown("normal", tuple(AXES), initial_value=state.axis)
            offset = gui.add_slider("offset (mm)", min=float(low.min()), max=float(high.max()), step=0.1,
                                    initial_value=round(state.offset, 1))
            thickness = gui.add_slider("thickness (mm)", min=0.1, max=extent, step=0.1,
                                       initial_value=max(round(state.thickness, 1), 0.1))

            def on_axis(event):
                index = "xyz".index(axis.value)
                centre = float(0.5 * (low[index] + high[index]))
                offset.value = centre         # its own callback records it
                self._changed(axis=axis.value, offset=centre)
            axis.on_update(on_axis)
            offset.on_update(lambda event: self._changed(offset=float(offset.value)))
            thickness.on_update(lambda event: self._changed(thickness=float(thickness.value)))
        with gui.add_folder("polariscope"):
            kind = gui.add_dropdown("kind", POLARISCOPE_KINDS, initial_value=state.polariscope)
            field = gui.add_dropdown("field", POLARISCOPE_FIELDS, initial_value=state.field)
            angle = gui.add_slider("analyser angle (deg)", min=-90.0, max=90.0, step=1.0, initial_value=state.angle)
            kind.on_update(lambda event: self._changed(polariscope=kind.value))
            field.on_update(lambda event: self._changed(field=field.value))
            angle.on_update(lambda event: self._changed(angle=float(angle.value)))
        with gui.add_folder("light and load"):
            load = gui.add_slider("load scale", min=0.0, max=3.0, step=0.01, initial_value=state.load_scale)
            wavelength = gui.add_slider("wavelength (nm)", min=380.0, max=780.0, step=1.0,
                                        initial_value=float(state.wavelength))
            load.on_update(lambda event: self._changed(load_scale=float(load.value)))
            wavelength.on_update(lambda event: self._changed(wavelength=float(wavelength.value)))
        reset = gui.add_button("reset view")
        reset.on_click(lambda event: self._reset_cameras())
        self._status = gui.add_markdown("rendering...")
        self._image = gui.add_image(np.zeros((8, 8, 3), dtype=np.uint8), label="frame", format="png")

    def _on_connect(self, client) -> None:
        self._place(client)

        def moved(camera):
            to_world = self.frames.pose_of_camera(camera.wxyz, camera.look_at,
                                                  float(np.linalg.norm(camera.position - camera.look_at)))
            with self._lock:
                self._to_world = to_world
                self._aspect = camera.aspect
                self._version += 1
                self._changed_at = time.monotonic()
        client.camera.on_update(moved)

    def _place(self, client) -> None:
        position, look_at, up = self.frames.reference_camera()
        with client.atomic():
            client.camera.up_direction = up
            client.camera.position = position
            client.camera.look_at = look_at

    def _reset_cameras(self) -> None:
        for client in self.server.get_clients().values():
            self._place(client)

    def _loop(self) -> None:
        drawn_version, drawn_full = -1, False
        while not self._stop.is_set():
            with self._lock:
                version, changed_at = self._version, self._changed_at
                state, to_world, aspect = self._state, self._to_world, self._aspect
            if version == drawn_version and drawn_full:
                self._stop.wait(0.01)
                continue
            moving = time.monotonic() - changed_at < SETTLE_SECONDS
            if moving and version == drawn_version:
                self._stop.wait(0.01)       # this preview is shown; the full frame waits for the view to rest
                continue
            resolution = self.frames.moving_resolution if moving else self.frames.resolution
            try:
                frame = self.frames.render(state, to_world, resolution)
            except KeyboardInterrupt:
                return      # Ctrl-C: the render between passes saw it; the main thread stops the viewer
            except (SliceError, ValueError) as error:
                self._status.content = f"**cannot show this:** {error}"
                drawn_version, drawn_full = version, True
                self._shown_version = version
                continue
            rgb = to_rgb(frame.image)
            background = 255 if state.field == "light" else 0
            self.server.scene.set_background_image(padded_to_aspect(rgb, aspect, background), format="png")
            self.frames_drawn += 1
            if not moving:
                self._image.image = rgb
                self.last_frame = frame
                self._shown_version = version
                self._status.content = (f"{frame.image.shape[1]}x{frame.image.shape[0]} in "
                                        f"{1000 * frame.seconds:.0f} ms")
            drawn_version, drawn_full = version, not moving


def run_viewer(source: str, defines: dict | None = None, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
               resolution: int = 256, moving_resolution: int = 128, open_browser: bool = True) -> None:
    """Serve the viewer until Ctrl-C, then stop it cleanly."""
    viewer = Viewer(FrameRenderer(source, defines, resolution, moving_resolution), host, port)
    viewer.start()
    print(f"mi-nest view: {viewer.url} (Ctrl-C to stop)", flush=True)
    if open_browser:
        import webbrowser
        webbrowser.open(viewer.url)
    try:
        while True:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    print("mi-nest view: stopped")
