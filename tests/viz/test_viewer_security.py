"""The viewer's exposure: it listens on 127.0.0.1 unless told otherwise (and warns when told), refuses WebSocket
connections without its access token or from a foreign page's Origin before any scene data is sent, clamps every
value a client sets to the range its GUI declares, and its screenshot browser keeps Chromium's sandbox unless
running as root. Only 127.0.0.1 traffic, bounded waits."""

import importlib.util
import logging
import socket

import numpy as np
import pytest

from gof_warp.core.camera import look_at
from gof_warp.core.model import Gaussians

HAVE_VISER = importlib.util.find_spec("viser") is not None
needs_viser = pytest.mark.skipif(not HAVE_VISER, reason="viser is not installed: pip install -e '.[viewer]'")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _scene():
    """One opaque red Gaussian at the origin and two cameras looking at it (no training needed)."""
    g = Gaussians.from_activated(np.zeros((1, 3)), np.array([[1.0, 0, 0, 0]]), np.full((1, 3), 0.4), np.array([0.99]),
                                 colors=np.array([[0.9, 0.1, 0.1]]), device="cpu")
    cams = [look_at([0.0, -3.0, 0.0], [0.0, 0.0, 0.0], fx=40.0, fy=40.0, width=48, height=40, name="a"),
            look_at([3.0, 0.0, 0.0], [0.0, 0.0, 0.0], fx=40.0, fy=40.0, width=48, height=40, name="b")]
    return g, cams


@pytest.fixture(scope="module")
def viewer():
    from gof_warp.viz.viewer import Viewer

    g, cams = _scene()
    v = Viewer(g, cams, port=_free_port(), max_size=64).start()  # the default host
    try:
        yield v
    finally:
        v.stop()


def _listening_addresses(port: int) -> set[str]:
    """The local addresses of the TCP sockets listening on ``port`` (``/proc/net/tcp`` and ``tcp6``)."""
    found = set()
    for table, width in (("/proc/net/tcp", 8), ("/proc/net/tcp6", 32)):
        try:
            lines = open(table).read().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            addr, p = fields[1].split(":")
            if int(p, 16) == port and fields[3] == "0A":  # 0A: LISTEN
                if width == 8:
                    found.add(socket.inet_ntop(socket.AF_INET, bytes.fromhex(addr)[::-1]))
                else:
                    raw = b"".join(bytes.fromhex(addr[i:i + 8])[::-1] for i in range(0, 32, 8))
                    found.add(socket.inet_ntop(socket.AF_INET6, raw))
    return found


def _connect(viewer, query: str = "", origin: str | None = None):
    """A WebSocket to the viewer as viser's page opens it (its subprotocol), with ``query`` and ``Origin``."""
    import viser
    from websockets.sync.client import connect

    headers = {"Origin": origin} if origin else None
    return connect(f"ws://127.0.0.1:{viewer.port}/{query}", subprotocols=[f"viser-v{viser.__version__}"],
                   additional_headers=headers, open_timeout=10, close_timeout=5)


def _first_message_or_close(ws, timeout: float = 10.0):
    """``("message", bytes)`` for the first message the server sends, or ``("closed", close code)``."""
    from websockets.exceptions import ConnectionClosed, InvalidStatus

    try:
        return "message", ws.recv(timeout=timeout)
    except ConnectionClosed as e:
        return "closed", e.rcvd.code if e.rcvd is not None else None
    except InvalidStatus as e:  # refused in the opening handshake
        return "closed", e.response.status_code


# ------------------------------------------------------------------------------------------ where it listens
@needs_viser
def test_viewer_listens_on_loopback_by_default(viewer):
    assert viewer.host == "127.0.0.1"
    assert _listening_addresses(viewer.port) == {"127.0.0.1"}
    assert viewer.url.startswith(f"http://127.0.0.1:{viewer.port}/")
    assert f"token={viewer.token}" in viewer.url and len(viewer.token) >= 20


def test_cli_defaults_are_loopback():
    import re

    from gof_warp.cli import train, view

    for main, flag in ((view.main, "--host"), (train.main, "--viewer-host")):
        entry = re.search(rf"^  {flag} .*?\(default:\s+(\S+?)\)", _help(main), re.S | re.M)
        assert entry and entry.group(1) == "127.0.0.1", f"{flag} default"


def _help(main) -> str:
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), pytest.raises(SystemExit):
        main(["--help"])
    return buf.getvalue()


def test_non_loopback_host_is_warned_about(caplog):
    from gof_warp.viz.viewer import Viewer, is_loopback

    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("") and not is_loopback("192.168.1.5")
    g, cams = _scene()
    local = Viewer(g, cams, host="127.0.0.1")
    assert local.exposure_warning() is None
    wide = Viewer(g, cams, host="0.0.0.0", port=8123)
    warning = wide.exposure_warning()
    assert warning and "anyone who can reach port 8123" in warning and "token" in warning
    hint = local.how_to_open()
    assert f"ssh -L {local.port}:127.0.0.1:{local.port}" in hint and local.token in hint


# ------------------------------------------------------------------------------------------ who may connect
@needs_viser
def test_websocket_without_the_token_is_refused_before_any_scene_data(viewer):
    with _connect(viewer) as ws:
        kind, what = _first_message_or_close(ws)
    assert kind == "closed", f"a connection without the token received {len(what)} bytes of the scene"
    with _connect(viewer, f"?token={viewer.token[:-1]}x") as ws:
        kind, what = _first_message_or_close(ws)
    assert kind == "closed", "a wrong token is refused too"


