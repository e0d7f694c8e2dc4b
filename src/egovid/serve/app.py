"""The web app (Starlette): the page, its JSON API, the streams and the report folders.

Routes (``{id}``: a drive's catalogue id; every change is a POST, see :mod:`egovid.serve.access`):

=========================================  ==========================================================
``GET /``                                  the page (static files from ``egovid/data/serve``)
``GET /api/info``                          archive name, read-only, token for changes, tiles, reports
``GET /api/drives``                        every drive: kind, lock, start, length, storage, saving,
                                           paths, its track for the map; the archive's totals
``GET /api/drives/{id}/track``             GPS fixes on the video clock with speed and acceleration
``GET /api/drives/{id}/stream``            the stream's manifest (fps, size, chunk length)
``GET /api/drives/{id}/chunks/{k}.mp4``    chunk k, fragmented MP4 (H.264), produced on the fly
                                           (``?v=VIEWER``: the page's id; see StreamService.chunk)
``GET /api/find``                          ``near=LAT,LON&radius=M``, ``bbox=W,S,E,N``, ``from``/``to``
``POST /api/clips``                        ``{drive, t, before, after}`` → the clip's download links
``GET /api/clips/{clip}/{file}``           the clip (.mp4) or its GPS track (.gpx), as attachments
``POST /api/drives/{id}/lock``, ``unlock`` ``{note}``
``POST /api/forget/preview``, ``/forget``  ``{drives: [id, ...]}``: what would change, then do it
``GET /reports/{fpv|voeval}/{n}/...``      the report folders given to ``egovid serve``
=========================================  ==========================================================

With ``read_only`` the change routes do not exist (404) and the page shows no change control.
Archive work runs in worker threads; an error is a JSON answer ``{"error": "problem; fix"}`` with
a 4xx status for bad input, 500 for a failure, and never stops the server.
"""

from __future__ import annotations

import contextlib
import re
import shutil
import tempfile
import threading
import uuid
from collections import OrderedDict
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from urllib.parse import urlsplit

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from egovid.core.errors import EgovidError, user_error
from egovid.core.times import iso_to_utc
from egovid.serve.access import AccessMiddleware, AccessPolicy, new_token
from egovid.serve.archive_ops import ArchiveOps, DriveNotFoundError
from egovid.serve.fragments import EncodeSettings, mime_codec
from egovid.serve.streams import StreamError, StreamService

CLIP_FILE = re.compile(r"^clip\.(mp4|gpx)$")
CLIP_ID = re.compile(r"^[0-9a-f]{32}$")


@dataclass
class ServeConfig:
    """How to serve an archive: ``archive`` folder; ``host``/``port`` to listen on; ``token``
    (None: generated); ``read_only``; ``reports``: (kind, folder) pairs, kind ``fpv`` or ``voeval``;
    ``tiles``: an XYZ tile URL the browser may fetch when online, or None; stream settings:
    ``cache_mb`` (encoded chunks kept), ``crf``, ``max_height`` (0: the drive's own size),
    ``producers`` (streams produced at once)."""

    archive: Path
    host: str = "127.0.0.1"
    port: int = 8642
    token: str | None = None
    read_only: bool = False
    reports: list[tuple[str, Path]] = field(default_factory=list)
    tiles: str | None = None
    cache_mb: int = 256
    crf: int = 26
    max_height: int = 0
    producers: int = 6


