"""``egovid serve``: the archive in a browser (map, timeline, list, playback, find, clip, lock, forget).

Rooms: :mod:`~egovid.serve.archive_ops` is the one module that calls the dashcam library;
:mod:`~egovid.serve.fragments` encodes decoded frames as fragmented MP4 (H.264) chunks;
:mod:`~egovid.serve.streams` produces those chunks on demand with a bounded cache;
:mod:`~egovid.serve.access` is the access policy (token, host, POST-only changes);
:mod:`~egovid.serve.app` the web app (Starlette) and :mod:`~egovid.serve.server` runs it (uvicorn).
"""
