"""The viewer in a real browser: Debian's headless Chromium driven by Playwright loads the page, drags the view
and moves a slider; the frame the 3D view draws changes and equals a direct render of the same pose within 8-bit
rounding; each tab keeps its own controls.
"""
import contextlib
import http.client
import os
import shutil
import time

import imageio.v3 as iio
import numpy as np
import pytest

import mi_nest
from mi_nest.cli import main
from mi_nest.views.page_probe import PAGE_PROBE
from mi_nest.render import render_white_light, white_light
from mi_nest.views.viewer import FrameRenderer, Viewer, padded_to_aspect, to_rgb
from mi_nest.physics.polariscope import polariscope_setting
from mi_nest.scene import pose
from mi_nest.tracer import View

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
# What the machine's closed network needs (docs in the workplace's env notes): no background connections.
CHROMIUM_FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]
RESOLUTION, MOVING = 64, 32


def _browser_or_skip():
    playwright = pytest.importorskip("playwright.sync_api")
    if not os.path.exists(CHROMIUM):
        if os.environ.get("CI"):
            pytest.fail("CI has no chromium: scripts/test.sh runs scripts/setup.sh --browser, which installs it")
        pytest.skip("no chromium here (bash scripts/setup.sh --browser installs Debian's)")
    return playwright


@pytest.fixture(scope="module")
def viewer():
    frames = FrameRenderer("disk_compression", {"load": "400"}, RESOLUTION, MOVING)
    served = Viewer(frames, port=0)
    served.start()
    yield served
    served.stop()


def _direct(frame):
    """The frame's pose rendered straight through mi_nest.render, as 8-bit grey."""
    scene = mi_nest.load_scene("disk_compression", load=400, res=frame.resolution)
    pose(scene, frame.to_world)
    state = frame.state
    scale = state.load_scale * 532.0 / state.wavelength
    view = View(polariscope_setting(state.polariscope, state.field, state.angle), scale)
    image = mi_nest.render(scene, spp=1, seed=0, view=view).main
    return to_rgb(image)[..., 0].astype(int)


def _shown(page, colour=False):
    """The frame the page's 3D view drew last (its centre square of the frame's size, without the padding to the
    view's aspect), decoded to grey levels (``colour``: RGB); None before the first, or while the camera moves
    (JPEG previews)."""
    data = page.evaluate("window.__lastFrame && Array.from(window.__lastFrame)")
    if not data or bytes(data[:4]) != b"\x89PNG":
        return None
    image = iio.imread(bytes(data), extension=".png")[..., :3 if colour else 1].astype(int)
    image = image if colour else image[..., 0]
    top, left = (image.shape[0] - RESOLUTION) // 2, (image.shape[1] - RESOLUTION) // 2
    return image[top:top + RESOLUTION, left:left + RESOLUTION]


def _wait_until_shown(page, viewer, condition, seconds=90.0):
    """Once the viewer has rendered the view as it stands (``condition`` on its last frame), the page's frame image
    equals a direct render of that frame's pose and settings within 8-bit rounding: returns it and the frame.
    Polled, since the image reaches the page a moment after the server renders it (and later on a busy machine)."""
    deadline = time.monotonic() + seconds
    expected = None
    while time.monotonic() < deadline:
        frame = viewer.last_frame
        if frame is not None and viewer.settled and condition(frame):
            if expected is None or expected[0] is not frame:
                expected = (frame, _direct(frame))
            shown = _shown(page)
            if shown is not None and shown.shape == expected[1].shape and np.abs(shown - expected[1]).max() <= 1:
                return shown, frame
        time.sleep(0.1)
    raise AssertionError("the page did not show the direct render of the viewer's frame in time")


def _wait_for(condition, seconds=60.0):
    deadline = time.monotonic() + seconds
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("the viewer did not get there in time")
        time.sleep(0.05)


def _wait_for_new_frame(page, previous, seconds=60.0):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        shown = _shown(page)
        if shown is not None and shown.shape == (RESOLUTION, RESOLUTION) and (
                previous is None or np.any(shown != previous)):
            return shown
        time.sleep(0.1)
    raise AssertionError("the page did not show a new frame in time")


@contextlib.contextmanager
def _page(viewer):
    """A headless browser's tab on the viewer, once it has drawn its first frame."""
    sync_api = _browser_or_skip()
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS)
        try:
            page = browser.new_page(viewport={"width": 1100, "height": 800})
            page.add_init_script(PAGE_PROBE)
            page.goto(viewer.url)
            _wait_for_new_frame(page, None)
            yield page
        finally:
            browser.close()


