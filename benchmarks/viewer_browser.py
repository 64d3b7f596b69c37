"""``mi-nest view`` as a person sees it: times measured in a real browser (Debian's headless Chromium through
Playwright), from an input event to the changed image on the page.

The page is instrumented before it loads (``mi_nest/views/page_probe.py``): every input event (key, pointer)
and every frame the 3D view draws are stamped with the page's own clock. Measured:

- page load: from navigation to the first frame drawn;
- slider step: a click on the load-scale slider's track, a few pixels right of the last (a new value), to the
  first frame drawn after it, and to the first at full resolution (medians of ``--steps``, each from a settled
  view);
- drag: a pointer drag across the view for ``--drag-seconds``; distinct frames drawn per second while the pointer
  is down, and the longest gap between them;
- quick keys: 30 arrow presses on the focused slider as fast as Playwright types, to the last frame they cause
  (viser's client also turns the camera with arrow keys, even on a focused slider: the view turns a little).

The targets (issue 33, on 2 cores): slider step median under 250 ms; at least 5 frames per second during a drag
at 256 px. With ``--baseline DIR`` (another checkout, e.g. a git worktree) each scene is measured with both
versions' viewers, one after the other, through this checkout's probe and browser.

    python benchmarks/viewer_browser.py [--scene disk_compression] [--res 256] [--steps 15] [--baseline DIR]
"""
from __future__ import annotations

import argparse
import runpy
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from reconstruction import cpu_name, installed_layout, run

HERE = Path(__file__).resolve().parents[1]
# This checkout's probe, for a baseline's viewer too (read from the file: a baseline's mi_nest may have none).
PAGE_PROBE = runpy.run_path(str(HERE / "mi_nest" / "views" / "page_probe.py"))["PAGE_PROBE"]
WORKER = f"""
import json, runpy, sys
sys.path.insert(1, {str(Path(__file__).resolve().parent)!r})
import mi_nest
options = json.loads(sys.argv[1])
results = runpy.run_path({str(Path(__file__).resolve())!r})["measure"](**options)
print(json.dumps({{"results": results, "mi_nest": mi_nest.__file__}}))
"""

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]

def wait_settled(viewer, seconds: float = 60.0) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if viewer.settled:
            time.sleep(0.3)          # the last frame's way to the page
            return
        time.sleep(0.02)
    raise SystemExit("the viewer did not settle")


def frames_after(page, start: float, full: int | None = None) -> list[float]:
    """When the frames drawn after ``start`` were drawn (with ``full``, only those at least that tall)."""
    return sorted(drawn for _, _, drawn, height in page.evaluate("window.__frames")
                  if drawn > start and (full is None or height >= full))


def last_input(page, kind: str) -> float:
    return max(t for k, t in page.evaluate("window.__inputs") if k == kind)


def slider(page, label: str):
    index = page.evaluate("""(label) => Array.from(document.querySelectorAll("[role=slider]")).findIndex(s => {
        let node = s;
        for (let i = 0; i < 8 && node; i++, node = node.parentElement) {
            const text = node.innerText || "";
            if (/[a-z]/i.test(text) && text.length < 80) return text.includes(label);
        }
        return false;
    })""", label)
    if index < 0:
        raise SystemExit(f"no slider labelled {label!r}")
    return page.get_by_role("slider").nth(index)


