"""``egovid serve``: the archive in a browser."""

from __future__ import annotations

from pathlib import Path

import typer

from egovid.cli.common import console, err_console


def serve(
    archive: Path = typer.Argument(
        ..., help="Archive folder (from `egovid dashcam init`; SQLite or PostgreSQL, local or S3)."
    ),
    host: str = typer.Option(
        "127.0.0.1",
        "--host",
        help="Address to listen on. Only this machine can reach the default; any other address (0.0.0.0, a LAN "
        "address) needs the access token on every request.",
    ),
    port: int = typer.Option(8642, "--port", help="Port to listen on (0: any free port)."),
    token: str = typer.Option(
        None,
        "--token",
        help="Access token, 16 characters or more. Changes (lock, unlock, forget) always need it (the page sends "
        "it); with a --host other than 127.0.0.1, ::1 or localhost every request does. Default: a random one, printed "
        "in the address.",
    ),
    read_only: bool = typer.Option(
        False,
        "--read-only",
        help="Look, play, find and clip, but change nothing: the page shows no lock, unlock or forget and the API "
        "refuses them (404).",
    ),
    fpv: list[Path] = typer.Option(
        [], "--fpv", help="A folder with stabiliser reports (fpv stabilize --report) to open too; repeatable."
    ),
    voeval: list[Path] = typer.Option(
        [], "--voeval", help="A voeval run folder (its report.html) to open too; repeatable."
    ),
    tiles: str = typer.Option(
        "osm",
        "--tiles",
        help="Background map: osm (OpenStreetMap, fetched by the browser only when online), none, or an XYZ URL "
        "https://…/{z}/{x}/{y}.png. The tracks show on a plain projection without it.",
    ),
    cache_mb: int = typer.Option(256, "--cache-mb", help="MiB of encoded video kept for the viewers (16-65536)."),
    max_height: int = typer.Option(
        0,
        "--max-height",
        min=0,
        max=4320,
        help="Stream taller drives scaled down to this many pixels (0: as recorded).",
    ),
) -> None:
    """Open the archive in a web browser: the drives on a map and a timeline, a list with filters,
    playback (a marker with the speed follows on the map), find by drawing on the map, incident
    clips to download, lock/unlock and forget.

    Prints the address to open (`serving http://...`) and serves until Ctrl-C. Video is produced on
    the fly as H.264 in fragmented MP4 (any current Chrome, Edge, Firefox or Safari plays it);
    nothing is fetched from the network but the map tiles, by the browser, when online.

    **Access.** On 127.0.0.1 (the default) only this machine can connect and reads need no token.
    Any other `--host` (0.0.0.0, a LAN address) needs the access token on every request: `--token`,
    or a random one printed in the address (`?token=...`; opening it once sets a cookie). Changes
    are POST requests with the token, never links; `--read-only` removes them.

    **Examples**

    * `egovid serve fleet/` : http://127.0.0.1:8642/, this machine only
    * `egovid serve fleet/ --port 0` : any free port (printed)
    * `egovid serve fleet/ --host 0.0.0.0 --read-only` : the LAN, a printed token, nothing can be changed
    * `egovid serve fleet/ --host 0.0.0.0 --token "$EGOVID_TOKEN"` : a token of your own
    * `egovid serve fleet/ --voeval vo-run/ --tiles none` : a voeval report too; no background map

    More in docs/serve.md.
    """
    from egovid.cli.validate import input_folder
    from egovid.dashcam.mapdata import tile_url
    from egovid.serve.server import ServeConfig
    from egovid.serve.server import serve as run_server

    input_folder(archive, "archive folder")
    config = ServeConfig(
        archive=archive,
        host=host,
        port=port,
        token=token,
        read_only=read_only,
        reports=[("fpv", p) for p in fpv] + [("voeval", p) for p in voeval],
        tiles=tile_url(tiles),
        cache_mb=cache_mb,
        max_height=max_height,
    )
    run_server(config, say=lambda line: (console if line.startswith("serving") else err_console).print(
        line, highlight=False, soft_wrap=True))  # fmt: skip
