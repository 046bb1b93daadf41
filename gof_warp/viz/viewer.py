"""A live web viewer of a model: our renderer's images from the browser's camera, served with viser.

Library part of ``python -m gof_warp.view RUN`` and ``python -m gof_warp.train --viewer`` (both thin CLIs).
:class:`Viewer` starts a viser server (a web page with a 3D scene and a GUI panel) and keeps, for every
connected browser, the picture of the Gaussians rendered by :func:`gof_warp.rendering.render.render` from that
browser's camera, set as the page's background image; over it viser draws the training cameras as frustums
and the run's newest mesh when there is one (:func:`~gof_warp.viz.mesh_files.find_mesh`: the last modified of
``RUN/mesh_*.ply|glb|obj``), shown from the start (a GUI checkbox hides it). A mesh with vertex colours or a
texture is sent to the browser as GLB with them, unlit (:func:`browser_glb`; the page draws it with three.js's
GLTFLoader), an uncoloured one as a lit grey surface. While the mesh is shown the
render is sent without its depth, as a backdrop behind the mesh: the mesh lies on the Gaussians' surface, and
compositing the two by depth would let each break through the other. A GUI dropdown picks what is shown:

* ``render``: the Gaussian render; ``depth``: median depth, colour-mapped as in the run pictures;
  ``normal``: rendered normals in world space, ``(n + 1) / 2``;
* ``opacity slice``: the GOF opacity field (min over the training views, :func:`gof_warp.rendering.opacity_field`) on
  the plane at ``slice depth`` in front of the browser's camera (black 0 → white 1, unseen points red).

The page opens at a training camera (:func:`start_camera`: the one whose optical axis points most directly at
the scene's centre, the per-axis median of the Gaussians' centres): its pose exactly, and its vertical field of
view (the browser's aspect ratio decides the horizontal one); orbiting turns about the point of its axis nearest
that centre.

Renders are at most ``max_size`` pixels on the long side (default 256 on a CPU, 1024 on a GPU; a GUI
slider changes it) and run in one worker thread, newest camera first: a browser that moves faster than
the renderer skips the stale poses. While training, :meth:`Viewer.update` hands the viewer a copy of the
Gaussians every few hundred iterations (``train --viewer-every``).

Access: the server listens on 127.0.0.1 by default; every WebSocket (the page's channel, which carries the
model, poses and renders) must present the viewer's random access token (``?token=`` in its address) and, when
a browser opens it, come from a page of the same host and port (its ``Origin``); others are closed before any
scene data is sent (:func:`access_refusal`). The printed address carries the token to viser's page through its
``?websocket=`` parameter (the page connects to that address). Every value a browser sets in the GUI is clamped
to the range the GUI declares before it is used (:meth:`Viewer.render_settings`).

viser is an optional dependency (``pip install 'gof_warp[viewer]'``), imported only when a viewer starts.
Cameras: ours are world-to-camera with OpenCV axes; viser's are camera-to-world with OpenCV axes
(``P_world = R_c2w p_cam + position``), vertical field of view in radians, quaternions wxyz.
"""

from __future__ import annotations

import ipaddress
import logging
import math
import secrets
import threading
import time
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import numpy as np

from ..core.camera import Camera
from ..core.errors import GofError
from .mesh_files import MeshFile, find_mesh, load_mesh_file  # noqa: F401 - find_mesh: the viewer's rule, re-exported

log = logging.getLogger(__name__)

MODES = ("render", "depth", "normal", "opacity slice")
CPU_MAX_SIZE, GPU_MAX_SIZE = 256, 1024  # default render size (long side, pixels)
MIN_SIZE, MAX_SIZE = 32, 2048
MIN_SLICE_DEPTH = 0.01
DEFAULT_HOST = "127.0.0.1"
REFUSED = 1008  # WebSocket close code "policy violation": a connection the access check refuses
JPEG_QUALITY = 90
UNSEEN_COLOR = (200, 40, 40)  # opacity slice: points no training view sees
MESH_COLOR = (200, 200, 190)
FRUSTUM_COLOR = (255, 150, 40)
FAR_DEPTH = 160.0  # depth of empty pixels for the browser's compositing (viser's depth range ends at 167.77)
MIN_LOOK_DISTANCE = 0.1  # the orbit centre of the first view lies at least this far along its camera's axis


def require_viser():
    """The ``viser`` module, or a :class:`GofError` saying how to install it."""
    try:
        import viser
    except ImportError:
        raise GofError("the web viewer needs viser, an optional dependency: pip install 'gof_warp[viewer]'") from None
    return viser