def measure(scene: str, resolution: int, moving: int, steps: int, drag_seconds: float) -> dict:
    """The figures of one viewer (the ``mi_nest`` this process imports) on ``scene``."""
    from playwright.sync_api import sync_playwright

    from mi_nest.views.viewer import FrameRenderer, Viewer
    viewer = Viewer(FrameRenderer(scene, {}, resolution, moving), port=0)
    viewer.start()
    results = {}
    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS)
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.add_init_script(PAGE_PROBE)
            page.goto(viewer.url)
            deadline = time.monotonic() + 120
            while not page.evaluate("window.__frames.length") and time.monotonic() < deadline:
                time.sleep(0.05)
            results["page load to first frame (s)"] = frames_after(page, 0.0)[0] / 1000
            wait_settled(viewer)

            load = slider(page, "load scale")
            track = load.locator("xpath=ancestor::div[contains(@class, 'mantine-Slider-root')][1]").bounding_box()
            latencies, full_latencies = [], []
            for step in range(steps):
                wait_settled(viewer)
                page.mouse.click(track["x"] + track["width"] * (0.4 + 0.03 * (step + 1)),
                                 track["y"] + 0.5 * track["height"])
                pressed = last_input(page, "pointerdown")
                deadline = time.monotonic() + 30
                while not frames_after(page, pressed, resolution) and time.monotonic() < deadline:
                    time.sleep(0.005)
                latencies.append(frames_after(page, pressed)[0] - pressed)
                full_latencies.append(frames_after(page, pressed, resolution)[0] - pressed)
            results["slider step to frame, median (ms)"] = statistics.median(latencies)
            results["slider step to full frame, median (ms)"] = statistics.median(full_latencies)
            results["slider step to frame, fastest (ms)"] = min(latencies)
            results["slider step to frame, slowest (ms)"] = max(latencies)

            wait_settled(viewer)
            canvas = page.locator("canvas").first.bounding_box()
            x, y = canvas["x"] + 0.3 * canvas["width"], canvas["y"] + 0.5 * canvas["height"]
            page.mouse.move(x, y)
            page.mouse.down()
            down = last_input(page, "pointerdown")
            moves = max(int(drag_seconds / 0.02), 2)
            for index in range(moves):
                page.mouse.move(x + 300 * (index + 1) / moves, y + 60 * (index + 1) / moves)
                time.sleep(0.02)
            page.mouse.up()
            up = last_input(page, "pointerup")
            during = [t for t in frames_after(page, down) if t <= up]
            gaps = [b - a for a, b in zip([down, *during], [*during, up])]
            results["drag frames per second"] = len(during) / ((up - down) / 1000)
            results["drag, longest wait for a frame (ms)"] = max(gaps)

            wait_settled(viewer)
            load.focus()
            for _ in range(30):
                page.keyboard.press("ArrowRight")
            pressed = last_input(page, "keydown")
            wait_settled(viewer)
            last = frames_after(page, pressed, resolution)[-1]
            results["30 quick keys, last key to last frame (ms)"] = last - pressed
            browser.close()
    finally:
        viewer.stop()
    return results


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", action="append", help="scene (repeatable; default: disk_compression and kitten)")
    parser.add_argument("--res", type=int, default=256, help="the viewer's resolution at rest (default: 256)")
    parser.add_argument("--moving-res", type=int, default=128, help="while the view moves (default: 128)")
    parser.add_argument("--steps", type=int, default=15, help="slider steps timed (default: 15)")
    parser.add_argument("--drag-seconds", type=float, default=3.0, help="length of the drag (default: 3)")
    parser.add_argument("--baseline", type=Path, help="another mi_nest checkout to measure beside this one")
    args = parser.parse_args()
    print(f"CPU: {cpu_name()}; Chromium {CHROMIUM}, headless, software rendering")
    with tempfile.TemporaryDirectory() as tmp:
        versions = {"this checkout": installed_layout(HERE, Path(tmp) / "current")}
        if args.baseline:
            versions["baseline"] = installed_layout(args.baseline.resolve(), Path(tmp) / "baseline")
        for scene in args.scene or ["disk_compression", "kitten"]:
            options = {"scene": scene, "resolution": args.res, "moving": args.moving_res, "steps": args.steps,
                       "drag_seconds": args.drag_seconds}
            measured = {name: run(entry, options, WORKER)["results"] for name, entry in reversed(versions.items())}
            print(f"{scene}: " + "  |  ".join(versions))
            for name in measured["this checkout"]:
                values = "  |  ".join(f"{measured[version][name]:10.3g}" for version in versions)
                print(f"  {name:44s} {values}", flush=True)


if __name__ == "__main__":
    main()