class ClipStore:
    """Clips made for download, in a temporary folder of the server's own (removed on close); at
    most ``keep`` clips, the oldest removed first. Clips are named by random ids, never by paths."""

    def __init__(self, keep: int = 8) -> None:
        self.root = Path(tempfile.mkdtemp(prefix="egovid-serve-clips-"))
        self.keep = keep
        self._clips: OrderedDict[str, Path] = OrderedDict()
        self._lock = threading.Lock()

    def new(self) -> tuple[str, Path]:
        cid = uuid.uuid4().hex
        folder = self.root / cid
        folder.mkdir()
        with self._lock:
            self._clips[cid] = folder
            while len(self._clips) > self.keep:
                _, old = self._clips.popitem(last=False)
                shutil.rmtree(old, ignore_errors=True)
        return cid, folder

    def file(self, cid: str, name: str) -> Path | None:
        if not CLIP_ID.match(cid) or not CLIP_FILE.match(name):
            return None
        with self._lock:
            folder = self._clips.get(cid)
        path = folder / name if folder is not None else None
        return path if path is not None and path.is_file() else None

    def close(self) -> None:
        shutil.rmtree(self.root, ignore_errors=True)


def report_pages(folder: Path, limit: int = 50) -> list[str]:
    """The HTML pages of a report folder (relative paths, at most two levels deep)."""
    pages = sorted(p.relative_to(folder).as_posix() for p in [*folder.glob("*.html"), *folder.glob("*/*.html")])
    return pages[:limit]


def _error(exc: BaseException) -> JSONResponse:
    if isinstance(exc, DriveNotFoundError):
        return JSONResponse({"error": exc.one_line()}, status_code=404)
    if isinstance(exc, StreamError):
        return JSONResponse({"error": str(exc)}, status_code=exc.status)
    found = user_error(exc)
    if found is not None:
        return JSONResponse({"error": found.one_line()}, status_code=400)
    return JSONResponse({"error": f"internal error: {type(exc).__name__}: {exc}"}, status_code=500)


async def _json_body(request: Request) -> dict:
    try:
        body = await request.json()
    except (ValueError, UnicodeDecodeError):
        raise EgovidError("the request body is not JSON", "send a JSON object") from None
    if not isinstance(body, dict):
        raise EgovidError("the request body is not a JSON object", "send a JSON object")
    return body


def _number(body: dict, key: str, default: float | None = None, lo: float = 0.0, hi: float = 1e12) -> float:
    v = body.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not lo <= v <= hi:
        raise EgovidError(f"{key} {v!r} is not a number in {lo:g}-{hi:g}", f"give {key} as a number")
    return float(v)


def _floats(text: str | None, n: int, name: str) -> tuple[float, ...] | None:
    if text is None or text == "":
        return None
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != n:
        raise EgovidError(f"{name} {text!r} is not {n} comma-separated numbers", f"write {name} as {n} numbers")
    return vals


def _utc(text: str | None, name: str) -> float | None:
    """A query's ISO 8601 time (no zone = UTC) → UTC seconds; None when not given."""
    if text is None or text == "":
        return None
    try:
        return iso_to_utc(text)
    except ValueError:
        raise EgovidError(f"{name} {text!r} is not an ISO 8601 time", "write e.g. 2026-05-04T08:00:00Z") from None