# ------------------------------------------------------------------------------------------ access
def is_loopback(host: str) -> bool:
    """Whether listening on ``host`` keeps the viewer to this machine (``localhost``, ``127.0.0.0/8``, ``::1``)."""
    if host.lower() in ("localhost", "localhost."):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _host_port(netloc: str, default_port: int) -> tuple[str, int] | None:
    """``("host", port)`` of a ``host[:port]`` (lower case, ``[]`` stripped), None when unreadable."""
    try:
        parts = urlsplit("//" + netloc)
        return (parts.hostname or "").lower(), parts.port or default_port
    except ValueError:
        return None


def access_refusal(path: str, headers, token: str) -> str | None:
    """Why a WebSocket opening request is refused, or None when it may connect.

    Args:
        path: the request target (``/?token=...``); headers: its HTTP headers (a mapping: ``Host``, ``Origin``).
        token: the viewer's access token.
    Rules: the query's ``token`` must equal ``token`` (compared in constant time); an ``Origin`` header (sent by
    every browser) must name an http(s) page at the request's own ``Host`` and port, loopback names
    (``localhost``, ``127.0.0.1``, ``::1``) counting as one host. A request without ``Origin`` is not from a
    browser page; the token alone decides.
    """
    given = parse_qs(urlsplit(path).query).get("token", [""])[0]
    if not token or not secrets.compare_digest(given.encode(), token.encode()):
        return "missing or wrong access token"
    origin = headers.get("Origin")
    if origin is None:
        return None
    o = urlsplit(origin)
    if o.scheme not in ("http", "https"):
        return f"foreign origin {origin!r}"
    page = _host_port(o.netloc, 443 if o.scheme == "https" else 80)
    own = _host_port(headers.get("Host", ""), 80)
    if page is None or own is None:
        return f"foreign origin {origin!r}"
    same_host = page[0] == own[0] or (is_loopback(page[0]) and is_loopback(own[0]))
    return None if same_host and page[1] == own[1] else f"foreign origin {origin!r}"


def _guard_connections(server, token: str) -> None:
    """Close every WebSocket of the viser ``server`` that :func:`access_refusal` refuses, before it gets data.

    viser has no hook on its WebSocket handshake (its ``process_request`` is a closure inside
    ``viser.infra.WebsockServer``). The narrowest point is its infra-level ``on_client_connect``: viser runs
    those callbacks for every new connection after the handshake and before it starts sending (the scene
    backlog, renders) or reading messages, and its raw connection (request path and headers) is in the infra
    server's ``_live_connections`` by then. The callback closes a refused connection (code :data:`REFUSED`),
    so viser's senders find it closed and send nothing. Connections opened between the server's start and
    this hook (before any scene exists) are dropped so that they reconnect through the check.
    """
    infra = getattr(server, "_websock_server", None)
    live = getattr(infra, "_live_connections", None)
    if infra is None or not isinstance(live, dict):
        raise GofError("this viser version gives the viewer no way to check connections; install viser 1.1")

    async def check(conn) -> None:
        ws = live.get(conn.client_id)
        if ws is None:  # cannot read the request: refuse (viser closes the connection on the error)
            raise PermissionError("viewer: a connection without a readable request")
        reason = access_refusal(ws.request.path, ws.request.headers, token)
        if reason is not None:
            log.warning("viewer: refused a connection from %s: %s", ws.remote_address, reason)
            await ws.close(REFUSED, "refused: " + reason)

    infra.on_client_connect(check)
    infra.disconnect_all_clients()


def clamp_number(value, lo: float, hi: float, default: float) -> float:
    """``value`` as a float in ``[lo, hi]``; ``default`` when it is not a number (or NaN)."""
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        return default
    return default if v != v else min(max(v, lo), hi)


def _accept_only_values(server) -> None:
    """Let browsers change only the ``value`` of a GUI input.

    viser applies every key of a client's ``GuiUpdateMessage`` to the input's server-side state (its props such
    as a slider's ``min``/``max``, its callbacks, ``removed``); its page only ever sends ``value``. The GUI's
    handler is swapped, through the infra server's public ``register_handler``/``unregister_handler``, for one
    that passes the ``value`` key on and drops the rest."""
    from viser import _messages

    infra, gui = server._websock_server, server.gui
    original = gui._handle_gui_updates

    async def values_only(client_id, message) -> None:
        updates = {k: v for k, v in message.updates.items() if k == "value"}
        if updates:
            await original(client_id, _messages.GuiUpdateMessage(message.uuid, updates))

    infra.unregister_handler(_messages.GuiUpdateMessage, original)
    infra.register_handler(_messages.GuiUpdateMessage, values_only)


