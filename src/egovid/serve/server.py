"""Running the web app: check the configuration, bind the socket, print the address, serve (uvicorn)
until interrupted."""

from __future__ import annotations

import errno
import socket
from collections.abc import Callable
from pathlib import Path
from urllib.parse import urlsplit

from egovid.core.errors import EgovidError
from egovid.serve.access import is_loopback, new_token
from egovid.serve.app import ServeConfig, create_app
from egovid.serve.archive_ops import ArchiveOps

KINDS = ("fpv", "voeval")


def check_config(config: ServeConfig) -> ServeConfig:
    """The configuration made whole (a token generated where none was given), or
    :class:`EgovidError` naming what is wrong; nothing is opened or bound yet."""
    if not 0 <= config.port <= 65535:
        raise EgovidError(f"--port {config.port} is not a port", "give 1-65535, or 0 for any free port")
    if config.token is not None and len(config.token) < 16:
        raise EgovidError("--token is shorter than 16 characters", "give a longer token, or leave it out to get one")
    if not (16 <= config.cache_mb <= 65536):
        raise EgovidError(f"--cache-mb {config.cache_mb} is not usable", "give 16-65536 MiB")
    if config.tiles is not None and not tiles_ok(config.tiles):
        raise EgovidError(
            f"--tiles {config.tiles} is not osm, none or a tile URL",
            "give e.g. https://tile.openstreetmap.org/{z}/{x}/{y}.png",
        )
    for kind, folder in config.reports:
        if kind not in KINDS:
            raise EgovidError(f"report kind {kind!r} is unknown", "use --fpv DIR or --voeval DIR")
        if not Path(folder).is_dir():
            raise EgovidError(f"report folder {folder} does not exist", f"give the folder the {kind} report is in")
    token = config.token or new_token()
    return ServeConfig(**{**config.__dict__, "token": token})


def tiles_ok(url: str) -> bool:
    """True for an XYZ tile URL the browser can fetch: http(s), a host, and {z}, {x} and {y}."""
    u = urlsplit(url.replace("{s}", "a"))
    return u.scheme in ("http", "https") and bool(u.netloc) and all(k in url for k in ("{z}", "{x}", "{y}"))


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host``:``port`` (0: any free port); :class:`EgovidError` when
    the address is not this machine's or the port is taken."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror:
        raise EgovidError(
            f"--host {host} is not an address of this machine", "give 127.0.0.1 or an IP address"
        ) from None
    family, _, _, _, addr = infos[0]
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(addr)
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRNOTAVAIL:
            raise EgovidError(
                f"--host {host} is not an address of this machine", "give 127.0.0.1, 0.0.0.0 or one of its addresses"
            ) from None
        fix = "a port above 1023" if exc.errno == errno.EACCES else "another --port"
        fix = f"choose {fix} (0: any free)"
        raise EgovidError(f"cannot listen on {host}:{port} ({exc.strerror})", fix) from None
    sock.listen(128)
    sock.set_inheritable(True)
    return sock


def address(config: ServeConfig, port: int) -> str:
    """The address to open: with the token in it when reads need one."""
    host = f"[{config.host}]" if ":" in config.host else config.host
    url = f"http://{host}:{port}/"
    if config.host not in ("127.0.0.1", "::1", "localhost"):
        url += f"?token={config.token}"
    return url


def serve(config: ServeConfig, say: Callable[[str], None] = print) -> None:
    """Serve the archive until interrupted (SIGINT/SIGTERM). ``say`` gets the address line first
    (``serving http://…``), then notes."""
    import uvicorn

    config = check_config(config)
    ops = ArchiveOps(config.archive)  # a bad archive is an error before anything listens
    try:
        sock = bind(config.host, config.port)
    except BaseException:
        ops.close()
        raise
    port = sock.getsockname()[1]
    config = ServeConfig(**{**config.__dict__, "port": port})
    try:
        app = create_app(config, ops)
        mode = "read-only" if config.read_only else "changes allowed (POST with the token)"
        say(f"serving {address(config, port)} ({config.archive}, {mode})")
        if not is_loopback(config.host):
            say("note: listening beyond this machine; every request needs the token in the address above")
        if config.host in ("0.0.0.0", "::"):
            say(f"note: from another machine, open it with this machine's name or address in place of {config.host}")
        server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False, lifespan="on",
                                               timeout_graceful_shutdown=3))  # fmt: skip
        server.run(sockets=[sock])
    finally:
        sock.close()