class _Api:
    """The JSON API's handlers over one archive's operations, streams and clips (one job: turn a
    request into a library call and its answer into a response)."""

    def __init__(self, config: ServeConfig, ops: ArchiveOps, streams: StreamService, clips: ClipStore, token: str):
        self.config, self.ops, self.streams, self.clips, self.token = config, ops, streams, clips, token
        self.reports = [(kind, Path(folder).resolve()) for kind, folder in config.reports]

    @staticmethod
    async def call(fn, *args, **kwargs):
        try:
            return await run_in_threadpool(fn, *args, **kwargs)
        except Exception as exc:
            return _error(exc)

    @staticmethod
    def respond(result, status: int = 200) -> Response:
        return result if isinstance(result, Response) else JSONResponse(result, status_code=status)

    @staticmethod
    def drive_id(request: Request) -> int:
        return int(request.path_params["id"])

    async def info(self, request: Request) -> Response:
        listed = []
        for kind in ("fpv", "voeval"):
            for n, (_, folder) in enumerate([r for r in self.reports if r[0] == kind]):
                listed.append({"kind": kind, "name": folder.name, "base": f"/reports/{kind}/{n}/",
                               "pages": report_pages(folder)})  # fmt: skip
        c = self.config
        return JSONResponse({"archive": c.archive.resolve().name, "read_only": c.read_only, "token": self.token,
                             "tiles": c.tiles, "reports": listed})  # fmt: skip

    async def drives(self, request: Request) -> Response:
        return self.respond(await self.call(self.ops.overview))

    async def track(self, request: Request) -> Response:
        return self.respond(await self.call(self.ops.track, self.drive_id(request)))

    async def manifest(self, request: Request) -> Response:
        return self.respond(await self.call(self.streams.manifest, self.drive_id(request)))

    async def chunk(self, request: Request) -> Response:
        viewer = request.query_params.get("v", "")[:64]
        k = int(request.path_params["k"])
        got = await self.call(self.streams.chunk, self.drive_id(request), k, viewer=viewer)
        if isinstance(got, Response):
            return got
        return Response(got, media_type="video/mp4", headers={"x-egovid-codec": mime_codec(got),
                                                              "cache-control": "private, max-age=600"})  # fmt: skip

    async def find(self, request: Request) -> Response:
        q = request.query_params

        def run():
            return self.ops.find(
                near=_floats(q.get("near"), 2, "near"),
                radius=float(q.get("radius") or 50.0),
                bbox=_floats(q.get("bbox"), 4, "bbox"),
                t_from=_utc(q.get("from"), "from"),
                t_to=_utc(q.get("to"), "to"),
            )

        return self.respond(await self.call(run))

    async def make_clip(self, request: Request) -> Response:
        try:
            body = await _json_body(request)
            did = int(_number(body, "drive", hi=2**62))
            t = _number(body, "t", hi=1e7)
            before = _number(body, "before", 10.0, hi=3600)
            after = _number(body, "after", 10.0, hi=3600)
        except EgovidError as exc:
            return _error(exc)
        cid, folder = self.clips.new()
        got = await self.call(self.ops.clip, did, t, before, after, folder / "clip.mp4")
        if isinstance(got, Response):
            return got
        links = {"video": f"/api/clips/{cid}/clip.mp4", "gpx": f"/api/clips/{cid}/clip.gpx" if got["gpx"] else None}
        return JSONResponse({**{k: v for k, v in got.items() if k not in ("video", "gpx")}, **links, "id": cid})

    async def clip_file(self, request: Request) -> Response:
        path = self.clips.file(request.path_params["clip"], request.path_params["file"])
        if path is None:
            return JSONResponse({"error": "no such clip; make it again"}, status_code=404)
        kind = "video/mp4" if path.suffix == ".mp4" else "application/gpx+xml"
        return FileResponse(path, media_type=kind, filename=f"{request.path_params['clip'][:8]}-{path.name}")

    async def lock(self, request: Request) -> Response:
        try:
            body = await _json_body(request)
        except EgovidError as exc:
            return _error(exc)
        note = body.get("note")
        if note is not None and (not isinstance(note, str) or len(note) > 500):
            return JSONResponse({"error": "note must be text of at most 500 characters"}, status_code=400)
        return self.respond(await self.call(self.ops.set_lock, self.drive_id(request), True, note or None))

    async def unlock(self, request: Request) -> Response:
        return self.respond(await self.call(self.ops.set_lock, self.drive_id(request), False, None))

    @staticmethod
    async def _forget_ids(request: Request) -> list[int]:
        body = await _json_body(request)
        ids = body.get("drives")
        if not isinstance(ids, list) or not ids or not all(isinstance(i, int) and not isinstance(i, bool) for i in ids):
            raise EgovidError("drives must be a list of drive ids", 'send {"drives": [ID, ...]}')
        return ids

    async def forget_preview(self, request: Request) -> Response:
        try:
            ids = await self._forget_ids(request)
        except EgovidError as exc:
            return _error(exc)
        return self.respond(await self.call(self.ops.forget, ids, dry_run=True))

    async def forget(self, request: Request) -> Response:
        try:
            ids = await self._forget_ids(request)
        except EgovidError as exc:
            return _error(exc)
        got = await self.call(self.ops.forget, ids, dry_run=False)
        if not isinstance(got, Response):
            self.streams.invalidate()  # trimmed or deleted segments: every cached chunk is suspect
        return self.respond(got)

    def routes(self) -> list:
        """Every route of the app: the page, the API (the changes only when not read-only), the
        static files and the report folders."""
        data = resources.files("egovid.data")
        index = str(data / "serve" / "index.html")
        routes = [
            Route("/", lambda r: FileResponse(index, headers={"cache-control": "no-store"})),
            Route("/favicon.ico", lambda r: Response(status_code=204)),
            Route("/api/info", self.info),
            Route("/api/drives", self.drives),
            Route("/api/drives/{id:int}/track", self.track),
            Route("/api/drives/{id:int}/stream", self.manifest),
            Route("/api/drives/{id:int}/chunks/{k:int}.mp4", self.chunk),
            Route("/api/find", self.find),
            Route("/api/clips", self.make_clip, methods=["POST"]),
            Route("/api/clips/{clip}/{file}", self.clip_file),
        ]
        if not self.config.read_only:
            routes += [
                Route("/api/drives/{id:int}/lock", self.lock, methods=["POST"]),
                Route("/api/drives/{id:int}/unlock", self.unlock, methods=["POST"]),
                Route("/api/forget/preview", self.forget_preview, methods=["POST"]),
                Route("/api/forget", self.forget, methods=["POST"]),
            ]
        routes += [
            Mount("/static/leaflet", app=StaticFiles(directory=str(data / "leaflet"))),
            Mount("/static", app=StaticFiles(directory=str(data / "serve"))),
        ]
        kinds: dict[str, int] = {}
        for kind, folder in self.reports:
            n = kinds.get(kind, 0)
            kinds[kind] = n + 1
            routes.append(Mount(f"/reports/{kind}/{n}", app=StaticFiles(directory=str(folder), html=True)))
        return routes


