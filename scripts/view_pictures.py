"""Make the pictures of README's "Views into the field" and docs/views.md with the commands they show.

    .venv/bin/python scripts/view_pictures.py [DEMO_OUTPUT (default: mi_nest_out)]

Needs the demo's output (bash scripts/demo.sh) for the reconstruction's views, and Debian's chromium
(scripts/setup.sh --browser) for the viewer's screenshot. Writes docs/images/views/.
"""
from __future__ import annotations

import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
IMAGES = ROOT / "docs" / "images" / "views"
MI_NEST = [sys.executable, "-m", "mi_nest.cli"]


def run(arguments: str) -> None:
    print(f"$ mi-nest {arguments}", flush=True)
    subprocess.run(MI_NEST + shlex.split(arguments), check=True, cwd=IMAGES)


def viewer_screenshot(source: str, output: Path) -> None:
    """The viewer on ``source`` in headless chromium, after a drag, as a PNG."""
    import re

    from playwright.sync_api import sync_playwright

    from mi_nest.views.page_probe import PAGE_PROBE
    process = subprocess.Popen(MI_NEST + ["view", source, "--no-browser", "--port", "0"], stdout=subprocess.PIPE,
                               text=True, cwd=IMAGES)
    try:
        url = None
        while url is None:
            found = re.search(r"mi-nest view: (http://\S+)", process.stdout.readline())
            url = found.group(1) if found else None
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path="/usr/bin/chromium", args=[
                "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync"])
            page = browser.new_page(viewport={"width": 1200, "height": 760})
            page.add_init_script(PAGE_PROBE)
            page.goto(url)
            page.wait_for_function("window.__frames.length > 0", timeout=120_000)
            # Headless chromium renders WebGL in software, and viser says so in a notification: close it.
            for close in page.locator(".mantine-Notification-root button").all():
                close.click()
            box = page.locator("canvas").first.bounding_box()
            x, y = box["x"] + 0.35 * box["width"], box["y"] + 0.5 * box["height"]
            page.mouse.move(x, y)
            page.mouse.down()
            page.mouse.move(x + 90, y - 40, steps=10)
            page.mouse.up()
            time.sleep(3.0)
            page.screenshot(path=str(output))
            browser.close()
    finally:
        process.terminate()
        process.wait(timeout=60)


def main() -> None:
    demo = Path(sys.argv[1] if len(sys.argv) > 1 else ROOT / "mi_nest_out").resolve()
    result = demo / "reconstruction"
    if not (result / "reconstruction.json").is_file():
        raise SystemExit(f"no reconstruction in {result}: run bash scripts/demo.sh first")
    IMAGES.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as scratch:
        exr = Path(scratch)
        run(f"slice disk_compression --plane z=0 --thickness 1 -o {exr}/slice.exr --maps slice_disk.png")
        for name, box in (("lower", "-30,-30,-7,30,30,0"), ("upper", "-30,-30,0,30,30,7")):
            run(f"slice stacked_disks --plane z=0 --thickness 12 --region box:{box} -o {exr}/{name}.exr "
                f"--png stacked_{name}.png")
        run(f"slice stacked_disks --plane z=0 --thickness 12 -o {exr}/both.exr --png stacked_both.png")
        run(f"render {result} -D res=256 --azimuth 40 --elevation 25 -o {exr}/view.exr --png novel_reconstructed.png")
        run(f"render disk_compression -D load=60 -D contact_width=4 --azimuth 40 --elevation 25 -o {exr}/truth.exr "
            "--png novel_truth.png")
        run(f"turntable {result} -D res=128 --frames 24 --elevation 20 -o turntable.gif")
        run(f"compare {result} -o held_out.png --views 5")
        run(f"principal {result} --plane z=0 -o principal_reconstruction.png --res 96")
        run("principal lame_cylinder --plane z=0 -o principal_lame.png --res 96")
    viewer_screenshot("kitten", IMAGES / "viewer.png")
    print(f"wrote {IMAGES}")


if __name__ == "__main__":
    main()
