"""The archive's map: drives drawn as tracks on one self-contained HTML page.

:func:`render_map` turns map records (:class:`MapDrive`, each a list of :class:`MapStretch` in
latitude/longitude degrees) into a page that needs nothing but a browser:

* the map library (Leaflet 1.9.4, BSD-2, shipped as package data in ``egovid/data/leaflet``) and the
  track data are inlined, so the page works offline and wherever it is copied;
* background tiles are fetched only when the browser is online and a tile server is configured
  (``tiles``; None = never); without tiles (offline, server unreachable) the tracks are drawn on a
  plain Web-Mercator plane with a metric scale bar;
* where Leaflet cannot run at all (scripts off), a static SVG of the tracks in a local equirectangular
  projection (drawn here in Python) is shown instead;
* tracks are coloured by drive or by the saving of joint coding (a switch on the page); a click on a
  track shows its details.

The page sets ``data-tracks`` on ``<body>`` to the number of polylines it drew (the browser test
reads it) and ``data-tiles`` to ``online``, ``offline`` or ``none``.
"""

from __future__ import annotations

import html
import json
import math
from dataclasses import dataclass, field
from importlib import resources

import numpy as np

from egovid.dashcam.route.tracks import project

OSM_TILES = "https://tile.openstreetmap.org/{z}/{x}/{y}.png"
OSM_ATTRIBUTION = '&copy; <a href="https://www.openstreetmap.org/copyright">OpenStreetMap</a> contributors'
#: Categorical colours for drives (Tableau 10; colour-blind safe enough for a handful of drives).
DRIVE_COLOURS = (
    "#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7", "#9c755f", "#bab0ac",
)  # fmt: skip
#: Saving colour scale (viridis stops), 0 % … SAVING_FULL.
SAVING_STOPS = ("#440154", "#3b528b", "#21918c", "#5ec962", "#fde725")
SAVING_FULL = 0.5
KIND_DASH = {"event": "8 6", "parking": "2 6"}


@dataclass
class MapStretch:
    """A stretch of a drive: positions (degrees, WGS 84), the saving of joint coding on it (fraction
    of the standalone size, None for a root stretch or where it was not measured) and details shown
    on click (label → text)."""

    lat: np.ndarray
    lon: np.ndarray
    saving: float | None = None
    info: dict[str, str] = field(default_factory=dict)


@dataclass
class MapDrive:
    """A drive on the map: its name, kind (``drive``, ``event`` or ``parking``), stretches and the
    details shown on click for all of its stretches."""

    name: str
    stretches: list[MapStretch]
    kind: str = "drive"
    info: dict[str, str] = field(default_factory=dict)


def saving_colour(saving: float | None) -> str:
    """Colour of a saving (fraction) on the viridis scale from 0 to :data:`SAVING_FULL`; grey if None."""
    if saving is None or not math.isfinite(saving):
        return "#8c8c8c"
    x = min(max(saving / SAVING_FULL, 0.0), 1.0) * (len(SAVING_STOPS) - 1)
    i = min(int(x), len(SAVING_STOPS) - 2)
    f = x - i
    a, b = (tuple(int(c[k : k + 2], 16) for k in (1, 3, 5)) for c in SAVING_STOPS[i : i + 2])
    return "#" + "".join(f"{round(p + (q - p) * f):02x}" for p, q in zip(a, b, strict=True))


def _simplified(lat: np.ndarray, lon: np.ndarray, tolerance_m: float) -> np.ndarray:
    """(N, 2) lat/lon of a track simplified (Douglas-Peucker in metres) to ``tolerance_m``."""
    import shapely  # loaded only when a map is drawn

    lat, lon = np.asarray(lat, float), np.asarray(lon, float)
    ok = np.isfinite(lat) & np.isfinite(lon)
    lat, lon = lat[ok], lon[ok]
    if len(lat) < 3:
        return np.stack([lat, lon], axis=1)
    xy = project(lat, lon, (float(lat[0]), float(lon[0])))
    line = shapely.simplify(shapely.linestrings(xy), tolerance_m, preserve_topology=False)
    kept = shapely.get_coordinates(line)
    # Simplify only drops vertices: keep the original lat/lon of the ones it kept.
    where = {(float(x), float(y)): i for i, (x, y) in enumerate(xy)}
    idx = sorted({where[(float(x), float(y))] for x, y in kept})
    return np.stack([lat[idx], lon[idx]], axis=1)