def test_the_page_shows_the_render_and_follows_a_drag_and_a_slider(viewer):
    with _page(viewer) as page:
        first, _ = _wait_until_shown(page, viewer, lambda frame: True)
        assert first.max() > 100      # fringes, not a blank frame

        # Drag across the 3D view: the camera turns about the part.
        canvas = page.locator("canvas").first.bounding_box()
        x, y = canvas["x"] + 0.3 * canvas["width"], canvas["y"] + 0.5 * canvas["height"]
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x + 120, y + 40, steps=12)
        page.mouse.up()
        dragged, _ = _wait_until_shown(
            page, viewer, lambda frame: not np.allclose(frame.to_world, viewer.frames.reference, atol=1e-6))
        assert np.abs(dragged - first).mean() > 5

        # A slider: the load scale, stepped with the keyboard.
        slider = page.get_by_role("slider").nth(_slider_index(page, "load scale"))
        slider.focus()
        for _ in range(40):
            page.keyboard.press("ArrowRight")
        loaded, frame = _wait_until_shown(page, viewer, lambda frame: abs(frame.state.load_scale - 1.4) < 0.005)
        assert np.abs(loaded - dragged).mean() > 5


def test_a_tab_turned_to_white_light_shows_the_colour_render(viewer):
    """The 'white light (LED-B3)' box in the browser: the next frame at rest is the white-light render of its pose, in
    colour, as the page draws it (8-bit RGB within one level)."""
    with _page(viewer) as page:
        page.get_by_text("white light (LED-B3)").click()
        deadline = time.monotonic() + 90
        shown = expected = None
        while time.monotonic() < deadline:
            frame = viewer.last_frame
            if frame is not None and viewer.settled and frame.state.white_light:
                if expected is None or expected[0] is not frame:
                    scene = mi_nest.load_scene("disk_compression", load=400, res=frame.resolution)
                    pose(scene, frame.to_world)
                    colour = render_white_light(scene, white_light(), spp=1, polariscope=frame.state.scope())
                    expected = (frame, to_rgb(np.stack([colour.channels[c] for c in "RGB"], axis=-1)).astype(int))
                shown = _shown(page, colour=True)
                if shown is not None and shown.shape == expected[1].shape and np.abs(shown - expected[1]).max() <= 1:
                    break
            time.sleep(0.1)
        else:
            raise AssertionError("the page did not show the white-light render in time")
        assert np.abs(shown[..., 0] - shown[..., 2]).max() > 50        # colours, not grey


def _slider_index(page, label):
    """Which of the page's sliders is the one labelled ``label``."""
    labels = page.evaluate("""() => Array.from(document.querySelectorAll("[role=slider]")).map(s => {
        let node = s;
        for (let i = 0; i < 8 && node; i++, node = node.parentElement) {
            const text = node.innerText || "";
            if (/[a-z]/i.test(text) && text.length < 80) return text;     // the row with the slider's label
        }
        return "";
    })""")
    matches = [i for i, text in enumerate(labels) if label in text]
    assert matches, f"no slider labelled {label!r} among {labels}"
    return matches[0]


def test_the_viewer_serves_only_its_own_files_on_localhost(viewer):
    assert viewer.url.startswith("http://127.0.0.1:")
    host, port = viewer.url[len("http://"):].split(":")
    for path in ("/../../../../etc/passwd", "/%2e%2e/%2e%2e/etc/passwd", "/pyproject.toml"):
        connection = http.client.HTTPConnection(host, int(port), timeout=10)
        connection.request("GET", path)
        response = connection.getresponse()
        body = response.read()
        assert response.status == 404 and b"root:" not in body, path


def test_a_frame_padded_to_the_views_aspect_keeps_its_pixels():
    rgb = to_rgb(np.linspace(0, 1, 12).reshape(3, 4))
    wide = padded_to_aspect(rgb, 2.0, 0)
    assert wide.shape[:2] == (3, 6)
    np.testing.assert_array_equal(wide[:, 1:5], rgb)
    tall = padded_to_aspect(rgb, 0.5, 255)
    assert tall.shape[:2] == (8, 4) and (tall[0] == 255).all()


