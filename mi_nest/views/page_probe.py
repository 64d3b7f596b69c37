"""What a person sees of ``mi-nest view``, measured in the browser: a script added to the viewer's page before it
loads (Playwright's ``add_init_script``) that stamps every input event and every frame the 3D view draws with
the page's own clock (ms since navigation), and keeps the bytes of the last frame.

The viewer's frames are the 3D view's background image: viser decodes each into a detached ``<img>`` and draws
it on the next animation frame; the panel's own images are attached to the page and are not counted.
``window.__frames`` holds ``[received, decoded, drawn, height]`` per frame (height: the image's, in pixels, which
tells a preview from a frame at rest), ``window.__inputs`` ``[kind, time]``, and
``window.__lastFrame`` the last frame's encoded bytes (PNG at rest, JPEG while the camera moves).
"""

PAGE_PROBE = """
(() => {
  window.__inputs = []; window.__frames = []; window.__lastFrame = null;
  for (const kind of ["keydown", "pointerdown", "pointermove", "pointerup"]) {
    window.addEventListener(kind, () => window.__inputs.push([kind, performance.now()]), true);
  }
  const source = Object.getOwnPropertyDescriptor(HTMLImageElement.prototype, "src");
  Object.defineProperty(HTMLImageElement.prototype, "src", {
    set(value) {
      if (String(value).startsWith("blob:") && !this.isConnected) {
        const received = performance.now();
        fetch(value).then((r) => r.arrayBuffer()).then((bytes) => { window.__lastFrame = new Uint8Array(bytes); });
        this.addEventListener("load", () => {
          const decoded = performance.now();
          const height = this.naturalHeight;
          requestAnimationFrame(() => requestAnimationFrame(
            (drawn) => window.__frames.push([received, decoded, drawn, height])));
        }, {once: true});
      }
      source.set.call(this, value);
    },
    get() { return source.get.call(this); },
  });
})();
"""
