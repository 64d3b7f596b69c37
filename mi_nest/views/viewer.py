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

import errno
import functools
import socket
import threading
import time
import warnings
from dataclasses import dataclass, replace

import numpy as np

from ..physics.polariscope import POLARISCOPE_FIELDS, POLARISCOPE_KINDS, polariscope_setting
from ..render import COLOUR_CHANNELS, scene_light, white_light
from ..scene import SceneError, specimen_bounds, specimen_media, specimen_shapes
from .slicing import AXES, Plane, SliceError, Slicer, SliceSpec
from .source import open_source
from .novel import render_pose

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
    white_light: bool = False        # white light (the scene panel's, or the LED) instead of the wavelength

    def scope(self):
        return polariscope_setting(self.polariscope, self.field, self.angle)


@dataclass
class Frame:
    """A rendered frame: what it shows and how it was made."""
    image: np.ndarray           # (H, W) float32 intensity, or (H, W, 3) sRGB in white light
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
        # What the white-light box shows: the scene panel's own spectrum, else the white LED (its box then starts
        # ticked where the scene's panel is white).
        self.scene_light = scene_light(full.scene)
        self.light = self.scene_light or white_light()
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

    def fitted_camera(self, margin: float = 1.1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(position, look_at, up)`` of a viewer camera looking as the scene's camera does, zoomed so that the
        whole part fits in the frame with ``margin``."""
        position, look_at, up = self.reference_camera()
        right = self.reference[:3, 0] / np.linalg.norm(self.reference[:3, 0])
        low, high = self.bounds
        corners = np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1])
                            for z in (low[2], high[2])]) - self.center
        half_width, half_height = np.abs(corners @ right).max(), np.abs(corners @ up).max()
        scale = np.linalg.norm(self.reference[:3, :3], axis=0)
        zoom = margin * max(half_width / scale[0], half_height / scale[1])
        return look_at + (position - look_at) * zoom, look_at, up

    def render(self, state: ViewState, to_world: np.ndarray, resolution: int) -> Frame:
        """The frame of ``state`` seen from ``to_world`` (part mode) at ``resolution``."""
        start = time.perf_counter()
        source = self.sources[resolution]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # aliasing at a preview's resolution is expected
            light = self.light if state.white_light else None
            wavelength = None if state.white_light else state.wavelength
            if state.mode == "slice":
                spec = SliceSpec(Plane(AXES[state.axis], state.offset), state.thickness, resolution=resolution,
                                 polariscope=state.scope(), load_scale=state.load_scale, wavelength=wavelength)
                slicer = self.slicers[resolution]
                result = slicer.render(spec, source.field) if light is None else \
                    slicer.render_white_light(spec, source.field, light)
            else:
                result = render_pose(source, to_world, state.scope(), state.load_scale, wavelength, spp=1,
                                     light=light)
            image = result.main if light is None else np.stack([result.channels[c] for c in COLOUR_CHANNELS], -1)
        return Frame(np.asarray(image, dtype=np.float32), state, to_world, resolution, time.perf_counter() - start)



def to_rgb(image: np.ndarray) -> np.ndarray:
    """8-bit RGB of an intensity image (0 to 1: grey) or of a white-light frame's display-encoded sRGB."""
    levels = np.round(255.0 * np.clip(image, 0.0, 1.0)).astype(np.uint8)
    return levels if levels.ndim == 3 else np.repeat(levels[..., None], 3, axis=-1)


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


# The ports TCP has; viser's thread dies on another and leaves the command waiting for it.
PORTS = range(65536)


def require_address(host: str, port: int) -> None:
    """Refuse a host and port viser cannot serve on: its server thread would die (a port outside TCP's) or give
    up (a host that is not this machine's), and ``ViserServer()`` would wait for it forever."""
    if port not in PORTS:
        raise ValueError(f"port {port} is outside TCP's ports, {PORTS.start} to {PORTS.stop - 1} (0: any free one)")
    try:
        family, kind, protocol, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        with socket.socket(family, kind, protocol) as probe:
            probe.bind(address)
    except OSError as error:
        # viser goes on to the next port from one that is taken or privileged.
        if error.errno not in (errno.EADDRINUSE, errno.EACCES):
            raise ValueError(f"cannot serve on {host}:{port} ({error.strerror or error}): give --host an address "
                             f"of this machine ({DEFAULT_HOST}, the default, serves this machine only)") from None


@dataclass
class TabView:
    """One browser tab's view: its own controls' state, its camera and what of them has been drawn."""
    state: ViewState
    to_world: np.ndarray
    aspect: float = 1.0
    version: int = 0                 # bumped by every change
    changed_at: float = 0.0
    camera_moving: bool = False      # the last change was the camera's: previews until it rests
    drawn_version: int = -1
    drawn_full: bool = False
    status: object = None            # the tab's status line

    @property
    def settled(self) -> bool:
        return self.drawn_version == self.version and self.drawn_full


class Viewer:
    """The viser server, each tab's controls and the render thread (``start``, ``stop``).

    Every browser tab has its own controls, camera and frames (viser's per-client GUI and scene). One thread
    renders for all of them, always the latest state of a tab, so quick inputs coalesce: a slider step renders
    at full resolution straight away; a camera drag renders previews at the lower resolution (sent as JPEG,
    cheaper to encode) until the camera rests, then the full frame (PNG).
    """

    def __init__(self, frames: FrameRenderer, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT):
        self.frames = frames
        self.host, self.port = host, port
        low, high = frames.bounds
        self.initial_state = ViewState(offset=round(float(0.5 * (low[2] + high[2])), 1),
                                       thickness=max(round(float(max(high - low) / 20), 1), 0.1),
                                       wavelength=frames.wavelength, white_light=frames.scene_light is not None)
        self._tabs: dict[int, TabView] = {}
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread = None
        self.server = None
        self.last_frame: Frame | None = None        # the last full-resolution frame drawn, in any tab
        self.frames_drawn = 0

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.server.get_port() if self.server else self.port}"

    def start(self) -> None:
        require_address(self.host, self.port)
        import viser
        self.server = viser.ViserServer(host=self.host, port=self.port, label="mi_nest", verbose=False)
        self.server.gui.main_panel.dock_right()       # the panel beside the view, not over the part
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(self._on_disconnect)
        self._thread = threading.Thread(target=self._loop, name="mi_nest-view-render", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=30)
        if self.server is not None:
            self.server.stop()

    @property
    def settled(self) -> bool:
        """Whether every tab shows its view as it stands at full resolution (nothing left to render)."""
        with self._lock:
            return all(tab.settled for tab in self._tabs.values())

    def _changed(self, client_id: int, camera: bool = False, **changes) -> None:
        with self._lock:
            tab = self._tabs.get(client_id)
            if tab is None:
                return
            tab.state = replace(tab.state, **changes)
            tab.version += 1
            tab.changed_at = time.monotonic()
            tab.camera_moving = camera
        self._wake.set()

    def _on_connect(self, client) -> None:
        tab = TabView(self.initial_state, self.frames.reference)
        tab.status = self._controls(client, tab.state)
        self._place(client)

        def moved(camera):
            distance = float(np.linalg.norm(camera.position - camera.look_at))
            to_world = self.frames.pose_of_camera(camera.wxyz, camera.look_at, distance)
            with self._lock:
                # The browser also reports a camera that has not moved (a resize, a redraw): no new frame for it.
                if np.allclose(to_world, tab.to_world, rtol=0, atol=1e-9) and camera.aspect == tab.aspect:
                    return
                tab.to_world, tab.aspect = to_world, camera.aspect
                tab.version += 1
                tab.changed_at = time.monotonic()
                tab.camera_moving = True
            self._wake.set()
        client.camera.on_update(moved)
        # Only a tab with its status line may be drawn: the render thread writes the frame's time into it.
        with self._lock:
            self._tabs[client.client_id] = tab
        self._wake.set()

    def _on_disconnect(self, client) -> None:
        with self._lock:
            self._tabs.pop(client.client_id, None)

    def _controls(self, client, state: ViewState):
        """The tab's controls; returns its status line."""
        gui = client.gui
        changed = functools.partial(self._changed, client.client_id)
        low, high = (np.asarray(bound, dtype=np.float64) for bound in self.frames.bounds)
        low, high = np.floor(10 * low) / 10, np.ceil(10 * high) / 10       # slider ends in tenths of a mm
        extent = float(round(max(high - low), 1))
        gui.add_markdown(f"**{self.frames.name}**: drag in the view to turn the part, scroll to zoom")
        mode = gui.add_dropdown("view", MODES, initial_value=state.mode)
        mode.on_update(lambda event: changed(mode=mode.value))
        with gui.add_folder("slice"):
            axis = gui.add_dropdown("normal", tuple(AXES), initial_value=state.axis)
            offset = gui.add_slider("offset (mm)", min=round(float(low.min()), 1), max=round(float(high.max()), 1),
                                    step=0.1, initial_value=round(state.offset, 1))
            thickness = gui.add_slider("thickness (mm)", min=0.1, max=extent, step=0.1,
                                       initial_value=max(round(state.thickness, 1), 0.1))

            def on_axis(event):
                index = "xyz".index(axis.value)
                centre = round(float(0.5 * (low[index] + high[index])), 1)
                offset.value = centre         # its own callback records it
                changed(axis=axis.value, offset=centre)
            axis.on_update(on_axis)
            offset.on_update(lambda event: changed(offset=float(offset.value)))
            thickness.on_update(lambda event: changed(thickness=float(thickness.value)))
        with gui.add_folder("polariscope"):
            kind = gui.add_dropdown("kind", POLARISCOPE_KINDS, initial_value=state.polariscope)
            field = gui.add_dropdown("field", POLARISCOPE_FIELDS, initial_value=state.field)
            angle = gui.add_slider("analyser angle (deg)", min=-90.0, max=90.0, step=1.0, initial_value=state.angle)
            kind.on_update(lambda event: changed(polariscope=kind.value))
            field.on_update(lambda event: changed(field=field.value))
            angle.on_update(lambda event: changed(angle=float(angle.value)))
        with gui.add_folder("light and load"):
            load = gui.add_slider("load scale", min=0.0, max=3.0, step=0.01, initial_value=state.load_scale)
            wavelength = gui.add_slider("wavelength (nm)", min=380.0, max=780.0, step=1.0,
                                        initial_value=float(round(state.wavelength)))
            load.on_update(lambda event: changed(load_scale=float(load.value)))
            white = gui.add_checkbox(f"white light ({self.frames.light.name})", initial_value=state.white_light)
            wavelength.disabled = state.white_light
            wavelength.on_update(lambda event: changed(wavelength=float(wavelength.value)))

            def on_white(event):
                wavelength.disabled = white.value     # white light holds every wavelength
                changed(white_light=bool(white.value))
            white.on_update(on_white)
        reset = gui.add_button("reset view")
        reset.on_click(lambda event: self._place(client))
        return gui.add_markdown("rendering...")

    def _place(self, client) -> None:
        position, look_at, up = self.frames.fitted_camera()
        with client.atomic():
            client.camera.up_direction = up
            client.camera.position = position
            client.camera.look_at = look_at

    def _next(self):
        """The tab to draw next and what to draw: ``(client id, tab, version, state, pose, aspect, moving)``;
        None when every tab is drawn or waits for its camera to rest."""
        now = time.monotonic()
        with self._lock:
            for client_id, tab in self._tabs.items():
                if tab.settled:
                    continue
                moving = tab.camera_moving and now - tab.changed_at < SETTLE_SECONDS
                if moving and tab.drawn_version == tab.version:
                    continue            # this preview is shown; the full frame waits for the camera to rest
                return client_id, tab, tab.version, tab.state, tab.to_world, tab.aspect, moving
        return None

    def _loop(self) -> None:
        while not self._stop.is_set():
            work = self._next()
            if work is None:
                self._wake.wait(0.02)
                self._wake.clear()
                continue
            client_id, tab, version, state, to_world, aspect, moving = work
            client = self.server.get_clients().get(client_id)
            if client is None:          # the tab closed since
                with self._lock:
                    self._tabs.pop(client_id, None)
                continue
            resolution = self.frames.moving_resolution if moving else self.frames.resolution
            try:
                frame = self.frames.render(state, to_world, resolution)
            except KeyboardInterrupt:
                return      # Ctrl-C: the render between passes saw it; the main thread stops the viewer
            except (SliceError, ValueError) as error:
                tab.status.content = f"**cannot show this:** {error}"
                with self._lock:
                    tab.drawn_version, tab.drawn_full = version, True
                continue
            background = 255 if state.field == "light" else 0
            canvas = padded_to_aspect(to_rgb(frame.image), aspect, background)
            # Previews as JPEG (1 ms to encode against 15 ms for PNG); the frame at rest exact, as PNG.
            client.scene.set_background_image(canvas, format="jpeg" if moving else "png", jpeg_quality=95)
            self.frames_drawn += 1
            if not moving:
                self.last_frame = frame
                tab.status.content = (f"{frame.image.shape[1]}x{frame.image.shape[0]} in "
                                      f"{1000 * frame.seconds:.0f} ms")
            with self._lock:
                tab.drawn_version, tab.drawn_full = version, not moving


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
