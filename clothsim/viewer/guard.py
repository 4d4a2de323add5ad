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
  counted before viser buffers it, and a refused transfer, one whose connection closed or one
  idle past its timeout (a check scheduled on viser's event loop) is removed from viser's private
  ``GuiApi._current_file_upload_states`` (which frees its parts). The limits are per transfer and,
  as a byte budget, for all tabs' transfers together.
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
import time
import types
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


def release_memory() -> None:
    """Give freed heap memory back to the system (glibc's ``malloc_trim``; nothing elsewhere).
    Upload parts are 512 kB buffers: once freed, glibc keeps them in its arenas, so 40 abandoned
    19 MB uploads kept the server about 780 MB larger after they were dropped."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


class UploadGuard:
    """Uploads are limited by the bytes actually received, per transfer and for the whole server:

    - a transfer is refused when it is announced larger than ``limit``, with more parts than its
      size needs, or when its announced size added to the sizes of every transfer in flight (from
      any tab) would pass ``budget`` (default: ``limit``), so that many tabs cannot hold many
      uploads at once;
    - a part is refused (and its transfer dropped) when it would take the transfer past its
      announced size or the limit, or the bytes buffered for all transfers past the budget;
    - an abandoned transfer is dropped: at once when its tab closes, and when no part arrived
      for ``idle_timeout`` seconds (checked every few seconds on viser's event loop).

    A dropped transfer's buffered parts are freed at once and the memory returned to the system
    (:func:`release_memory`)."""

    def __init__(self, server, limit: int, refuse: Callable[[int, object, str, str], None],
                 budget: int | None = None, idle_timeout: float = 60.0):
        from viser import _messages

        self.server = server
        self.limit = limit
        self.budget = limit if budget is None else budget
        self.idle_timeout = idle_timeout
        self.refuse = refuse  # refuse(client_id, message, filename, reason): report it
        self.activity: dict[str, float] = {}  # transfer uuid -> time of its last message
        self.sources: dict[str, str] = {}  # transfer uuid -> its upload button's uuid
        self.expired = 0  # transfers dropped for lack of progress
        ws = server._websock_server
        ws.register_handler(_messages.FileTransferStartUpload, self.on_start)
        _first_handler(ws, _messages.FileTransferPart, self.on_part)
        # viser drops a closed tab's uploads only for tabs that sent a camera message (its
        # "connected" clients); a script never does: drop them for every closed connection
        ws.on_client_disconnect(self.on_disconnect)
        loop = getattr(ws, "_background_event_loop", None)
        if loop is not None:
            loop.call_soon_threadsafe(self._tick)

    def _tick(self) -> None:
        """(viser's event loop) Drop stalled transfers, then check again in a few seconds."""
        try:
            self.expire()
        finally:
            loop = getattr(self.server._websock_server, "_background_event_loop", None)
            if loop is not None and not loop.is_closed():
                loop.call_later(min(5.0, max(0.05, self.idle_timeout / 4)), self._tick)

    def expire(self, now: float | None = None) -> int:
        """Drop every transfer with no message for ``idle_timeout`` seconds; returns how many."""
        now = time.monotonic() if now is None else now
        stale = [u for u in list(self.states) if now - self.activity.setdefault(u, now) > self.idle_timeout]
        for u in stale:
            state = self.states.pop(u, None)
            self.activity.pop(u, None)
            if state is not None:
                self.expired += 1
                what = types.SimpleNamespace(transfer_uuid=u, source_component_uuid=self.sources.get(u))
                self.refuse(state.get("client_id"), what, str(state.get("filename", "upload")),
                            f"no data for {self.idle_timeout:.0f} s: the upload was abandoned and dropped")
        for u in [u for u in list(self.activity) if u not in self.states]:  # finished or dropped by viser
            self.activity.pop(u, None)
        for u in [u for u in list(self.sources) if u not in self.states]:
            self.sources.pop(u, None)
        if stale:
            release_memory()
        return len(stale)

    def on_disconnect(self, conn) -> None:
        dropped = [u for u, s in list(self.states.items()) if s.get("client_id") == conn.client_id]
        for uuid in dropped:
            self.states.pop(uuid, None)
            self.activity.pop(uuid, None)
        if dropped:
            release_memory()

    @property
    def states(self) -> dict:
        return self.server.gui._current_file_upload_states

    def buffered_bytes(self, client_id=None) -> int:
        """Bytes held for uploads in flight (of one tab, or of all)."""
        return sum(len(p) for s in list(self.states.values())
                   if client_id is None or s["client_id"] == client_id for p in list(s["parts"].values()))

    def announced_bytes(self, skip: str | None = None) -> int:
        """Sizes announced by the transfers in flight (all tabs), but ``skip``'s."""
        return sum(int(s.get("total_bytes") or 0) for u, s in list(self.states.items()) if u != skip)

    def _drop(self, client_id, message, reason: str) -> None:
        state = self.states.pop(message.transfer_uuid, None) or {}
        self.activity.pop(message.transfer_uuid, None)
        release_memory()
        self.refuse(client_id, message, str(state.get("filename", "upload")), reason)

    def on_start(self, client_id, message) -> None:
        """After viser recorded the transfer: refuse it if its announced size is over the limit,
        its part count does not match that size, or the server's budget for uploads in flight
        has no room for it."""
        if message.transfer_uuid not in self.states:
            return
        self.activity[message.transfer_uuid] = time.monotonic()
        self.sources[message.transfer_uuid] = message.source_component_uuid
        size, parts = message.size_bytes, message.part_count
        others = self.announced_bytes(skip=message.transfer_uuid)
        if size > self.limit:
            self._drop(client_id, message, f"{size / 2**20:.1f} MB is over the upload limit of "
                                           f"{self.limit / 2**20:.0f} MB (--upload-limit-mb)")
        elif size < 0 or parts != -(-size // UPLOAD_CHUNK):
            self._drop(client_id, message, f"{parts} parts do not match the announced {size} bytes")
        elif size + others > self.budget:
            self._drop(client_id, message, f"the server is receiving other uploads ({others / 2**20:.0f} MB "
                                           f"in flight, {self.budget / 2**20:.0f} MB at most at once): "
                                           f"try again when they are done")
        self.expire()

    def on_part(self, client_id, message) -> None:
        """Before viser buffers a part: refuse the transfer if the part would take it past its
        announced size, the part size or the limit, or all uploads past the budget."""
        state = self.states.get(message.transfer_uuid)
        if state is None:
            return
        self.activity[message.transfer_uuid] = time.monotonic()
        n = len(message.content)
        got = state["transferred_bytes"] + n
        held = self.buffered_bytes() + n
        if n > UPLOAD_CHUNK or got > state["total_bytes"] or got > self.limit or held > self.budget:
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
