"""Real-time preview of a solved radiosity scene (`tessera preview SCENE`).

Radiosity's solution is view-independent: solved once, any view of it costs one primary
ray per pixel (its tile pass). The registry names the integrator whose product is such a
solution (`view_independent_product`: tessera_base.integrators.preview_integrator). The preview solves the scene once,
then re-renders it for every camera the user asks for, in a browser page served on
localhost (drag to orbit, wheel to zoom), or, with `--frames N`, along an orbit without a
server, printing the frame rate (the benchmark of docs/benchmarks/radiosity.md).
"""
from __future__ import annotations

import http.server
import json
import math
import time
import urllib.parse

import numpy as np

from tessera_renderer import Scene, _core

from tessera_base.images import tonemap_srgb8
from tessera_base.integrators import preview_integrator


def _rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' rotation of v about the unit axis."""
    c, s = math.cos(angle), math.sin(angle)
    return v * c + np.cross(axis, v) * s + axis * np.dot(axis, v) * (1 - c)


class RadiosityPreview:
    """A scene solved once; frame() renders it from an orbit around the view's pivot."""

    def __init__(self, scene: Scene, *, width: int = 256, height: int = 256, threads: int = 2,
                 integrator_params: dict[str, float] | None = None, seed: int = 0):
        self.scene, self.width, self.height, self.threads = scene, width, height, threads
        self.params = dict(integrator_params or {})
        self.integrator = preview_integrator()
        started = time.perf_counter()
        self.product = scene.scene_pass(self.integrator, 0, seed=seed, threads=threads,
                                        integrator_params=self.params)
        self.solve_seconds = time.perf_counter() - started
        c = scene.data.camera
        self.origin = np.asarray(c.origin, float)
        self.right, self.up = np.asarray(c.right, float), np.asarray(c.up, float)
        self.forward = np.asarray(c.forward, float)
        # The scene's own window: shifted, or orthographic (zoom then scales the window).
        self.tan_w, self.tan_h, self.shift_x, self.shift_y = c.window(width, height)
        self.orthographic = c.orthographic
        # Orbit about the point of the view axis nearest the scene's centre.
        p = np.asarray(scene.data.positions, float).reshape(-1, 3)
        centre = (p.min(axis=0) + p.max(axis=0)) / 2 if len(p) else self.origin + self.forward
        self.distance = max(float(np.dot(centre - self.origin, self.forward)), 1e-3)
        self.pivot = self.origin + self.forward * self.distance

    def camera(self, yaw: float = 0.0, pitch: float = 0.0, zoom: float = 1.0) -> "_core.Camera":
        """The view turned by yaw about the camera's up axis and pitch about its right axis
        (radians) around the pivot, at `zoom` times the distance."""
        up0 = self.up / np.linalg.norm(self.up)
        fwd = _rotate(self.forward, up0, yaw)
        right = _rotate(self.right, up0, yaw)
        fwd = _rotate(fwd, right / np.linalg.norm(right), pitch)
        up = _rotate(self.up, right / np.linalg.norm(right), pitch)
        origin = self.pivot - fwd * self.distance * zoom
        scale = zoom if self.orthographic else 1.0
        return _core.Camera(tuple(origin), tuple(right), tuple(up), tuple(fwd), self.tan_w * scale,
                            self.tan_h * scale, self.width, self.height, shift_x=self.shift_x * scale,
                            shift_y=self.shift_y * scale, orthographic=self.orthographic)

    def frame(self, yaw: float = 0.0, pitch: float = 0.0, zoom: float = 1.0) -> np.ndarray:
        """Linear RGBA (height, width, 4) of the solution from that view, 1 sample per pixel."""
        return self.scene.render_tile(0, 0, self.width, self.height, width=self.width, height=self.height,
                                      spp=1, threads=self.threads, integrator=self.integrator,
                                      integrator_params=self.params, scene_product=self.product,
                                      camera=self.camera(yaw, pitch, zoom))

    def benchmark(self, frames: int) -> dict:
        """Frames along a full orbit, timed: frames per second of frame() alone."""
        self.frame()  # warm-up: the first tile builds the element lookup's caches
        started = time.perf_counter()
        for i in range(frames):
            self.frame(yaw=2 * math.pi * i / frames, pitch=0.2 * math.sin(2 * math.pi * i / frames))
        seconds = time.perf_counter() - started
        return {"frames": frames, "seconds": seconds, "fps": frames / seconds,
                "solve_seconds": self.solve_seconds, "product_bytes": len(self.product)}