@pytest.mark.parametrize("arguments, message", [
    (["--res", "4"], "'--res' must be an integer >= 8"),
    (["--port", "-1"], "'--port' must be an integer >= 0"),
])
def test_bad_viewer_options_get_one_line(arguments, message, capsys):
    assert main(["view", "disk_compression", "--no-browser", *arguments]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error


def test_mi_nest_view_serves_until_ctrl_c_and_then_stops_cleanly():
    """Ctrl-C while the first frame (the kitten at 1024 x 1024) renders on the viewer's thread: the render's
    deferral of Ctrl-C must not hold back the main thread's (it slept on forever, once in CI)."""
    import re
    import signal
    import subprocess
    import sys
    import urllib.request
    process = subprocess.Popen([sys.executable, "-m", "mi_nest.cli", "view", "kitten", "--no-browser",
                                "--port", "0", "--res", "1024", "--moving-res", "512"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = None
        deadline = time.monotonic() + 120
        while url is None and time.monotonic() < deadline:
            line = process.stdout.readline()
            found = re.search(r"mi-nest view: (http://127\.0\.0\.1:\d+)", line)
            url = found.group(1) if found else None
        assert url, "the viewer did not say where it serves"
        assert urllib.request.urlopen(url, timeout=10).status == 200
        time.sleep(0.2)         # inside the first frame's render
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 0, err
    assert "mi-nest view: stopped" in out and "Traceback" not in err


def test_each_tab_keeps_its_own_controls_and_frames(viewer):
    sync_api = _browser_or_skip()
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS)
        try:
            pages = [browser.new_page(viewport={"width": 1100, "height": 800}) for _ in range(2)]
            for page in pages:
                page.add_init_script(PAGE_PROBE)
                page.goto(viewer.url)
                _wait_for_new_frame(page, None)
            first, second = pages
            # Each tab's first frame is drawn from the fitted camera before its browser reports the camera it
            # shows (a pose a float's rounding away, the view's aspect): the frame to keep is the one after.
            _wait_for(lambda: len(viewer._tabs) >= 2 and all(tab.version >= 1 for tab in viewer._tabs.values()))
            before = _wait_until_shown(second, viewer, lambda frame: True)[0]
            slider = first.get_by_role("slider").nth(_slider_index(first, "load scale"))
            track = slider.locator("xpath=ancestor::div[contains(@class, 'mantine-Slider-root')][1]").bounding_box()
            first.mouse.click(track["x"] + 0.9 * track["width"], track["y"] + 0.5 * track["height"])
            _wait_until_shown(first, viewer, lambda frame: frame.state.load_scale > 2.0)
            time.sleep(0.5)
            # The other tab's slider and frame are as they were.
            values = [page.locator("input").evaluate_all("(inputs) => inputs.map(i => i.value)") for page in pages]
            assert "1" in values[1] and "1" not in values[0]
            # Within 8-bit rounding, as against a direct render: the second tab's first frame and the one drawn
            # once it reports its camera (a float's rounding away) may both pass for ``before``; the first tab's
            # load would move its fringes by far more.
            assert np.abs(_shown(second) - before).max() <= 1
        finally:
            browser.close()


def test_a_tab_whose_controls_are_slow_to_build_still_gets_its_frame():
    """On a busy machine a tab's first frame could finish before its controls were built; the render thread then
    wrote its time into a status line that did not exist yet, died, and no tab got another frame (a CI failure).
    The controls are slowed here to make that order certain."""
    frames = FrameRenderer("disk_compression", {"load": "400"}, RESOLUTION, MOVING)
    served = Viewer(frames, port=0)
    build = served._controls

    def slow_controls(client, state):
        time.sleep(3.0)          # several frames' time at this size
        return build(client, state)
    served._controls = slow_controls
    served.start()
    try:
        with _page(served) as page:
            _wait_until_shown(page, served, lambda frame: True)
            assert served._thread.is_alive()
    finally:
        served.stop()


def test_the_first_view_fits_the_whole_part():
    """The kitten opened with its ears cut off: the fitted camera's frame holds every pixel of the part inside its
    border."""
    frames = FrameRenderer("kitten", {}, 64, 32)
    position, look_at, _ = frames.fitted_camera()
    camera = frames.pose_of_camera(_looking(look_at - position, frames.reference[:3, 1]), look_at,
                                   float(np.linalg.norm(position - look_at)))
    scene = frames.sources[64].scene
    pose(scene, camera)
    with pytest.warns(RuntimeWarning):      # 64 px: the kitten's fringes alias
        length = mi_nest.render(scene, spp=1).channels["path.length"]
    border = np.concatenate([length[0], length[-1], length[:, 0], length[:, -1]])
    assert (length > 0).mean() > 0.25 and not border.any()


def _looking(forward, up):
    """The viewer camera's orientation (wxyz; OpenCV axes: x right, y down, z forward) looking along ``forward``."""
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    matrix = np.stack([right, down, forward], axis=1)
    w = np.sqrt(max(1e-12, 1 + np.trace(matrix))) / 2
    return np.array([w, (matrix[2, 1] - matrix[1, 2]) / (4 * w), (matrix[0, 2] - matrix[2, 0]) / (4 * w),
                     (matrix[1, 0] - matrix[0, 1]) / (4 * w)])


def test_a_scene_with_a_white_panel_opens_in_its_light():
    """A scene whose light panel names a spectrum opens with the white-light box ticked, and its frames are the
    white-light render of that light."""
    from mi_nest.render import render_white_light
    from mi_nest.scene import pose as pose_scene
    frames = FrameRenderer("disk_compression", {"load": "300", "spectrum": "white_led"}, 16, 16)
    viewer = Viewer(frames, port=0)
    assert viewer.initial_state.white_light and frames.light.name == "LED-B3"
    frame = frames.render(viewer.initial_state, frames.reference, 16)
    scene = mi_nest.load_scene("disk_compression", load=300, res=16)
    pose_scene(scene, frame.to_world)
    expected = render_white_light(scene, frames.light, spp=1)
    np.testing.assert_allclose(frame.image[..., 0], expected.channels["R"], atol=1e-6)
    plain = FrameRenderer("disk_compression", {"load": "300"}, 16, 16)
    assert not Viewer(plain, port=0).initial_state.white_light