# ------------------------------------------------------------------------------------------ cameras
def quat_to_matrix(wxyz) -> np.ndarray:
    """Unit quaternion ``[4]`` (w, x, y, z) → rotation ``[3, 3]`` (normalised first)."""
    w, x, y, z = np.asarray(wxyz, np.float64) / np.linalg.norm(wxyz)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def matrix_to_quat(R) -> np.ndarray:
    """Rotation ``[3, 3]`` → unit quaternion ``[4]`` (w, x, y, z) with ``w >= 0``."""
    R = np.asarray(R, np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-12))
        q = [0.0] * 4
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i], q[1 + j], q[1 + k] = 0.25 * s, (R[j, i] + R[i, j]) / s, (R[k, i] + R[i, k]) / s
    q = np.asarray(q) / np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def camera_from_viewer(position, wxyz, fov: float, aspect: float, max_size: int, name: str = "viewer") -> Camera:
    """A browser's camera → our :class:`Camera`, ``max_size`` pixels on its long side.

    Args:
        position: ``[3]`` camera centre in the world; wxyz: ``[4]`` camera-to-world rotation (OpenCV axes).
        fov: vertical field of view in radians; aspect: width / height of the browser's canvas.
    """
    if not (0 < fov < math.pi) or not aspect > 0 or max_size < 1:
        raise GofError(f"bad viewer camera: fov {fov}, aspect {aspect}, max_size {max_size}")
    R_c2w = quat_to_matrix(wxyz)
    R = R_c2w.T
    t = -R @ np.asarray(position, np.float64)
    if aspect >= 1:
        w, h = max_size, max(1, round(max_size / aspect))
    else:
        w, h = max(1, round(max_size * aspect)), max_size
    f = 0.5 * h / math.tan(0.5 * fov)
    return Camera(R=R, t=t, fx=f, fy=f, cx=0.5 * w, cy=0.5 * h, width=w, height=h, name=name)