def _plain_svg(drives: list[MapDrive], colour_by: str, width: int = 960, height: int = 600) -> str:
    """A static SVG of the tracks in a local equirectangular projection (north up), with a scale bar."""
    pts = [np.stack([s.lat, s.lon], 1) for d in drives for s in d.stretches if len(s.lat)]
    if not pts:
        return f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}"></svg>'
    allp = np.concatenate(pts)
    allp = allp[np.all(np.isfinite(allp), axis=1)]
    origin = (float(np.mean(allp[:, 0])), float(np.mean(allp[:, 1])))
    xy = project(allp[:, 0], allp[:, 1], origin)
    lo, hi = xy.min(0), xy.max(0)
    margin = 30
    span = np.maximum(hi - lo, 1.0)
    scale = min((width - 2 * margin) / span[0], (height - 2 * margin) / span[1])
    off = np.array([width, height]) / 2 - (lo + hi) / 2 * np.array([scale, -scale])

    def to_px(lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        return project(lat, lon, origin) * np.array([scale, -scale]) + off

    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'viewBox="0 0 {width} {height}" class="egovid-plain"><rect width="100%" height="100%" fill="#f4f4f0"/>'
    ]
    for di, d in enumerate(drives):
        for s in d.stretches:
            if len(s.lat) == 0:
                continue
            colour = DRIVE_COLOURS[di % len(DRIVE_COLOURS)] if colour_by == "drive" else saving_colour(s.saving)
            p = to_px(s.lat, s.lon)
            coords = " ".join(f"{x:.1f},{y:.1f}" for x, y in p)
            dash = f' stroke-dasharray="{KIND_DASH[d.kind]}"' if d.kind in KIND_DASH else ""
            parts.append(
                f'<polyline class="egovid-track" points="{coords}" fill="none" stroke="{colour}" stroke-width="4" '
                f'stroke-linejoin="round" stroke-linecap="round"{dash}><title>{html.escape(d.name)}</title></polyline>'
            )
    # Scale bar: a round number of metres about a fifth of the width.
    metres = (width / 5) / scale
    nice = 10 ** math.floor(math.log10(metres))
    nice *= max(m for m in (1, 2, 5) if m * nice <= metres)
    bar = nice * scale
    label = f"{nice / 1000:g} km" if nice >= 1000 else f"{nice:g} m"
    y = height - 12
    parts.append(
        f'<line x1="12" y1="{y}" x2="{12 + bar:.1f}" y2="{y}" stroke="#222" stroke-width="2"/>'
        f'<text x="12" y="{y - 5}" font-size="12" font-family="sans-serif">{label}</text></svg>'
    )
    return "".join(parts)


def _asset(name: str) -> str:
    return resources.files("egovid.data").joinpath("leaflet", name).read_text(encoding="utf-8")


def _script_json(obj) -> str:
    """JSON safe to inline in a <script> element."""
    return json.dumps(obj, separators=(",", ":")).replace("</", "<\\/").replace("<!--", "<\\!--")