@needs_viser
def test_websocket_from_a_foreign_origin_is_refused_even_with_the_token(viewer):
    token = getattr(viewer, "token", "")
    with _connect(viewer, f"?token={token}", origin="http://evil.example") as ws:
        kind, what = _first_message_or_close(ws)
    assert kind == "closed", "a foreign page's connection received the scene"


@needs_viser
def test_websocket_with_the_token_and_own_origin_gets_the_scene(viewer):
    for origin in (None, f"http://127.0.0.1:{viewer.port}", f"http://localhost:{viewer.port}"):
        with _connect(viewer, f"?token={viewer.token}", origin=origin) as ws:
            kind, what = _first_message_or_close(ws)
        assert kind == "message" and len(what) > 16, (origin, kind, what)


def test_access_rule():
    from gof_warp.viz.viewer import access_refusal

    tok = "abc_DEF-123"
    ok = {"Host": "127.0.0.1:8080", "Origin": "http://127.0.0.1:8080"}
    assert access_refusal(f"/?token={tok}", ok, tok) is None
    assert access_refusal(f"/?token={tok}", {"Host": "127.0.0.1:8080"}, tok) is None  # not a browser
    assert access_refusal("/", ok, tok) is not None
    assert access_refusal("/?token=", ok, tok) is not None
    assert access_refusal(f"/?token={tok}x", ok, tok) is not None
    for origin in ("http://evil.example", "http://127.0.0.1:8081", "null", "file://", "http://evil.example:8080"):
        assert access_refusal(f"/?token={tok}", {**ok, "Origin": origin}, tok) is not None, origin
    assert access_refusal(f"/?token={tok}", {"Host": "gpu-host:8080", "Origin": "http://gpu-host:8080"}, tok) is None


# ------------------------------------------------------------------------------------------ client values
class _FakeCamera:
    position, wxyz, fov, aspect = np.array([0.0, -3.0, 0.0]), np.array([0.7071, -0.7071, 0.0, 0.0]), 0.9, 1.5


class _FakeClient:
    """What :meth:`Viewer._render_for` reads of a browser: its camera; it records the image set."""
    client_id = 12345

    def __init__(self):
        self.camera = _FakeCamera()
        self.images = []
        self.scene = self

    def set_background_image(self, image, **_):
        self.images.append(image)


def _client_update(viewer, handle, **updates):
    """Hand a client's ``GuiUpdateMessage`` for ``handle`` to viser's server as its connection reader does."""
    import asyncio

    from viser import _messages

    msg = _messages.GuiUpdateMessage(handle._impl.uuid, updates)
    infra = viewer.server._websock_server
    asyncio.run_coroutine_threadsafe(infra._handle_incoming_message(0, msg),
                                     infra._background_event_loop).result(timeout=10)


@needs_viser
def test_client_values_are_clamped_to_the_gui_range(viewer):
    from gof_warp.viz.viewer import MAX_SIZE, MIN_SIZE, MODES

    client = _FakeClient()
    _client_update(viewer, viewer._size, value=8)
    viewer._render_for(client)
    assert max(client.images[-1].shape[:2]) == MIN_SIZE, "an 8 px render size is raised to the slider's minimum"
    assert viewer.render_settings()[1] == MIN_SIZE
    _client_update(viewer, viewer._size, max=10**9, value=10**8)  # the client widens the slider first
    assert viewer.render_settings()[1] == MAX_SIZE, "a huge size is lowered to the slider's declared maximum"
    _client_update(viewer, viewer._slice, value=-5.0)
    assert viewer.render_settings()[2] == pytest.approx(0.01)
    _client_update(viewer, viewer._slice, value=float("inf"))
    assert 0.01 <= viewer.render_settings()[2] <= viewer._slice_range[1]
    _client_update(viewer, viewer._mode, value="rm -rf /")
    assert viewer.render_settings()[0] in MODES
    assert viewer._size._impl.props.max == MAX_SIZE, "a client changes values only, not the declared range"
    viewer._settings_changed()  # what viser calls for a connected browser's update: write the clamped values back
    assert viewer._size.value == MAX_SIZE and viewer._mode.value in MODES
    _client_update(viewer, viewer._size, value=64)
    _client_update(viewer, viewer._mode, value="render")


# ------------------------------------------------------------------------------------------ the screenshot browser
def test_chromium_keeps_its_sandbox_unless_running_as_root(monkeypatch, caplog, tmp_path):
    from gof_warp.cli import view
    from gof_warp.core.errors import GofError

    launched = []

    class Launched(Exception):
        pass

    def popen(argv, **_):  # the command line the screenshot would start Chromium with
        launched.append(list(argv))
        raise Launched

    monkeypatch.setattr(view.subprocess, "Popen", popen)
    monkeypatch.delenv("GOF_WARP_CHROMIUM_NO_SANDBOX", raising=False)
    for uid in (1000, 0):
        monkeypatch.setattr(view.os, "geteuid", lambda uid=uid: uid)
        with caplog.at_level(logging.INFO), pytest.raises((Launched, GofError)):
            view.screenshot("http://127.0.0.1:9/", tmp_path / "x.png", chromium="/bin/true")
    as_user, as_root = launched
    assert "--headless" in as_user and "--no-sandbox" not in as_user, "a normal user keeps Chromium's sandbox"
    assert "--no-sandbox" in as_root, "root: Chromium refuses to start with its sandbox"
    assert "root" in caplog.text, "why the sandbox is off is logged"