def viewer_pose(camera: Camera) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Our camera → viser's ``(wxyz [4], position [3], vertical fov (rad), aspect)`` (the inverse of
    :func:`camera_from_viewer` up to the image size)."""
    R_c2w = camera.R.T
    position = -R_c2w @ camera.t
    return matrix_to_quat(R_c2w), position, 2.0 * math.atan(0.5 * camera.height / camera.fy), camera.width / camera.height


def start_camera(cameras: list[Camera], centre) -> int:
    """Index of the training camera the page opens at: the one whose optical axis (``+z``) makes the smallest angle
    with the direction from its centre to ``centre`` ``[3]`` (the scene's centre); ties: the first. Cameras that
    sit on ``centre`` count as looking away."""
    centre = np.asarray(centre, np.float64)
    best, best_cos = 0, -np.inf
    for i, cam in enumerate(cameras):
        to = centre - cam.center
        n = np.linalg.norm(to)
        cos = float(cam.R[2] @ to / n) if n > 0 else -1.0
        if cos > best_cos + 1e-12:
            best, best_cos = i, cos
    return best


def viewer_look_at(camera: Camera, distance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(position, look_at, up)`` [3] each, world coordinates, that put viser's camera exactly at ``camera``'s pose:
    its centre, the point ``distance`` along its axis, and its image's up (``-y``) direction (orthogonal to the axis,
    so that the page's "look at with up" gives back the same roll)."""
    R_c2w = camera.R.T
    position = camera.center
    return position, position + R_c2w[:, 2] * float(distance), -R_c2w[:, 1]


def scene_up(cameras: list[Camera]) -> np.ndarray:
    """The mean "up" (``-y`` camera axis in the world) of the cameras, normalised; ``+z`` when they disagree."""
    up = np.mean([-c.R[1] for c in cameras], axis=0) if cameras else np.zeros(3)
    n = np.linalg.norm(up)
    return up / n if n > 0.3 else np.array([0.0, 0.0, 1.0])


# ------------------------------------------------------------------------------------------ pictures
def colorize_opacity(field: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Opacity ``[H, W]`` in [0, 1] → grey ``[H, W, 3]`` uint8 (0 black, 1 white); points no view sees red."""
    v = np.round(np.clip(np.asarray(field, np.float32), 0, 1) * 255).astype(np.uint8)
    img = np.repeat(v[..., None], 3, axis=-1)
    img[np.asarray(seen) == 0] = UNSEEN_COLOR
    return img


def render_mode(gaussians, camera: Camera, mode: str, *, render_config=None, train_cameras=None,
                slice_depth: float = 1.0) -> tuple[np.ndarray, np.ndarray | None]:
    """What the viewer shows for ``camera`` (``mode`` one of :data:`MODES`).

    Returns ``(image [H, W, 3] uint8, depth [H, W] float32 or None)``: ``depth`` is the camera-space depth the
    browser composites its own objects (frustums, mesh) against — the median depth where the Gaussians cover
    a pixel (alpha > 0.5), :data:`FAR_DEPTH` elsewhere; None for the opacity slice. ``opacity slice`` evaluates
    the opacity field over ``train_cameras`` at H·W points: the plane at camera-space depth ``slice_depth``,
    one point per pixel centre.
    """
    if mode not in MODES:
        raise GofError(f"viewer mode must be one of {MODES}, got {mode!r}")
    if mode == "opacity slice":
        from ..rendering.opacity_field import opacity_field

        if not train_cameras:
            raise GofError("the opacity slice needs the training cameras")
        u = (np.arange(camera.width) + 0.5 - camera.cx) / camera.fx
        v = (np.arange(camera.height) + 0.5 - camera.cy) / camera.fy
        uu, vv = np.meshgrid(u, v, indexing="xy")
        rays = np.stack([uu, vv, np.ones_like(uu)], -1) * float(slice_depth)  # camera space, z = slice_depth
        points = (rays - camera.t) @ camera.R  # world: R^T (x - t) on row vectors
        field, seen = opacity_field(gaussians, train_cameras, points.reshape(-1, 3), render_config=render_config,
                                    return_seen=True)
        shape = (camera.height, camera.width)
        return colorize_opacity(field.cpu().numpy().reshape(shape), seen.cpu().numpy().reshape(shape)), None
    import torch

    from .pictures import colorize_depth, colorize_normal
    from ..rendering.render import render

    with torch.no_grad():
        out = render(gaussians, camera, config=render_config)
    alpha = out["alpha"].reshape(camera.height, camera.width).cpu().numpy()
    median = out["median_depth"].reshape(camera.height, camera.width).cpu().numpy()
    if mode == "render":
        image = np.round(out["rgb"].clamp(0, 1).cpu().numpy() * 255).astype(np.uint8)
    elif mode == "depth":
        image = colorize_depth(median, alpha)
    else:
        image = colorize_normal(out["normal"].cpu().numpy(), alpha, camera)
    depth = np.where((alpha > 0.5) & (median > 0), median, FAR_DEPTH).astype(np.float32)
    return image, depth


def browser_glb(mesh: MeshFile) -> bytes:
    """The GLB the viewer sends for a coloured :class:`~gof_warp.viz.mesh_files.MeshFile`: the mesh drawn in its own
    colours, unlit, from both sides (:func:`gof_warp.mesh.export.coloured_glb`: vertex or face colours, sRGB like the
    photos they come from, as glTF's linear ``COLOR_0``; a texture as the material's ``baseColorTexture``, sRGB in
    glTF, as is: :func:`~gof_warp.mesh.export.unlit_glb`). viser's page tone-maps the meshes it draws (ACES filmic):
    more contrast than the file's colours, and strongly saturated ones shift (the tests in
    ``tests/viz/test_viewer_mesh.py`` measure it)."""
    from ..mesh.export import coloured_glb, unlit_glb

    if mesh.appearance == "texture":
        return unlit_glb(mesh.mesh.export(file_type="glb"))
    v, f, rgb = mesh.vertices, mesh.faces, mesh.vertex_colors
    if mesh.appearance == "face":  # a colour per face: corners of their own
        v, f, rgb = v[f.ravel()], np.arange(f.size).reshape(-1, 3), np.repeat(mesh.face_colors, 3, axis=0)
    return coloured_glb(v, f, rgb)


def add_mesh(scene, name: str, mesh, visible: bool = True):
    """Put ``mesh`` into a viser ``scene`` as ``name``; returns viser's handle.

    A :class:`~gof_warp.viz.mesh_files.MeshFile` with colours or a texture goes as the GLB of :func:`browser_glb`
    (viser's page reads it with three.js's GLTFLoader); an uncoloured one, or ``(vertices [V, 3], faces [F, 3])``,
    as a lit :data:`MESH_COLOR` surface seen from both sides. Neither casts nor receives the page's shadows (the
    shadow maps would draw a big mesh again per cascade, slow in a browser without a GPU)."""
    if isinstance(mesh, MeshFile) and mesh.coloured:
        return scene.add_glb(name, browser_glb(mesh), visible=visible, cast_shadow=False, receive_shadow=False)
    v, f = (mesh.vertices, mesh.faces) if isinstance(mesh, MeshFile) else mesh
    return scene.add_mesh_simple(name, np.asarray(v, np.float32), np.asarray(f, np.uint32), color=MESH_COLOR,
                                 side="double", visible=visible, cast_shadow=False, receive_shadow=False)


# ------------------------------------------------------------------------------------------ the viewer
class Viewer:
    """A viser server showing one model (see the module docstring).

    Args:
        gaussians: :class:`~gof_warp.core.model.Gaussians` (a copy is rendered; see :meth:`update`).
        cameras: the training cameras (frustums, the initial view, the opacity field).
        render_config: :class:`~gof_warp.rendering.render.RenderConfig` of the run (background, near plane, ...).
        mesh: a :class:`~gof_warp.viz.mesh_files.MeshFile` (shown with its colours or texture) or
            ``(vertices [V, 3], faces [F, 3])`` (grey) to show, visible from the start (a GUI checkbox), or None.
        host, port: where to listen (default ``127.0.0.1``, this machine only; ``0.0.0.0``: every interface, with
            a warning; a busy port → the next free one).
        max_size: render size, long side in pixels (default 256 on CPU, 1024 on CUDA).
        title: label of the GUI panel.
        token: the access token every WebSocket must present (default: a random one, ``secrets.token_urlsafe``).
    Call :meth:`start` (or use ``with``), then :meth:`stop`.
    """

    def __init__(self, gaussians, cameras: list[Camera], *, render_config=None, mesh=None, host: str = DEFAULT_HOST,
                 port: int = 8080, max_size: int | None = None, title: str = "gof_warp", token: str | None = None):
        if not cameras:
            raise GofError("the viewer needs at least one camera (the run's cameras.json)")
        if max_size is not None and not MIN_SIZE <= int(max_size) <= MAX_SIZE:
            raise GofError(f"--max-size must be in [{MIN_SIZE}, {MAX_SIZE}], got {max_size}")
        if not 0 <= int(port) <= 65535:
            raise GofError(f"--port must be in [0, 65535], got {port}")
        self.cameras, self.render_config, self.mesh = list(cameras), render_config, mesh
        self.host, self.port, self.title = host, int(port), title
        self.token = token or secrets.token_urlsafe(24)
        on_gpu = gaussians.device.type == "cuda"
        self.max_size = int(max_size or (GPU_MAX_SIZE if on_gpu else CPU_MAX_SIZE))
        self._gaussians = gaussians.clone()
        self._iteration: int | None = None
        self._lock = threading.Lock()
        self._dirty: dict[int, object] = {}  # client id → client handle, waiting for a render (under _dirty_lock)
        self._dirty_lock = threading.Lock()
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self.server = None
        self.frames_sent = 0
        self.last_frame: np.ndarray | None = None  # [H, W, 3] uint8: the newest image sent to a browser
        self.last_camera: Camera | None = None  # the camera (from the browser's) that image was rendered from
        self._cast_mesh = None  # the mesh made ready for ray casting (mesh_coverage), built on first use
        self.last_render_s = float("nan")
        self.errors: list[str] = []
        centres = np.stack([c.center for c in self.cameras])
        self.scene_size = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) or 1.0
        self.start_index = start_camera(self.cameras, self._scene_centre())  # the page's first view

    # ------------------------------------------------------------------ life cycle
    def start(self) -> "Viewer":
        """Start the server and the render thread; returns self."""
        viser = require_viser()
        warning = self.exposure_warning()
        if warning:
            log.warning("%s", warning)
        self.server = viser.ViserServer(host=self.host, port=self.port, label=self.title, verbose=False)
        self.port = int(self.server.get_port())
        _guard_connections(self.server, self.token)  # before the scene exists
        _accept_only_values(self.server)
        self._build_scene()
        self._build_gui()
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(self._forget)
        self._thread = threading.Thread(target=self._render_loop, name="gof_warp-viewer", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the render thread and the server (idempotent)."""
        self._stopping.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=30)
            self._thread = None
        if self.server is not None:
            self.server.stop()
            self.server = None

    def __enter__(self) -> "Viewer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def url_at(self, host: str, port: int | None = None) -> str:
        """The page's address as a browser reaches the server at ``host:port`` (default: the server's port),
        with the access token: viser's page opens its WebSocket at the address in its ``websocket`` parameter."""
        netloc = f"[{host}]:{port or self.port}" if ":" in host else f"{host}:{port or self.port}"
        return f"http://{netloc}/?websocket=ws://{netloc}/?token={self.token}"

    @property
    def url(self) -> str:
        """The page's address on this machine, with the access token."""
        host = DEFAULT_HOST if self.host in ("0.0.0.0", "::", "") else self.host
        return self.url_at(host)

    def exposure_warning(self) -> str | None:
        """A warning when the server listens beyond this machine (a non-loopback ``host``), else None."""
        if is_loopback(self.host):
            return None
        return (f"the viewer listens on {self.host or 'every interface'}: anyone who can reach port {self.port} "
                f"of this machine and knows the access token can see the model; keep the token (in the address) "
                f"private, or listen on 127.0.0.1 (the default) and use SSH port forwarding")

    def how_to_open(self) -> str:
        """Where to point a browser, here and from another machine through SSH port forwarding."""
        target = DEFAULT_HOST if self.host in ("0.0.0.0", "::", "") else self.host
        lines = [f"viewer at {self.url}",
                 f"  from another computer: ssh -L {self.port}:{target}:{self.port} user@this-host, then "
                         f"open {self.url_at(DEFAULT_HOST)} there (the same address)"]
        if not is_loopback(self.host):
            lines.append(f"  or directly: {self.url_at('THIS-HOST')} (THIS-HOST: this machine's name or address)")
        return "\n".join(lines)

    @property
    def iteration(self) -> int | None:
        """The training iteration of the model shown (None outside training)."""
        return self._iteration

    @property
    def num_gaussians(self) -> int:
        """How many Gaussians the model shown has."""
        return len(self._gaussians)

    def serve_forever(self) -> None:
        """Block until Ctrl-C (KeyboardInterrupt is left to the caller)."""
        while not self._stopping.is_set():
            time.sleep(0.5)

    # ------------------------------------------------------------------ model updates (training)
    def update(self, gaussians, iteration: int | None = None) -> None:
        """Show ``gaussians`` from now on and re-render for every browser. A copy is taken here, in the caller's
        thread (the trainer's), so training may go on changing its model: [N, 59] floats, e.g. 240 MB for 1M
        Gaussians with degree-3 SH — cheap next to a training step when done every few hundred iterations."""
        copy = gaussians.clone()
        with self._lock:
            self._gaussians = copy
            self._iteration = iteration
        self._refresh_info()
        self.rerender()

    def rerender(self) -> None:
        """Render again for every connected browser (e.g. after a GUI change)."""
        if self.server is None:
            return
        for client in self.server.get_clients().values():
            self._mark(client)

    # ------------------------------------------------------------------ scene and GUI
    def _build_scene(self) -> None:
        s = self.server.scene
        s.set_up_direction(tuple(scene_up(self.cameras)))
        scale = 0.06 * self.scene_size
        self._frustums = []
        for i, cam in enumerate(self.cameras):
            wxyz, pos, fov, aspect = viewer_pose(cam)
            self._frustums.append(s.add_camera_frustum(f"/cameras/{i}", fov=fov, aspect=aspect, scale=scale,
                                                       wxyz=wxyz, position=pos, color=FRUSTUM_COLOR,
                                                       thickness=0.01 * scale))
        self._mesh_handle = None
        if self.mesh is not None:
            self._mesh_handle = add_mesh(s, "/mesh", self.mesh)
        first = self.cameras[self.start_index]
        pos, look, up = viewer_look_at(first, self._look_distance(first))
        cam = self.server.initial_camera
        cam.position, cam.look_at, cam.up, cam.fov = tuple(pos), tuple(look), tuple(up), viewer_pose(first)[2]

    def _scene_centre(self) -> np.ndarray:
        """The scene's centre ``[3]``: the per-axis median of the Gaussians' centres (robust to far floaters)."""
        return self._gaussians.means.detach().median(0).values.cpu().numpy().astype(np.float64)

    def _look_distance(self, camera: Camera) -> float:
        """Depth of the scene's centre (:meth:`_scene_centre`) in ``camera`` (the orbit centre lies that far along its
        axis), at least :data:`MIN_LOOK_DISTANCE`."""
        return max(float(camera.R[2] @ self._scene_centre() + camera.t[2]), MIN_LOOK_DISTANCE)

    def _build_gui(self) -> None:
        g = self.server.gui
        # The ranges declared here are the server's own: a browser's values are clamped to them when used
        # (render_settings), whatever it sends, and written back to the GUI.
        self._slice_range = (MIN_SLICE_DEPTH, max(round(4 * self.scene_size, 2), MIN_SLICE_DEPTH))
        self._slice_default = clamp_number(round(self._look_distance(self.cameras[self.start_index]), 2),
                                           *self._slice_range, 1.0)
        self._mode = g.add_dropdown("show", MODES, initial_value="render")
        self._slice = g.add_slider("slice depth", min=self._slice_range[0], max=self._slice_range[1],
                                   step=round(self.scene_size / 100, 4) or 0.01, initial_value=self._slice_default)
        self._size = g.add_slider("max size (px)", min=MIN_SIZE, max=MAX_SIZE, step=32, initial_value=self.max_size)
        self._show_cams = g.add_checkbox("training cameras", initial_value=True)
        self._show_mesh = g.add_checkbox("mesh", initial_value=self.mesh is not None, disabled=self.mesh is None)
        self._info = g.add_markdown("")
        for handle in (self._mode, self._slice, self._size):
            handle.on_update(lambda _: self._settings_changed())
        self._show_cams.on_update(lambda _: [setattr(f, "visible", self._show_cams.value is True)
                                             for f in self._frustums])
        if self._mesh_handle is not None:
            self._show_mesh.on_update(lambda _: self._mesh_toggled())
        self._refresh_info()

    def _mesh_toggled(self) -> None:
        """The mesh checkbox changed: show or hide the mesh, and render again (with or without depth)."""
        self._mesh_handle.visible = self.mesh_shown
        self.rerender()

    @property
    def mesh_shown(self) -> bool:
        """Whether the mesh is on the page (the checkbox ticked; False without a mesh or a server)."""
        return self._mesh_handle is not None and self._show_mesh.value is True

    def mesh_coverage(self, camera: Camera) -> np.ndarray:
        """``[H, W]`` bool: the pixels of ``camera`` whose centre ray meets the mesh (all False without a mesh), by
        ray casting (:func:`gof_warp.viz.panels.shade_cast_mesh`). What the page shows there is the mesh, not the
        render (``view --screenshot`` compares the page with the render elsewhere)."""
        from .panels import CastMesh, shade_cast_mesh

        if self.mesh is None:
            return np.zeros((camera.height, camera.width), bool)
        if self._cast_mesh is None:
            v, f = (self.mesh.vertices, self.mesh.faces) if isinstance(self.mesh, MeshFile) else self.mesh
            self._cast_mesh = CastMesh.build(v, f, "cpu")
        marker = (1.0, 0.0, 1.0)  # a background no shaded mesh pixel has (the shaded mesh is grey or red)
        image = shade_cast_mesh(self._cast_mesh, camera, supersample=1, background=marker)
        return np.any(image != np.array([255, 0, 255], np.uint8), axis=-1)

    def render_settings(self) -> tuple[str, int, float]:
        """``(mode, max_size, slice_depth)`` from the GUI, each within the range the GUI declares: a mode not in
        :data:`MODES` → ``render``; sizes clamped to [:data:`MIN_SIZE`, :data:`MAX_SIZE`], the slice depth to
        its slider's range; values that are not numbers → the defaults."""
        mode = self._mode.value if self._mode.value in MODES else "render"
        size = int(round(clamp_number(self._size.value, MIN_SIZE, MAX_SIZE, self.max_size)))
        depth = clamp_number(self._slice.value, *self._slice_range, self._slice_default)
        return mode, size, depth

    def _settings_changed(self) -> None:
        """A browser changed the mode, size or slice depth: show the clamped values in every GUI, render again."""
        mode, size, depth = self.render_settings()
        for handle, value in ((self._mode, mode), (self._size, size), (self._slice, depth)):
            if handle.value != value:
                handle.value = value
        self.rerender()

    def _refresh_info(self) -> None:
        if self.server is None:
            return
        it = "" if self._iteration is None else f"iteration {self._iteration} · "
        ms = "" if self.last_render_s != self.last_render_s else f" · render {1000 * self.last_render_s:.0f} ms"
        self._info.content = f"{it}{len(self._gaussians):,} Gaussians · {len(self.cameras)} cameras{ms}"

    def _on_connect(self, client) -> None:
        client.camera.on_update(lambda cam: self._mark(client))
        self._mark(client)

    def _mark(self, client) -> None:
        with self._dirty_lock:
            self._dirty[client.client_id] = client
        self._wake.set()

    def _forget(self, client) -> None:
        with self._dirty_lock:
            self._dirty.pop(client.client_id, None)

    def _next_dirty(self):
        """The client waiting longest for a render (removed from the set), or None."""
        with self._dirty_lock:
            return self._dirty.pop(next(iter(self._dirty))) if self._dirty else None

    # ------------------------------------------------------------------ rendering (worker thread)
    def _render_loop(self) -> None:
        self._warm_up()
        while not self._stopping.is_set():
            self._wake.wait()
            self._wake.clear()
            while not self._stopping.is_set() and (client := self._next_dirty()) is not None:
                try:
                    self._render_for(client)
                except Exception as e:  # noqa: BLE001 - a failed frame must not end the viewer
                    if str(e) not in self.errors:
                        self.errors.append(str(e))
                        log.warning("viewer: render failed: %s", e)

    def _warm_up(self) -> None:
        """One small render before any browser asks, so that the first real frame is not slowed by first-use costs."""
        try:
            wxyz, pos, fov, aspect = viewer_pose(self.cameras[0])
            render_mode(self._gaussians, camera_from_viewer(pos, wxyz, fov, aspect, MIN_SIZE), "render",
                        render_config=self.render_config)
        except Exception as e:  # noqa: BLE001 - the real frames will report the error
            log.debug("viewer warm-up render failed: %s", e)

    def _render_for(self, client) -> None:
        cam = client.camera
        try:
            position, wxyz, fov, aspect = cam.position, cam.wxyz, cam.fov, cam.aspect
        except (AssertionError, ZeroDivisionError):  # the browser has not sent its camera yet
            return
        mode, size, slice_depth = self.render_settings()
        camera = camera_from_viewer(position, wxyz, fov, aspect, size)
        with self._lock:
            gaussians = self._gaussians
        t0 = time.perf_counter()
        image, depth = render_mode(gaussians, camera, mode, render_config=self.render_config,
                                   train_cameras=self.cameras, slice_depth=slice_depth)
        self.last_render_s = time.perf_counter() - t0
        if self.mesh_shown:  # a backdrop behind the mesh, which lies on the same surface (module docstring)
            depth = None
        client.scene.set_background_image(image, format="jpeg", jpeg_quality=JPEG_QUALITY, depth=depth)
        self.last_frame, self.last_camera = image, camera
        self.frames_sent += 1
        self._refresh_info()


