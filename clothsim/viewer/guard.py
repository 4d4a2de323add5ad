"""What stands between the network and the viewer: the websocket handshake check (Origin, Host,
token), the upload byte count, and the check of every GUI value a browser sends.

viser 1.1 offers no public hook for any of the three, so each is attached at the narrowest point
there is, and only here:

- **Handshake.** viser builds its ``websockets.asyncio.server.serve`` inside its own thread and
  passes its static-file handler as ``process_request``. While :func:`guarded_server` constructs
  the ``ViserServer`` (and only then: the constructor returns once the port is bound), the name
  ``websockets.asyncio.server.serve`` is replaced by a wrapper that puts :class:`HandshakeCheck`
  in front of viser's ``process_request``; it is restored before the constructor returns.
  A refused handshake gets HTTP 403 before any viser state exists for it.
- **Uploads.** :class:`UploadGuard` registers handlers on viser's websocket server (public
  ``register_handler`` of ``viser.infra.WebsockServer``, reached through the private
  ``ViserServer._websock_server``); the part handler is put *before* viser's own, so a part is
  counted before viser buffers it, and a refused transfer, or one whose connection closed, is
  removed from viser's private ``GuiApi._current_file_upload_states`` (which frees its parts).
- **GUI values.** :class:`GuiValueGuard` is put before viser's own ``GuiUpdateMessage``
  handler, so a value is checked before viser stores it and broadcasts it to every tab.
"""

from __future__ import annotations

import contextlib
import hmac
import http
import math
import secrets
import threading
from typing import Callable
from urllib.parse import parse_qs, urlsplit

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")
TOKEN_COOKIE = "clothsim_token"
UPLOAD_CHUNK = 512 * 1024  # [bytes] the part size of viser's browser client
INT_MIN, INT_MAX = -(2**63), 2**64 - 1  # what msgpack can carry
TEXT_MAX = 200_000  # [characters] longest text a widget accepts


def is_loopback(host: str) -> bool:
    """True if binding ``host`` keeps the viewer on this machine."""
    return host in ("localhost", "::1") or host.startswith("127.")


def new_token() -> str:
    return secrets.token_urlsafe(24)


def _hostname(netloc: str) -> str:
    """'127.0.0.1:8080' -> '127.0.0.1', '[::1]:80' -> '::1' (lower case)."""
    try:
        return (urlsplit("//" + netloc).hostname or "").lower()
    except ValueError:
        return ""


def _cookie(headers, name: str) -> str | None:
    for line in headers.get_all("Cookie"):
        for part in line.split(";"):
            k, _, v = part.strip().partition("=")
            if k == name:
                return v
    return None


class HandshakeCheck:
    """The check in front of viser's HTTP and websocket handling.

    A websocket handshake is accepted only if its ``Origin`` is the viewer's own page, i.e. equal
    to ``http://`` + its ``Host`` header (a web page elsewhere cannot drive the viewer: browsers
    always send Origin on websockets and scripts cannot forge it); when bound to loopback, the
    Host must also be a loopback name (a DNS-rebinding page has its own name as Host); and when a
    ``token`` is set (the viewer is open to the network), the token must come either as the
    ``clothsim_token_<port>`` cookie (set when the page is opened with ``?token=...``) or as
    ``?token=...`` on the websocket URL itself. Static files (viser's client, no data) are served
    to anyone who passes the Host check."""

    def __init__(self, *, loopback: bool, token: str | None):
        self.loopback = loopback
        self.token = token
        self.port = 0  # the bound port (set once known: it names the cookie)
        self.refused = 0

    @property
    def cookie_name(self) -> str:
        return f"{TOKEN_COOKIE}_{self.port}"

    def _token_ok(self, request) -> bool:
        if self.token is None:
            return True
        given = parse_qs(urlsplit(request.path).query).get("token", [None])[0]
        if given is None:
            given = _cookie(request.headers, self.cookie_name)
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())

    def reason(self, request) -> str | None:
        """Why a request is refused, or None if it may pass."""
        host = request.headers.get("Host", "")
        if not host:
            return "no Host header"
        if self.loopback and _hostname(host) not in LOOPBACK_NAMES:
            return f"Host {host[:80]!r} is not this machine"
        if request.headers.get("Upgrade", "").lower() != "websocket":
            return None
        origin = request.headers.get("Origin")
        if origin is None:
            return "no Origin header"
        if origin.lower() not in (f"http://{host}".lower(), f"https://{host}".lower()):
            return f"Origin {origin[:80]!r} is not this viewer's page"
        if not self._token_ok(request):
            return "missing or wrong token"
        return None

    def __call__(self, inner, connection, request):
        why = self.reason(request)
        if why is not None:
            self.refused += 1
            return connection.respond(http.HTTPStatus.FORBIDDEN, f"clothsim viewer: refused: {why}\n")
        response = inner(connection, request) if inner is not None else None
        if (response is not None and self.token is not None and request.headers.get("Upgrade", "") == ""
                and self._token_ok(request) and "token=" in request.path):
            response.headers["Set-Cookie"] = f"{self.cookie_name}={self.token}; Path=/; HttpOnly; SameSite=Strict"
        return response