async def _not_found(request: Request, exc: HTTPException) -> Response:
    return JSONResponse({"error": exc.detail}, status_code=exc.status_code)


def _tiles_origin(tiles: str | None) -> str | None:
    """The origin the page may load map tiles from (``{s}`` subdomains as a wildcard), for the
    content security policy; None without tiles."""
    if not tiles:
        return None
    u = urlsplit(tiles.replace("{s}", "a"))
    if u.scheme not in ("http", "https"):
        return None
    return f"{u.scheme}://*.{u.netloc.split('.', 1)[-1]}" if "{s}" in tiles else f"{u.scheme}://{u.netloc}"


def create_app(config: ServeConfig, ops: ArchiveOps | None = None) -> Starlette:
    """The web app for ``config`` (``ops``: an already open archive). Its state (archive, streams,
    clips) is closed when the app shuts down."""
    ops = ops or ArchiveOps(config.archive)
    streams = StreamService(
        ops.stream_source,
        settings=EncodeSettings(crf=config.crf, max_height=config.max_height),
        cache_bytes=config.cache_mb * 2**20,
        max_producers=config.producers,
    )
    clips = ClipStore()
    token = config.token or new_token()
    policy = AccessPolicy(config.host, config.port, token, _tiles_origin(config.tiles))
    api = _Api(config, ops, streams, clips, token)

    @contextlib.asynccontextmanager
    async def lifespan(app):
        try:
            yield
        finally:
            await run_in_threadpool(streams.close)
            clips.close()
            ops.close()

    app = Starlette(routes=api.routes(), exception_handlers={HTTPException: _not_found}, lifespan=lifespan)
    app.state.streams, app.state.ops, app.state.clips = streams, ops, clips
    app.add_middleware(AccessMiddleware, policy=policy)
    return app
