"""``python -m gof_warp.view RUN [--port 8080] [--host 127.0.0.1] [--device D] [--max-size PX] [--mesh M.ply | --no-mesh]
[--screenshot PNG]``

A live web viewer of a training run: open the printed address in a browser to fly around the Gaussians
rendered by gof_warp's own renderer (render / depth / normal / opacity-field slice), with the training
cameras and the run's newest mesh (the last modified ``RUN/mesh_*.ply|glb|obj``) in its colours or texture, shown
from the start; the page opens at a training camera. See :mod:`gof_warp.viz.viewer`.

It listens on 127.0.0.1 (this machine only) and prints its address, which carries a random access token: the
page's WebSocket must present it (see :mod:`gof_warp.viz.viewer`). On a remote GPU machine, start it there and
forward the port from your computer: ``ssh -L 8080:127.0.0.1:8080 user@gpu-host``, then open the printed
address on your computer. ``--host 0.0.0.0`` serves every interface (with a warning). ``--screenshot PNG`` takes a
picture of the page with a headless Chromium (no display needed) and exits. Needs the optional extra:
``pip install 'gof_warp[viewer]'``.
"""

from __future__ import annotations

import argparse
import base64
import json
import logging
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .common import HelpFormatter, configure_output, run_command
from ..core.errors import GofError
from ..core.io_utils import write_bytes_atomic
from ..viz.viewer import FRUSTUM_COLOR

log = logging.getLogger(__name__)

GUI_PANEL_PX = (340, 250)  # viser's GUI panel: width and height (pixels) at the top right of the page
MESH_PAGE_TIMEOUT = 300.0  # screenshot: seconds for a page with a mesh (software WebGL draws a big one slowly)
PAGE_MATCH_LEVELS = 12.0  # shows_frame: median difference (of 255) of a page that shows the frame
#: JavaScript that hides viser's pop-up notifications (e.g. "software WebGL") before a screenshot.
HIDE_NOTIFICATIONS_JS = ("(() => { const s = document.createElement('style'); "
                         "s.textContent = '.mantine-Notifications-root { display: none !important; }'; "
                         "document.head.appendChild(s); return true; })()")
CHROMIUM_NAMES = ("chromium-headless-shell", "chromium", "chromium-browser", "google-chrome", "google-chrome-stable",
                  "headless_shell")
CHROMIUM_FLAGS = ("--headless", "--no-first-run", "--disable-dev-shm-usage", "--hide-scrollbars",
                  "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--mute-audio")


def quiet_websockets() -> None:
    """Keep the ``websockets`` library (under viser) from logging every connection at INFO in a command's output."""
    import logging

    logging.getLogger("websockets").setLevel(logging.WARNING)


def chromium_flags() -> list[str]:
    """:data:`CHROMIUM_FLAGS`, plus ``--no-sandbox`` only where Chromium cannot start with its sandbox: as root
    (Chromium refuses to), or when ``GOF_WARP_CHROMIUM_NO_SANDBOX=1`` says so (e.g. a container without user
    namespaces). The reason is logged."""
    flags = list(CHROMIUM_FLAGS)
    if os.geteuid() == 0:
        log.info("screenshot browser: running as root, where Chromium refuses its sandbox: --no-sandbox")
        flags.append("--no-sandbox")
    elif os.environ.get("GOF_WARP_CHROMIUM_NO_SANDBOX") == "1":
        log.info("screenshot browser: GOF_WARP_CHROMIUM_NO_SANDBOX=1: --no-sandbox")
        flags.append("--no-sandbox")
    return flags


def find_chromium() -> str | None:
    """A Chromium binary: ``$GOF_WARP_CHROMIUM``, else the first of :data:`CHROMIUM_NAMES` on the PATH (Debian:
    ``apt-get install chromium-headless-shell`` or ``chromium``); None when there is none."""
    env = os.environ.get("GOF_WARP_CHROMIUM")
    if env:
        return env if Path(env).is_file() else shutil.which(env)
    return next((p for p in map(shutil.which, CHROMIUM_NAMES) if p), None)