_PATCH_LOCK = threading.Lock()


@contextlib.contextmanager
def _serve_with(check: HandshakeCheck):
    """While active, websockets' ``serve`` puts ``check`` in front of the ``process_request`` its
    caller gives (viser's static-file handler)."""
    import websockets.asyncio.server as ws_server

    original = ws_server.serve

    def serve(*args, process_request=None, **kwargs):
        def guarded(connection, request):
            return check(process_request, connection, request)

        return original(*args, process_request=guarded, **kwargs)

    with _PATCH_LOCK:
        ws_server.serve = serve
        try:
            yield
        finally:
            ws_server.serve = original


def guarded_server(host: str, port: int, check: HandshakeCheck):
    """A ``viser.ViserServer`` whose every HTTP request and websocket handshake passes ``check``."""
    import viser

    with _serve_with(check):
        server = viser.ViserServer(host=host, port=port, verbose=False)
    check.port = server.get_port()
    return server


def _first_handler(ws_server, message_cls, fn) -> None:
    """Register fn to run before the handlers already registered for message_cls."""
    ws_server.register_handler(message_cls, fn)
    handlers = ws_server._incoming_handlers[message_cls]
    handlers.insert(0, handlers.pop())


class UploadGuard:
    """Uploads are limited by the bytes actually received: a transfer is refused when it is
    announced larger than the limit or with more parts than its size needs, and as soon as the
    bytes received for it (or for all of the same tab's transfers together) would pass its
    declared size or the limit. A refused transfer's buffered parts are dropped at once; a
    closed tab's are dropped by viser."""

    def __init__(self, server, limit: int, refuse: Callable[[int, object, str, str], None]):
        from viser import _messages

        self.server = server
        self.limit = limit
        self.refuse = refuse  # refuse(client_id, message, filename, reason): report it
        ws = server._websock_server
        ws.register_handler(_messages.FileTransferStartUpload, self.on_start)
        _first_handler(ws, _messages.FileTransferPart, self.on_part)
        # viser drops a closed tab's uploads only for tabs that sent a camera message (its
        # "connected" clients); a script never does: drop them for every closed connection
        ws.on_client_disconnect(self.on_disconnect)

    def on_disconnect(self, conn) -> None:
        for uuid in [u for u, s in list(self.states.items()) if s.get("client_id") == conn.client_id]:
            self.states.pop(uuid, None)

    @property
    def states(self) -> dict:
        return self.server.gui._current_file_upload_states

    def buffered_bytes(self, client_id=None) -> int:
        """Bytes held for uploads in flight (of one tab, or of all)."""
        return sum(len(p) for s in list(self.states.values())
                   if client_id is None or s["client_id"] == client_id for p in list(s["parts"].values()))

    def _drop(self, client_id, message, reason: str) -> None:
        state = self.states.pop(message.transfer_uuid, None) or {}
        self.refuse(client_id, message, str(state.get("filename", "upload")), reason)

    def on_start(self, client_id, message) -> None:
        """After viser recorded the transfer: refuse it if its announced size is over the limit
        or its part count does not match that size."""
        if message.transfer_uuid not in self.states:
            return
        size, parts = message.size_bytes, message.part_count
        if size > self.limit:
            self._drop(client_id, message, f"{size / 2**20:.1f} MB is over the upload limit of "
                                           f"{self.limit / 2**20:.0f} MB (--upload-limit-mb)")
        elif size < 0 or parts != -(-size // UPLOAD_CHUNK):
            self._drop(client_id, message, f"{parts} parts do not match the announced {size} bytes")

    def on_part(self, client_id, message) -> None:
        """Before viser buffers a part: refuse the transfer if the part would take it past its
        announced size, the part size or the limit."""
        state = self.states.get(message.transfer_uuid)
        if state is None:
            return
        n = len(message.content)
        got = state["transferred_bytes"] + n
        tab = self.buffered_bytes(client_id) + n
        if n > UPLOAD_CHUNK or got > state["total_bytes"] or got > self.limit or tab > self.limit:
            self._drop(client_id, message, f"received more bytes than announced or than the upload limit of "
                                           f"{self.limit / 2**20:.0f} MB")


def _int_ok(v) -> bool:
    """No int anywhere in v that msgpack cannot carry."""
    if isinstance(v, bool):
        return True
    if isinstance(v, int):
        return INT_MIN <= v <= INT_MAX
    if isinstance(v, (list, tuple)):
        return all(_int_ok(x) for x in v)
    if isinstance(v, dict):
        return all(_int_ok(x) for x in v.values())
    return True


class GuiValueGuard:
    """Every GUI value a browser sends is checked before viser stores it and broadcasts it to
    every tab: only a widget's ``value`` may be changed; numbers must be finite and within the
    widget's min and max; vectors as numbers, element by element; a dropdown's value must be one
    of its options; text is at most TEXT_MAX characters; no integer beyond what the message
    stream can carry, anywhere. A refused value is dropped and ``refused(handle, reason)`` is
    told (the viewer then shows the reason and sends the widget's last valid value back)."""

    def __init__(self, server, handles: dict[str, object], refused: Callable[[object, str], None]):
        from viser import _messages

        self.handles = handles  # uuid -> handle
        self.refused = refused
        _first_handler(server._websock_server, _messages.GuiUpdateMessage, self.on_update)

    @staticmethod
    def check(handle, value) -> str | None:
        """Why ``value`` is not acceptable for ``handle``, or None."""
        import viser

        if isinstance(handle, viser.GuiCheckboxHandle):
            return None if isinstance(value, bool) else "not a yes/no value"
        if isinstance(handle, viser.GuiDropdownHandle):
            return None if isinstance(value, str) and value in handle.options else "not one of the choices"
        if isinstance(handle, viser.GuiTextHandle):
            if not isinstance(value, str):
                return "not text"
            return None if len(value) <= TEXT_MAX else f"longer than {TEXT_MAX} characters"
        if isinstance(handle, (viser.GuiNumberHandle, viser.GuiSliderHandle)):
            vals, lo, hi = [value], [handle.min], [handle.max]
        elif isinstance(handle, (viser.GuiVector2Handle, viser.GuiVector3Handle)):
            k = len(handle.value)
            if not isinstance(value, (list, tuple)) or len(value) != k:
                return f"expected {k} numbers"
            vals, lo, hi = list(value), list(handle.min or (None,) * k), list(handle.max or (None,) * k)
        else:
            return None
        for v, a, b in zip(vals, lo, hi):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                return "not a number"
            if not math.isfinite(v):
                return "not a finite number"
            a = -1e15 if a is None else a
            b = 1e15 if b is None else b
            if not a <= v <= b:
                return f"must be between {a:g} and {b:g} (got {v:g})"
        return None

    def on_update(self, client_id, message) -> None:
        handle = self.handles.get(message.uuid)
        if handle is None:
            if not _int_ok(message.updates):
                message.updates = {}
            return
        updates = message.updates
        message.updates = {}
        if "value" not in updates:
            return
        why = "value out of range" if not _int_ok(updates["value"]) else self.check(handle, updates["value"])
        if why is None:
            message.updates = {"value": updates["value"]}
        else:
            self.refused(handle, why)
