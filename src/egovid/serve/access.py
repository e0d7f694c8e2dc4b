"""Who may use the web app, and how (an ASGI middleware in front of every route).

* **Bound to loopback** (127.0.0.1, ::1, localhost: the default): pages and reads need no token,
  but the ``Host`` header must name the loopback address and port (so a web page on another site
  cannot reach the server by DNS rebinding).
* **Any other address**: every request needs the access token: the ``X-Egovid-Token`` header,
  or the cookie that opening ``/?token=TOKEN`` sets (HttpOnly, SameSite=Strict) before it
  redirects to ``/`` (so the token does not stay in the address bar or the history). Without it:
  401.
* **Changes** (lock, unlock, forget, clips) are POST requests only, and always need the token in
  the ``X-Egovid-Token`` header: a cookie alone never suffices, so no link, form or image on
  another site can make a change (a cross-site request cannot set that header without a CORS
  preflight, which this server never answers). A POST whose ``Origin`` is not this server is
  refused too.
* Every answer carries a Content-Security-Policy that allows nothing from elsewhere but the
  configured map tiles, ``nosniff``, no framing and no referrer.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from http.cookies import SimpleCookie
from urllib.parse import parse_qs, urlsplit

TOKEN_HEADER = "x-egovid-token"
COOKIE = "egovid_token"
SAFE_METHODS = frozenset({"GET", "HEAD"})


def new_token() -> str:
    """A random access token (URL-safe, 192 bits)."""
    return secrets.token_urlsafe(24)


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and ``localhost``."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True)
class AccessPolicy:
    """``host``/``port``: where the server listens; ``token``: the access token; ``tiles_origin``:
    the origin map tiles come from (``https://tile.openstreetmap.org``), or None."""

    host: str
    port: int
    token: str
    tiles_origin: str | None = None

    @property
    def token_for_reads(self) -> bool:
        """Reads need the token too (the server listens beyond the exact loopback addresses)."""
        return self.host not in ("127.0.0.1", "::1", "localhost")

    def host_allowed(self, header: str) -> bool:
        """A ``Host`` header the server answers (only checked when it listens on loopback)."""
        if self.token_for_reads:
            return True
        names = {f"127.0.0.1:{self.port}", f"localhost:{self.port}", f"[::1]:{self.port}"}
        return header.lower() in names

    def token_ok(self, given: str | None) -> bool:
        return bool(given) and hmac.compare_digest(given.encode(), self.token.encode())

    def csp(self, report: bool = False) -> str:
        """The Content-Security-Policy of an answer (``report``: a stabiliser or voeval report,
        which may carry inline styles and scripts of its own)."""
        img = "'self' data: blob:" + (f" {self.tiles_origin}" if self.tiles_origin else "")
        if report:
            return (f"default-src 'self'; img-src {img}; style-src 'self' 'unsafe-inline'; "
                    "script-src 'self' 'unsafe-inline'; connect-src 'self'; frame-ancestors 'self'")  # fmt: skip
        return (f"default-src 'self'; img-src {img}; media-src 'self' blob:; style-src 'self' 'unsafe-inline'; "
                "script-src 'self'; connect-src 'self'; object-src 'none'; base-uri 'none'; "
                "form-action 'none'; frame-ancestors 'none'")  # fmt: skip


Scope = dict
Receive = Callable[[], Awaitable[dict]]
Send = Callable[[dict], Awaitable[None]]


class AccessMiddleware:
    """Applies an :class:`AccessPolicy` to every HTTP request (see the module docstring)."""

    def __init__(self, app, policy: AccessPolicy) -> None:
        self.app, self.policy = app, policy

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        pol = self.policy
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        method = scope["method"].upper()
        if not pol.host_allowed(headers.get("host", "")):
            await _plain(send, 421, "this server answers only to its own address (open the address egovid printed)")
            return
        cookie = SimpleCookie()
        try:
            cookie.load(headers.get("cookie", ""))
        except Exception:
            cookie = SimpleCookie()
        from_cookie = cookie[COOKIE].value if COOKIE in cookie else None
        from_header = headers.get(TOKEN_HEADER)
        if method in SAFE_METHODS and scope["path"] == "/":
            given = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [None])[0]
            if given is not None:
                if not pol.token_ok(given):
                    await _plain(send, 401, "wrong access token: open the address egovid serve printed")
                    return
                await _redirect_with_cookie(send, pol.token)
                return
        authorised = pol.token_ok(from_header) or pol.token_ok(from_cookie)
        if method not in SAFE_METHODS:
            origin = headers.get("origin")
            if origin is not None and urlsplit(origin).netloc.lower() != headers.get("host", "").lower():
                await _plain(send, 403, "a change must come from this server's own page")
                return
            if not pol.token_ok(from_header):
                await _plain(send, 403, "a change needs the access token in the X-Egovid-Token header")
                return
        elif pol.token_for_reads and not authorised:
            await _plain(send, 401, "this server needs its access token: open the address egovid serve printed")
            return
        report = scope["path"].startswith("/reports/")

        async def send_with_headers(message: dict) -> None:
            if message["type"] == "http.response.start":
                extra = [
                    (b"content-security-policy", pol.csp(report).encode()),
                    (b"x-content-type-options", b"nosniff"),
                    (b"referrer-policy", b"no-referrer"),
                    (b"x-frame-options", b"SAMEORIGIN" if report else b"DENY"),
                    (b"cross-origin-resource-policy", b"same-origin"),
                ]
                message = {**message, "headers": [*message.get("headers", []), *extra]}
            await send(message)

        await self.app(scope, receive, send_with_headers)


async def _plain(send: Send, status: int, text: str) -> None:
    body = (text + "\n").encode()
    headers = [
        (b"content-type", b"text/plain; charset=utf-8"),
        (b"content-length", str(len(body)).encode()),
        (b"x-content-type-options", b"nosniff"),
    ]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})


async def _redirect_with_cookie(send: Send, token: str) -> None:
    cookie = f"{COOKIE}={token}; HttpOnly; SameSite=Strict; Path=/"
    await send({"type": "http.response.start", "status": 303,
                "headers": [(b"location", b"/"), (b"set-cookie", cookie.encode()), (b"content-length", b"0"),
                            (b"cache-control", b"no-store")]})  # fmt: skip
    await send({"type": "http.response.body", "body": b""})