def open_run(run_dir, *, device: str = "cpu", mesh_path=None, **viewer_kwargs) -> Viewer:
    """A :class:`Viewer` (not started) of a training run folder: its Gaussians, training cameras, render
    settings and its newest mesh (:func:`~gof_warp.viz.mesh_files.find_mesh`; or ``mesh_path``; ``False``: no mesh),
    with its colours or texture."""
    from ..training.run_folder import load_run

    run = Path(run_dir)
    if not run.is_dir():
        raise GofError(f"{run} is not a run folder (a training output with point_cloud.ply and cameras.json)")
    gaussians, cameras, _, render_config = load_run(run, None, device)
    cfg_background = _run_background(run)
    if cfg_background is not None:
        import dataclasses

        render_config = dataclasses.replace(render_config, background=cfg_background)
    mesh = None
    if mesh_path is not False:
        path = Path(mesh_path) if mesh_path else find_mesh(run)
        if path is not None:
            mesh = load_mesh_file(path)
            log.info("mesh %s: %d vertices, %d faces, colours: %s", path, len(mesh.vertices), len(mesh.faces),
                     mesh.appearance)
    return Viewer(gaussians, cameras, render_config=render_config, mesh=mesh, title=f"gof_warp · {run.name}",
                  **viewer_kwargs)


def _run_background(run: Path):
    """The scene background of a run (``config.yaml``'s ``data.background``), as the trainer renders with."""
    cfg = run / "config.yaml"
    if not cfg.is_file():
        return None
    from ..core.config import load_yaml

    bg = (load_yaml(cfg).get("data") or {}).get("background")
    return tuple(float(c) for c in bg) if isinstance(bg, (list, tuple)) and len(bg) == 3 else None