def render_map(
    drives: list[MapDrive],
    *,
    title: str = "egovid dashcam archive",
    tiles: str | None = OSM_TILES,
    attribution: str = OSM_ATTRIBUTION,
    colour_by: str = "drive",
    tolerance_m: float = 1.0,
) -> str:
    """The HTML page (one string, no external files) drawing ``drives`` on a map.

    ``tiles``: an XYZ tile URL template (``{z}/{x}/{y}``) fetched only when the browser is online,
    or None for none; ``colour_by``: ``drive`` or ``saving`` (initial colouring; the page can switch);
    ``tolerance_m``: tracks are simplified to this many metres (Douglas-Peucker) to keep pages small.
    """
    if colour_by not in ("drive", "saving"):
        raise ValueError(f"colour_by must be 'drive' or 'saving', not {colour_by!r}")
    data = {
        "title": title,
        "tiles": tiles,
        "attribution": attribution,
        "colourBy": colour_by,
        "savingStops": SAVING_STOPS,
        "savingFull": SAVING_FULL,
        "dash": KIND_DASH,
        "drives": [
            {
                "name": d.name,
                "kind": d.kind,
                "colour": DRIVE_COLOURS[i % len(DRIVE_COLOURS)],
                "info": d.info,
                "stretches": [
                    {
                        "pts": np.round(_simplified(s.lat, s.lon, tolerance_m), 7).tolist(),
                        "saving": s.saving,
                        "savingColour": saving_colour(s.saving),
                        "info": s.info,
                    }
                    for s in d.stretches
                ],
            }
            for i, d in enumerate(drives)
        ],
    }
    return _PAGE.format(
        title=html.escape(title),
        leaflet_css=_asset("leaflet.css"),
        leaflet_js=_asset("leaflet.js"),
        data=_script_json(data),
        plain=_plain_svg(drives, colour_by),
    )


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>{leaflet_css}</style>
<style>
html, body {{ margin: 0; height: 100%; font: 14px/1.4 system-ui, sans-serif; }}
#map {{ position: absolute; top: 0; bottom: 0; left: 0; right: 0; background: #f4f4f0; }}
#plain {{ padding: 8px; }}
.egovid-panel {{ background: #fff; padding: 6px 10px; border-radius: 4px; box-shadow: 0 1px 4px #0004; }}
.egovid-panel h1 {{ font-size: 15px; margin: 0 0 4px; }}
.egovid-legend span.sw {{ display: inline-block; width: 18px; height: 4px; margin-right: 6px; vertical-align: middle; }}
.egovid-bar {{ height: 10px; width: 160px; }}
.egovid-popup td {{ padding: 0 6px 0 0; vertical-align: top; }} .egovid-popup td:first-child {{ color: #555; }}
.egovid-note {{ color: #555; font-size: 12px; }}
</style></head>
<body data-tracks="0" data-tiles="none">
<div id="map"></div>
<div id="plain"><p>{title} (plain projection: the map library could not run here)</p>{plain}</div>
<script>{leaflet_js}</script>
<script>
"use strict";
const DATA = {data};
(function () {{
  if (!window.L) return;  // keep the plain SVG
  document.getElementById("plain").style.display = "none";
  const map = L.map("map", {{ zoomSnap: 0.25 }});
  const body = document.body;
  let note = "no background map (none configured)";
  if (DATA.tiles && navigator.onLine) {{
    const tiles = L.tileLayer(DATA.tiles, {{ attribution: DATA.attribution, maxZoom: 19, crossOrigin: true }});
    let failed = 0;
    tiles.on("tileerror", function () {{
      if (++failed === 4) {{
        map.removeLayer(tiles);
        setNote("background map unreachable: plain projection");
        body.dataset.tiles = "offline";
      }}
    }});
    tiles.addTo(map);
    note = "";
    body.dataset.tiles = "online";
  }} else if (DATA.tiles) {{
    note = "offline: tracks on a plain projection";
    body.dataset.tiles = "offline";
  }}
  function savingColour(v) {{
    if (v === null || v === undefined || !isFinite(v)) return "#8c8c8c";
    const s = DATA.savingStops, x = Math.min(Math.max(v / DATA.savingFull, 0), 1) * (s.length - 1);
    const i = Math.min(Math.floor(x), s.length - 2), f = x - i;
    const a = s[i], b = s[i + 1];
    let out = "#";
    for (const k of [1, 3, 5]) {{
      const p = parseInt(a.substr(k, 2), 16), q = parseInt(b.substr(k, 2), 16);
      out += Math.round(p + (q - p) * f).toString(16).padStart(2, "0");
    }}
    return out;
  }}
  function table(rows) {{
    const t = document.createElement("table");
    t.className = "egovid-popup";
    for (const [k, v] of rows) {{
      const tr = t.insertRow();
      tr.insertCell().textContent = k;
      tr.insertCell().textContent = v;
    }}
    return t;
  }}
  const lines = [];
  const bounds = L.latLngBounds([]);
  for (const d of DATA.drives) {{
    for (const s of d.stretches) {{
      if (!s.pts.length) continue;
      const style = {{ weight: 5, opacity: 0.9, className: "egovid-track", dashArray: DATA.dash[d.kind] || null }};
      const line = L.polyline(s.pts, style);
      const rows = [["drive", d.name], ["kind", d.kind], ...Object.entries(d.info), ...Object.entries(s.info)];
      line.bindPopup(function () {{
        const div = document.createElement("div"), h = document.createElement("b");
        h.textContent = d.name;
        div.append(h, table(rows));
        return div;
      }});
      line.on("mouseover", function () {{ line.setStyle({{ weight: 8 }}); }});
      line.on("mouseout", function () {{ line.setStyle({{ weight: 5 }}); }});
      line.addTo(map);
      lines.push([line, d, s]);
      bounds.extend(line.getBounds());
    }}
  }}
  if (bounds.isValid()) map.fitBounds(bounds, {{ padding: [30, 30], maxZoom: 18 }}); else map.setView([0, 0], 2);
  L.control.scale({{ imperial: false }}).addTo(map);
  const panel = L.control({{ position: "topright" }});
  function setNote(text) {{ const n = document.getElementById("egovid-note"); if (n) n.textContent = text; }}
  function recolour(mode) {{
    for (const [line, d, s] of lines) line.setStyle({{ color: mode === "drive" ? d.colour : savingColour(s.saving) }});
    const legend = document.getElementById("egovid-legend");
    legend.replaceChildren();
    if (mode === "drive") {{
      for (const d of DATA.drives) {{
        const row = document.createElement("div"), sw = document.createElement("span");
        sw.className = "sw"; sw.style.background = d.colour;
        row.append(sw, document.createTextNode(d.name + (d.kind !== "drive" ? " (" + d.kind + ")" : "")));
        legend.append(row);
      }}
    }} else {{
      const bar = document.createElement("div");
      bar.className = "egovid-bar";
      bar.style.background = "linear-gradient(to right, " + DATA.savingStops.join(", ") + ")";
      const lab = document.createElement("div");
      lab.textContent = "saving 0 % … " + Math.round(100 * DATA.savingFull) + " % (grey: root or not measured)";
      legend.append(bar, lab);
    }}
  }}
  panel.onAdd = function () {{
    const div = L.DomUtil.create("div", "egovid-panel egovid-legend-panel");
    const h = document.createElement("h1"); h.textContent = DATA.title; div.append(h);
    const form = document.createElement("div");
    for (const [mode, label] of [["drive", "colour by drive"], ["saving", "colour by saving"]]) {{
      const lab = document.createElement("label"), r = document.createElement("input");
      r.type = "radio"; r.name = "colour"; r.value = mode; r.checked = mode === DATA.colourBy;
      r.addEventListener("change", function () {{ recolour(mode); }});
      lab.append(r, document.createTextNode(" " + label + " "));
      form.append(lab);
    }}
    const legend = document.createElement("div"); legend.id = "egovid-legend"; legend.className = "egovid-legend";
    const n = document.createElement("div"); n.id = "egovid-note"; n.className = "egovid-note"; n.textContent = note;
    div.append(form, legend, n);
    L.DomEvent.disableClickPropagation(div);
    return div;
  }};
  panel.addTo(map);
  recolour(DATA.colourBy);
  body.dataset.tracks = String(lines.length);
}})();
</script>
</body></html>
"""