_PAGE = """<!doctype html><html><head><title>tessera preview</title></head>
<body style="background:#222;color:#ccc;font-family:sans-serif">
<canvas id="c" width="%(w)d" height="%(h)d" style="width:%(w2)dpx;height:%(h2)dpx;image-rendering:pixelated"></canvas>
<p>drag: orbit, wheel: zoom. <span id="fps"></span></p>
<script>
const c = document.getElementById('c'), g = c.getContext('2d');
let yaw = 0, pitch = 0, zoom = 1, busy = false, dirty = true, last = null;
async function draw() {
  if (busy || !dirty) return; busy = true; dirty = false;
  const t = performance.now(), view = `yaw=${yaw}&pitch=${pitch}&zoom=${zoom}`;
  const r = await fetch(`/frame?${view}`);
  const px = new Uint8ClampedArray(await r.arrayBuffer());
  g.putImageData(new ImageData(px, %(w)d, %(h)d), 0, 0);
  c.dataset.view = view;  // the view the canvas shows (read by tests and scripts)
  document.getElementById('fps').textContent = (1000 / (performance.now() - t)).toFixed(1) + ' frames/s';
  busy = false; draw();
}
c.onmousedown = e => last = [e.clientX, e.clientY];
window.onmouseup = () => last = null;
window.onmousemove = e => { if (!last) return;
  yaw -= (e.clientX - last[0]) * 0.01; pitch -= (e.clientY - last[1]) * 0.01;
  pitch = Math.max(-1.5, Math.min(1.5, pitch)); last = [e.clientX, e.clientY]; dirty = true; draw(); };
c.onwheel = e => { e.preventDefault(); zoom *= Math.exp(e.deltaY * 0.001); dirty = true; draw(); };
draw();
</script></body></html>"""


def serve(preview: RadiosityPreview, host: str = "127.0.0.1", port: int = 8765) -> None:
    """Serves the page and its frames (raw sRGB RGBA8 bytes) until interrupted; port 0 takes
    a free port, and the line printed once the server listens names the one taken."""

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            url = urllib.parse.urlparse(self.path)
            if url.path == "/":
                body = (_PAGE % {"w": preview.width, "h": preview.height, "w2": 2 * preview.width,
                                 "h2": 2 * preview.height}).encode()
                kind = "text/html"
            elif url.path == "/frame":
                q = {k: v[0] for k, v in urllib.parse.parse_qs(url.query).items()}
                try:
                    view = {k: float(q.get(k, d)) for k, d in (("yaw", 0), ("pitch", 0), ("zoom", 1))}
                    if not all(math.isfinite(v) for v in view.values()) or view["zoom"] <= 0:
                        raise ValueError
                except ValueError:
                    self.send_error(400, "yaw, pitch and zoom must be finite numbers, zoom > 0")
                    return
                rgb = tonemap_srgb8(preview.frame(**view))
                alpha = np.full(rgb.shape[:2] + (1,), 255, np.uint8)
                body = np.concatenate([rgb, alpha], axis=2).tobytes()
                kind = "application/octet-stream"
            elif url.path == "/info":
                body, kind = json.dumps({"solve_seconds": preview.solve_seconds}).encode(), "application/json"
            else:
                self.send_error(404)
                return
            self.send_response(200)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    with http.server.ThreadingHTTPServer((host, port), Handler) as httpd:
        port = httpd.server_address[1]
        print(f"preview at http://{host}:{port}/ (solved in {preview.solve_seconds:.2f} s); Ctrl-C stops", flush=True)
        try:
            httpd.serve_forever()
        except KeyboardInterrupt:
            pass