class _DevTools:
    """A minimal Chrome DevTools Protocol client on one websocket (the ``websockets`` package viser brings)."""

    def __init__(self, ws_url: str):
        from websockets.sync.client import connect

        self.ws = connect(ws_url, max_size=64 * 2**20, open_timeout=20)
        self.next_id = 0

    def call(self, method: str, params: dict | None = None, session: str | None = None, timeout: float = 30.0) -> dict:
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        self.ws.send(json.dumps(msg))
        deadline = time.monotonic() + timeout
        while True:
            reply = json.loads(self.ws.recv(timeout=max(deadline - time.monotonic(), 0.01)))
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise GofError(f"Chromium refused {method}: {reply['error']}")
                return reply.get("result", {})

    def close(self):
        self.ws.close()


def screenshot(url: str, path, *, width: int = 1200, height: int = 800, ready=None, accept=None, timeout: float = 90.0,
               settle: float = 1.0, script: str | None = None, chromium: str | None = None,
               stable: bool = False) -> Path:
    """Load ``url`` in a headless Chromium and write a PNG screenshot ``[height, width]`` to ``path``.

    Args:
        ready: a function polled (every 0.1 s, up to ``timeout`` seconds after the page loaded) until it returns
            True before the picture is taken — e.g. ``lambda: viewer.frames_sent > 0``; then ``settle`` seconds
            more for the browser to draw.
        script: JavaScript evaluated in the page just before the picture (e.g. to hide pop-ups).
        accept: a function of the screenshot (``[height, width, 3]`` uint8) saying whether the page shows what it
            should yet (a slow software-WebGL browser draws late); captures are repeated every 0.5 s until it
            does, up to ``timeout``. None: the first capture.
        stable: after that, capture every 0.5 s until two captures in a row are the same picture (the page has
            finished drawing, e.g. a mesh the browser was still loading), up to ``timeout``.
        chromium: the binary (default :func:`find_chromium`).
    Raises :class:`GofError` when there is no Chromium or the page cannot be captured.
    """
    binary = chromium or find_chromium()
    if binary is None:
        raise GofError("no Chromium found for the screenshot: apt-get install chromium-headless-shell (or chromium), "
                       "or set GOF_WARP_CHROMIUM to a Chrome/Chromium binary")
    with tempfile.TemporaryDirectory(prefix="gof_warp_chromium_") as profile:
        proc = subprocess.Popen([binary, *chromium_flags(), "--remote-debugging-port=0", f"--user-data-dir={profile}",
                                 f"--window-size={width},{height}", "about:blank"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)  # its own process group: ended whole below
        try:
            ws_url = _devtools_url(proc, timeout=30.0)
            dt = _DevTools(ws_url)
            try:
                target = dt.call("Target.createTarget", {"url": "about:blank"})["targetId"]
                session = dt.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
                dt.call("Emulation.setDeviceMetricsOverride", {"width": width, "height": height,
                                                               "deviceScaleFactor": 1, "mobile": False}, session)
                dt.call("Page.enable", session=session)
                dt.call("Page.navigate", {"url": url}, session)
                deadline = time.monotonic() + timeout
                while ready is not None and not ready():
                    if time.monotonic() > deadline:
                        raise GofError(f"the page {url} did not get ready within {timeout:.0f} s")
                    time.sleep(0.1)
                time.sleep(settle)
                if script:
                    dt.call("Runtime.evaluate", {"expression": script}, session)
                    time.sleep(0.2)

                def capture() -> str:  # software WebGL may take long over a frame of a big mesh: up to the deadline
                    return dt.call("Page.captureScreenshot", {"format": "png"}, session,
                                   timeout=max(deadline - time.monotonic(), 30.0))["data"]

                while True:
                    data = capture()
                    if accept is None or accept(_decode_png(data)):
                        break
                    if time.monotonic() > deadline:
                        raise GofError(f"the page {url} did not show the expected picture within {timeout:.0f} s")
                    time.sleep(0.5)
                while stable and time.monotonic() < deadline:
                    time.sleep(0.5)
                    again = capture()
                    if np.array_equal(_decode_png(again), _decode_png(data)):
                        break
                    data = again
            finally:
                dt.close()
        finally:
            _end_browser(proc)
    out = Path(path)
    write_bytes_atomic(out, base64.b64decode(data))
    return out


def _end_browser(proc: subprocess.Popen) -> None:
    """End the Chromium started by :func:`screenshot` and every process it spawned (renderer, GPU process): its
    process group, which it leads (``start_new_session``); SIGTERM, then SIGKILL after 10 s."""
    for sig, wait in ((signal.SIGTERM, 10), (signal.SIGKILL, 5)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:  # the group is gone
            break
        try:
            proc.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
        deadline = time.monotonic() + wait  # the leader is gone: wait for the rest of its group
        while time.monotonic() < deadline:
            try:
                os.killpg(proc.pid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.1)
    if proc.stderr is not None:
        proc.stderr.close()


def _decode_png(data: str):
    import io

    import numpy as np
    from PIL import Image

    with Image.open(io.BytesIO(base64.b64decode(data))) as im:
        return np.asarray(im.convert("RGB"))


def _devtools_url(proc: subprocess.Popen, timeout: float) -> str:
    """The browser's DevTools websocket address, read from Chromium's stderr ("DevTools listening on ws://...")."""
    deadline = time.monotonic() + timeout
    seen = []
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            if proc.poll() is not None:
                break
            continue
        seen.append(line.strip())
        m = re.search(r"DevTools listening on (ws://\S+)", line)
        if m:
            return m.group(1)
    raise GofError("Chromium did not start its DevTools endpoint: " + " | ".join(seen[-5:]))


def page_difference(page: np.ndarray, frame: np.ndarray, covered: np.ndarray | None = None) -> np.ndarray:
    """How far a screenshot of the viewer's page is from the rendered ``frame`` it should show, per frame pixel.

    ``page``: ``[H, W, 3]`` uint8 screenshot (the canvas fills the window; the image is stretched over it);
    ``frame``: ``[h, w, 3]`` uint8 render; ``covered``: ``[h, w]`` bool, the frame's pixels the mesh hides on the
    page (:meth:`gof_warp.viz.viewer.Viewer.mesh_coverage`), or None. The page is box-filtered down to ``h × w``;
    returns the mean absolute difference (0–255) of the pixels clear of the GUI panel (:data:`GUI_PANEL_PX`, top
    right), of the orange camera frustums, of the mesh (``covered`` and its 1-pixel rim) and of the border, as a
    1-D array.
    """
    from PIL import Image

    H, W = page.shape[:2]
    h, w = frame.shape[:2]
    small = np.asarray(Image.fromarray(page).resize((w, h), Image.Resampling.BOX)).astype(np.int32)
    orange = (np.abs(page.astype(np.int32) - FRUSTUM_COLOR).sum(-1) < 90).astype(np.uint8) * 255
    keep = np.asarray(Image.fromarray(orange).resize((w, h), Image.Resampling.BOX)) == 0
    pw, ph = GUI_PANEL_PX
    keep[: math.ceil(h * ph / H), int(w * (W - pw) / W):] = False
    keep[[0, -1], :] = False
    keep[:, [0, -1]] = False
    if covered is not None:
        keep &= ~grow_mask(np.asarray(covered, bool))
    return np.abs(small - frame.astype(np.int32)).mean(-1)[keep]


def grow_mask(mask: np.ndarray) -> np.ndarray:
    """``mask`` ``[h, w]`` bool with its 8 neighbours of every True pixel set too."""
    out = mask.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out[max(dy, 0):mask.shape[0] + min(dy, 0), max(dx, 0):mask.shape[1] + min(dx, 0)] |= \
                mask[max(-dy, 0):mask.shape[0] + min(-dy, 0), max(-dx, 0):mask.shape[1] + min(-dx, 0)]
    return out


def shows_frame(page, frame, covered=None) -> bool:
    """Whether a screenshot ``[H, W, 3]`` of the viewer's page shows ``frame`` (None: nothing rendered yet) where the
    mesh does not hide it (``covered``, see :func:`page_difference`): on at least half of those pixels, with a median
    difference under :data:`PAGE_MATCH_LEVELS`. A frame the mesh hides almost entirely (under 2 % left) cannot be
    checked: then any frame counts."""
    if frame is None:
        return False
    h, w = frame.shape[:2]
    open_pixels = h * w if covered is None else int((~grow_mask(np.asarray(covered, bool))).sum())
    if open_pixels < 0.02 * h * w:
        return True
    diff = page_difference(page, frame, covered)
    return diff.size > 0.5 * open_pixels and float(np.median(diff)) < PAGE_MATCH_LEVELS


def _page_ready(viewer, page) -> bool:
    """Whether the screenshot ``page`` shows the viewer's newest render where the mesh (if shown) leaves it open."""
    camera = viewer.last_camera
    frame = viewer.last_frame
    if frame is None or camera is None:
        return False
    covered = viewer.mesh_coverage(camera) if viewer.mesh_shown else None
    if covered is not None and covered.shape != frame.shape[:2]:  # a newer frame came in between: next capture
        return False
    return shows_frame(page, frame, covered)


DESCRIPTION = """\
A live web viewer of a training run: open the printed address in a browser to fly around the
Gaussians rendered by gof_warp's own renderer (render, depth, normal, opacity-field slice), with the
training cameras and the run's newest mesh (the last modified RUN/mesh_*.ply|glb|obj, in its colours
or texture, shown from the start). The page opens at the training camera that looks most directly at
the scene's centre."""
EPILOG = """\
It listens on 127.0.0.1 (this machine only) and prints its address, with a random access token that
the page's connection must present. On a remote GPU machine, start it there and forward the port
from your computer:
  ssh -L 8080:127.0.0.1:8080 user@gpu-host
then open the printed address on your computer. --host 0.0.0.0 serves every interface (with a
warning: anyone who reaches the port and has the address sees the model). --screenshot PNG takes a picture of the page with a headless
Chromium (no display needed) and exits. Needs the optional extra: pip install 'gof_warp[viewer]'."""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gof_warp.view", description=DESCRIPTION, epilog=EPILOG,
                                 formatter_class=HelpFormatter)
    ap.add_argument("run", help="training output folder (point_cloud.ply, cameras.json)")
    ap.add_argument("--port", type=int, default=8080, help="port of the web page (a busy one: the next free one)")
    ap.add_argument("--host", default="127.0.0.1", help="interface to listen on (127.0.0.1: this machine only; "
                                                        "0.0.0.0: every interface, with a warning)")
    ap.add_argument("--device", default="auto", help="cpu, cuda, cuda:N or auto")
    ap.add_argument("--max-size", type=int, default=None, help="render size, long side in pixels (default 256 on "
                                                                "CPU, 1024 on GPU; also a slider in the page)")
    ap.add_argument("--mesh", default=None, help="mesh to show, PLY, OBJ or GLB, with its colours or texture "
                                                  "(default: the run's last modified mesh_*.ply|glb|obj)")
    ap.add_argument("--no-mesh", action="store_true", help="show no mesh")
    ap.add_argument("--screenshot", default=None, metavar="PNG", help="write a screenshot of the page (headless "
                                                                       "Chromium) and exit (default: serve until Ctrl-C)")
    ap.add_argument("--quiet", action="store_true", help="no log lines (errors and warnings still shown)")
    a = ap.parse_args(argv)
    configure_output(a.quiet)
    quiet_websockets()

    def body():
        from ..core.devices import resolve_device
        from ..viz.viewer import open_run, require_viser

        if a.screenshot:  # before any work: never over the run's own files, a folder or a device
            from ..core.io_utils import check_output_path
            from ..training.run_folder import run_inputs

            from ..viz.mesh_files import run_meshes

            meshes = [Path(a.mesh)] if a.mesh else run_meshes(a.run)
            check_output_path(a.screenshot, protected=run_inputs(Path(a.run)) + meshes)
        require_viser()
        if a.screenshot and find_chromium() is None:
            screenshot("", a.screenshot)  # raises the clear "no Chromium" error before the model is loaded
        viewer = open_run(a.run, device=resolve_device(a.device), mesh_path=False if a.no_mesh else a.mesh,
                          host=a.host, port=a.port, max_size=a.max_size)
        with viewer:
            if a.screenshot:
                path = screenshot(viewer.url, a.screenshot, ready=lambda: viewer.frames_sent > 0,
                                  accept=lambda page: _page_ready(viewer, page), script=HIDE_NOTIFICATIONS_JS,
                                  stable=viewer.mesh_shown,
                                  timeout=MESH_PAGE_TIMEOUT if viewer.mesh_shown else 90.0)
                print(f"wrote {path}")
                return 0
            print(viewer.how_to_open(), flush=True)
            print("Ctrl-C to stop", flush=True)
            try:
                viewer.serve_forever()
            except KeyboardInterrupt:
                print("viewer stopped", file=sys.stderr)
        return 0

    return run_command(body)


if __name__ == "__main__":
    sys.exit(main())
