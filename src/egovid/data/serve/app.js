// egovid serve: the archive in a browser. Plain JS, no build step, nothing from the network
// (map tiles only when configured and online). The server's API is described in egovid/serve/app.py.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const COLOURS = ["#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7", "#9c755f", "#bab0ac"];
  const BUFFER_AHEAD = 8;   // seconds of video kept ready ahead of the playhead
  const KEEP_BEHIND = 30;   // seconds kept behind it (older data is removed from the buffer)
  const VIEWER = Math.random().toString(36).slice(2, 12);  // this page, for the server's producers
  const S = { info: null, overview: null, drives: [], shown: [], lines: new Map(), findLayer: null, mode: null };

  // -- small helpers -----------------------------------------------------------------------------
  function status(text, error) {
    const el = $("status");
    el.textContent = text || "";
    el.classList.toggle("error", !!error);
  }
  function mib(n) { return n < 1024 * 1024 ? (n / 1024).toFixed(0) + " KiB" : (n / 1048576).toFixed(2) + " MiB"; }
  function hms(s) {
    s = Math.max(0, s);
    const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), x = (s % 60).toFixed(1);
    return (h ? h + ":" + String(m).padStart(2, "0") : m) + ":" + x.padStart(4, "0");
  }
  function isoUtc(t) { return new Date(t * 1000).toISOString().replace(".000Z", "Z"); }
  async function api(path, body) {
    const opt = body === undefined ? {} : {
      method: "POST", body: JSON.stringify(body),
      headers: { "content-type": "application/json", "x-egovid-token": S.info ? S.info.token : "" },
    };
    const r = await fetch(path, opt);
    const text = await r.text();
    let data = null;
    try { data = JSON.parse(text); } catch (e) { data = { error: text.trim() }; }
    if (!r.ok) throw new Error((data && data.error) || r.status + " " + r.statusText);
    return data;
  }
  function colourOf(d) { return COLOURS[S.drives.indexOf(d) % COLOURS.length]; }
  function interp(xs, ys, x) {  // piecewise linear, held at the ends (xs ascending)
    const n = xs.length;
    if (!n) return NaN;
    if (x <= xs[0]) return ys[0];
    if (x >= xs[n - 1]) return ys[n - 1];
    let lo = 0, hi = n - 1;
    while (hi - lo > 1) { const mid = (lo + hi) >> 1; if (xs[mid] <= x) lo = mid; else hi = mid; }
    const f = (x - xs[lo]) / (xs[hi] - xs[lo] || 1);
    return ys[lo] + f * (ys[hi] - ys[lo]);
  }

  // -- map ---------------------------------------------------------------------------------------
  const map = L.map("map", { zoomSnap: 0.25 });
  L.control.scale({ imperial: false }).addTo(map);
  const marker = L.circleMarker([0, 0], { radius: 8, color: "#fff", weight: 2, fillColor: "#f28e2b", fillOpacity: 1 });
  marker.bindTooltip("", { permanent: true, direction: "bottom", offset: [0, 10], className: "egovid-speed" });

  function setupTiles(url) {
    if (!url || !navigator.onLine) { document.body.dataset.tiles = url ? "offline" : "none"; return; }
    const tiles = L.tileLayer(url, { maxZoom: 19, attribution: "&copy; OpenStreetMap contributors" });
    let failed = 0;
    tiles.on("tileerror", () => { if (++failed === 4) { map.removeLayer(tiles); document.body.dataset.tiles = "offline"; } });
    tiles.addTo(map);
    document.body.dataset.tiles = "online";
  }

  function drawTracks() {
    for (const line of S.lines.values()) line.remove();
    S.lines.clear();
    const bounds = L.latLngBounds([]);
    for (const d of S.shown) {
      if (!d.track.length) continue;
      const line = L.polyline(d.track, { color: colourOf(d), weight: 5, opacity: 0.85, className: "egovid-track",
                                         dashArray: d.kind === "event" ? "8 6" : d.kind === "parking" ? "2 6" : null });
      line.on("click", (e) => { L.DomEvent.stopPropagation(e); clickTrack(d, e.latlng); });
      line.bindTooltip(d.name, { sticky: true });
      line.addTo(map);
      S.lines.set(d.id, line);
      bounds.extend(line.getBounds());
    }
    if (bounds.isValid()) map.fitBounds(bounds, { padding: [20, 20], maxZoom: 18 });
    else if (!map._loaded) map.setView([0, 0], 2);
  }

  function nearestTime(track, latlng) {  // video time of the fix nearest to latlng, and its distance in pixels
    const p = map.latLngToContainerPoint(latlng);
    let best = null, bestD = Infinity;
    for (let i = 0; i < track.t.length; i++) {
      const q = map.latLngToContainerPoint([track.lat[i], track.lon[i]]);
      const dd = (q.x - p.x) ** 2 + (q.y - p.y) ** 2;
      if (dd < bestD) { bestD = dd; best = i; }
    }
    return best === null ? null : { t: track.t[best], px: Math.sqrt(bestD) };
  }

  async function clickTrack(d, latlng) {
    if (Player.drive && Player.track && Player.drive.id !== d.id) {  // tracks of one road overlap: the playing one first
      const hit = nearestTime(Player.track, latlng);
      if (hit && hit.px < 12) { Player.seek(hit.t); return; }
    }
    const track = Player.drive && Player.drive.id === d.id ? Player.track : await api(`/api/drives/${d.id}/track`);
    const hit = nearestTime(track, latlng);
    const t = hit ? hit.t : 0;
    if (Player.drive && Player.drive.id === d.id) Player.seek(t); else Player.open(d, t);
  }

  map.on("click", (e) => {
    if (S.mode || !Player.drive || !Player.track) return;
    const hit = nearestTime(Player.track, e.latlng);
    if (hit && hit.px < 40) Player.seek(hit.t);
  });

  // -- the list and its filters --------------------------------------------------------------------
  function applyFilters() {
    const day = $("f-day").value, kind = $("f-kind").value, locked = $("f-locked").value, path = $("f-path").value;
    S.shown = S.drives.filter((d) => (!day || d.day === day) && (!kind || d.kind === kind) &&
      (!locked || (locked === "yes") === d.locked) && (!path || d.paths.includes(Number(path))));
    const ul = $("drives");
    ul.replaceChildren();
    for (const d of S.shown) {
      const li = document.createElement("li");
      li.dataset.id = d.id;
      li.style.borderLeftColor = colourOf(d);
      li.classList.toggle("current", !!(Player.drive && Player.drive.id === d.id));
      const b = document.createElement("b"); b.textContent = d.name; li.append(b);
      if (d.kind !== "drive") { const s = document.createElement("span"); s.className = "badge " + d.kind; s.textContent = d.kind; li.append(s); }
      if (d.locked) { const s = document.createElement("span"); s.className = "badge lock"; s.textContent = "locked"; s.title = d.lock_note || ""; li.append(s); }
      const meta = document.createElement("div"); meta.className = "meta";
      const saving = d.saving === null || d.saving === undefined ? (d.modes.includes("joint") ? "joint, saving not measured" : "root")
        : "saving " + (100 * d.saving).toFixed(1) + " %";
      meta.textContent = `${d.start.replace("T", " ").slice(0, 19)} · ${hms(d.duration)} · ${d.width}×${d.height} · ${mib(d.bytes)} · ${saving}` +
        (d.references.length ? " vs " + d.references.join(", ") : "");
      li.append(meta);
      li.addEventListener("click", () => Player.open(d, 0));
      ul.append(li);
    }
    drawTracks();
    drawTimeline();
  }

  function fillFilters(ov) {
    const days = [...new Set(ov.drives.map((d) => d.day))].sort();
    for (const [id, values, label] of [["f-day", days, (v) => v], ["f-path", ov.paths.map((p) => p.id), (v) => {
      const p = ov.paths.find((x) => x.id === v); return `path ${v} (${Math.round(p.length_m)} m)`; }]]) {
      const sel = $(id), keep = sel.value;
      sel.replaceChildren(new Option("all", ""));
      for (const v of values) sel.append(new Option(label(v), String(v)));
      sel.value = values.map(String).includes(keep) ? keep : "";
    }
  }

  async function loadDrives() {
    const ov = await api("/api/drives");
    S.overview = ov;
    S.drives = ov.drives;
    const saving = ov.drives.filter((d) => d.saving !== null);
    $("title").textContent = ov.archive;
    $("totals").textContent = `${ov.drives.length} drive(s), ${mib(ov.stored_bytes)} stored` +
      (saving.length ? `; joint coding saved ${(100 * saving.reduce((a, d) => a + d.saving, 0) / saving.length).toFixed(1)} % on average (${saving.length} measured)` : "");
    fillFilters(ov);
    applyFilters();
  }
  for (const id of ["f-day", "f-kind", "f-locked", "f-path"]) $(id).addEventListener("change", applyFilters);

  // -- timeline: one row per day, time of day across (UTC) ------------------------------------------
  const TL = { t0: 0, t1: 1, w: 1, rows: [] };
  const DAY = 86400;
  function drawTimeline() {
    const svg = $("tl");
    svg.replaceChildren();
    const ds = S.shown;
    if (!ds.length) return;
    const days = [...new Set(ds.map((d) => Math.floor(d.start_utc / DAY)))].sort((a, b) => a - b);
    const rh = 16, top = 4, h = top + days.length * (rh + 4) + 18;
    svg.style.height = h + "px";
    const w = svg.clientWidth || 800, label = 74;
    let t0 = Math.min(...ds.map((d) => d.start_utc - Math.floor(d.start_utc / DAY) * DAY));
    let t1 = Math.max(...ds.map((d) => d.start_utc + d.duration - Math.floor(d.start_utc / DAY) * DAY));
    const pad = Math.max((t1 - t0) * 0.02, 1);
    t0 = Math.max(0, t0 - pad); t1 = t1 + pad;
    Object.assign(TL, { t0, t1, w, label, days });
    const x = (tod) => label + ((tod - t0) / (t1 - t0)) * (w - label - 4);
    const ns = "http://www.w3.org/2000/svg";
    const el = (name, attrs, text) => {
      const e = document.createElementNS(ns, name);
      for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
      if (text !== undefined) e.textContent = text;
      svg.append(e);
      return e;
    };
    days.forEach((day, i) => el("text", { x: 2, y: top + i * (rh + 4) + rh - 4 }, isoUtc(day * DAY).slice(0, 10)));
    for (const d of ds) {
      const day = Math.floor(d.start_utc / DAY), row = days.indexOf(day), tod = d.start_utc - day * DAY;
      const r = el("rect", { x: x(tod), y: top + row * (rh + 4), height: rh, class: "drive", fill: colourOf(d),
                             width: Math.max(3, x(tod + d.duration) - x(tod)) });
      r.dataset.id = d.id;
      const title = document.createElementNS(ns, "title"); title.textContent = `${d.name} ${d.start}`; r.append(title);
      r.addEventListener("click", (e) => {
        e.stopPropagation();
        const at = t0 + ((e.offsetX - label) / (w - label - 4)) * (t1 - t0) - tod;
        const within = Math.min(Math.max(at, 0), d.duration - 0.05);
        if (Player.drive && Player.drive.id === d.id) Player.seek(within); else Player.open(d, within);
      });
    }
    for (const [t, anchor] of [[t0, "start"], [(t0 + t1) / 2, "middle"], [t1, "end"]]) {
      el("text", { x: x(t), y: h - 4, "text-anchor": anchor }, isoUtc(Math.round(t)).slice(11, 19) + " UTC");
    }
    el("line", { id: "tl-head", y1: 0, y2: h - 16, stroke: "#d00", "stroke-width": 2, visibility: "hidden" });
  }
  function timelineX(d, t) {  // x of second t of drive d on the timeline
    const day = Math.floor(d.start_utc / DAY), tod = d.start_utc - day * DAY + t;
    return TL.label + ((tod - TL.t0) / (TL.t1 - TL.t0)) * (TL.w - TL.label - 4);
  }
  window.addEventListener("resize", () => drawTimeline());

  // -- the player: Media Source Extensions, chunks of fragmented MP4 appended where they belong --------
  const video = $("video");
  const Player = {
    drive: null, manifest: null, track: null, ms: null, sb: null, gen: 0, busy: false, abort: null,
    failures: 0, started: 0, seekTarget: null, seekStarted: 0, appendChain: Promise.resolve(),

    chunkAt(t) { const m = this.manifest; return Math.min(m.chunks - 1, Math.max(0, Math.floor((t * m.fps + 1e-6) / m.chunk_frames))); },
    chunkStart(k) { return (k * this.manifest.chunk_frames) / this.manifest.fps; },
    buffered(t) {
      const b = this.sb ? this.sb.buffered : null;
      if (!b) return false;
      for (let i = 0; i < b.length; i++) if (b.start(i) <= t + 0.02 && t < b.end(i)) return true;
      return false;
    },

    async open(d, t0) {
      const gen = ++this.gen;
      this.stop();
      this.drive = d;
      this.started = performance.now();
      this.seekTarget = null;
      document.body.dataset.playing = String(d.id);
      document.body.dataset.firstFrame = "";
      status(`opening ${d.name}…`);
      $("actions").hidden = false;
      $("clip-links").replaceChildren();
      $("lock").textContent = d.locked ? "unlock" : "lock";
      $("lock-note").hidden = d.locked;
      for (const li of $("drives").children) li.classList.toggle("current", li.dataset.id === String(d.id));
      try {
        const [manifest, track] = await Promise.all([api(`/api/drives/${d.id}/stream`), api(`/api/drives/${d.id}/track`)]);
        if (gen !== this.gen) return;
        this.manifest = manifest; this.track = track;
        const MS = window.ManagedMediaSource || window.MediaSource;
        const ms = new MS();
        this.ms = ms;
        video.src = URL.createObjectURL(ms);
        await new Promise((ok) => ms.addEventListener("sourceopen", ok, { once: true }));
        if (gen !== this.gen) return;
        ms.duration = manifest.duration;
        const k = this.chunkAt(t0);
        const first = await this.fetchChunk(k, gen);
        if (!first || gen !== this.gen) return;
        this.sb = ms.addSourceBuffer(first.codec);
        this.sb.mode = "segments";
        await this.append(k, first.data, gen);
        if (gen !== this.gen) return;
        video.currentTime = Math.max(t0, this.chunkStart(k));
        marker.addTo(map);
        await video.play().catch(() => {});
        $("play").disabled = false;
        status("");
        this.pump();
      } catch (e) {
        if (gen === this.gen) status(`cannot play ${d.name}: ${e.message}`, true);
      }
    },

    stop() {
      if (this.abort) this.abort.abort();
      this.abort = null; this.busy = false; this.sb = null; this.manifest = null; this.track = null; this.failures = 0;
      this.appendChain = Promise.resolve();
      if (this.ms) { video.removeAttribute("src"); video.load(); }
      this.ms = null;
    },

    close() {
      this.gen++; this.stop(); this.drive = null;
      document.body.dataset.playing = "";
      marker.remove();
      $("actions").hidden = true; $("play").disabled = true;
      $("clock").textContent = "no drive: click one on the map, the list or the timeline";
    },

    async fetchChunk(k, gen) {
      this.abort = new AbortController();
      const r = await fetch(`/api/drives/${this.drive.id}/chunks/${k}.mp4?v=${VIEWER}`, { signal: this.abort.signal });
      if (gen !== this.gen) return null;
      if (!r.ok) {
        let msg = r.status + " " + r.statusText;
        try { msg = (await r.json()).error || msg; } catch (e) { /* not JSON */ }
        throw new Error(msg);
      }
      return { codec: r.headers.get("x-egovid-codec") || 'video/mp4; codecs="avc1.42c01f"', data: await r.arrayBuffer() };
    },

    append(k, data, gen) {  // appends run one after another, each once the buffer is idle
      const run = async () => {
        const sb = this.sb;
        if (!sb || gen !== this.gen) return;
        while (sb.updating) await new Promise((ok) => sb.addEventListener("updateend", ok, { once: true }));
        if (gen !== this.gen || this.sb !== sb) return;
        await new Promise((ok, fail) => {
          const done = () => { sb.removeEventListener("error", bad); ok(); };
          const bad = () => { sb.removeEventListener("updateend", done); fail(new Error("the browser could not decode chunk " + k)); };
          sb.addEventListener("updateend", done, { once: true });
          sb.addEventListener("error", bad, { once: true });
          sb.timestampOffset = this.chunkStart(k);
          sb.appendBuffer(data);
        });
      };
      const p = this.appendChain.then(run, run);
      this.appendChain = p.catch(() => {});
      return p;
    },

    async pump() {  // keep BUFFER_AHEAD seconds ready; one request at a time
      if (this.busy || !this.sb || !this.manifest) return;
      const gen = this.gen, m = this.manifest, now = video.currentTime;
      let k = this.chunkAt(now);
      while (k < m.chunks && this.buffered(this.chunkStart(k) + 0.5 / m.fps) && this.buffered(Math.min(this.chunkStart(k + 1), m.duration) - 0.5 / m.fps)) k++;
      if (k >= m.chunks) {
        if (this.ms && this.ms.readyState === "open" && !this.sb.updating && this.buffered(m.duration - 0.5 / m.fps)) {
          try { this.ms.endOfStream(); } catch (e) { /* already ended */ }
        }
        return;
      }
      if (this.chunkStart(k) > now + BUFFER_AHEAD) return;
      this.busy = true;
      try {
        const b = this.sb.buffered;
        if (b.length && b.start(0) < now - KEEP_BEHIND - 5) {
          const sb = this.sb;
          const drop = async () => {
            while (sb.updating) await new Promise((ok) => sb.addEventListener("updateend", ok, { once: true }));
            if (this.sb !== sb) return;
            await new Promise((ok) => { sb.addEventListener("updateend", ok, { once: true }); sb.remove(0, now - KEEP_BEHIND); });
          };
          const p = this.appendChain.then(drop, drop);
          this.appendChain = p.catch(() => {});
          await p;
        }
        const got = await this.fetchChunk(k, gen);
        if (got && gen === this.gen) await this.append(k, got.data, gen);
        this.failures = 0;
      } catch (e) {
        if (e.name !== "AbortError" && gen === this.gen) {
          this.failures++;
          status(`chunk ${k} of ${this.drive.name}: ${e.message}`, true);
        }
      } finally {
        if (gen === this.gen) this.busy = false;
      }
      if (gen === this.gen && this.failures < 3) setTimeout(() => this.pump(), this.failures ? 1000 : 0);
    },

    seek(t) {
      if (!this.manifest) return;
      t = Math.min(Math.max(0, t), this.manifest.duration - 0.5 / this.manifest.fps);
      this.seekStarted = performance.now();
      this.seekTarget = t;
      document.body.dataset.seeked = "";
      document.body.dataset.seekFrame = "";
      if (!this.buffered(t) && this.abort) { this.abort.abort(); this.busy = false; }
      video.currentTime = t;
      this.failures = 0;
      this.pump();
    },

    at(t) {  // position, speed and acceleration at video time t, from the GPS fixes
      const tr = this.track;
      if (!tr || !tr.t.length) return null;
      return { lat: interp(tr.t, tr.lat, t), lon: interp(tr.t, tr.lon, t), speed: interp(tr.t, tr.speed, t), accel: interp(tr.t, tr.accel, t) };
    },
  };
  window.egovid = { Player, map, marker, S };

  video.addEventListener("timeupdate", () => Player.pump());
  video.addEventListener("waiting", () => Player.pump());
  video.addEventListener("seeked", () => {
    if (Player.seekStarted) document.body.dataset.seeked = String(Math.round(performance.now() - Player.seekStarted));
  });
  video.addEventListener("playing", () => { $("play").textContent = "❚❚"; });
  video.addEventListener("pause", () => { $("play").textContent = "▶"; });
  video.addEventListener("error", () => { if (Player.drive) status(`the browser stopped the video: ${video.error ? video.error.message : "?"}`, true); });
  $("play").addEventListener("click", () => { if (video.paused) video.play(); else video.pause(); });
  $("scrub").addEventListener("click", (e) => {
    if (!Player.manifest) return;
    const r = $("scrub").getBoundingClientRect();
    Player.seek(((e.clientX - r.left) / r.width) * Player.manifest.duration);
  });
  if ("requestVideoFrameCallback" in video) {
    // Latencies for the benchmark and the tests: click to the first frame shown, seek to the first
    // frame shown at the new position (milliseconds, in data-first-frame / data-seek-frame).
    const onFrame = (now, meta) => {
      const ms = String(Math.round(performance.now() - (Player.seekTarget !== null ? Player.seekStarted : Player.started)));
      if (Player.started && !document.body.dataset.firstFrame) document.body.dataset.firstFrame = ms;
      else if (Player.seekTarget !== null && Math.abs(meta.mediaTime - Player.seekTarget) < 0.5) {
        document.body.dataset.seekFrame = ms;
        Player.seekTarget = null;
      }
      video.requestVideoFrameCallback(onFrame);
    };
    video.requestVideoFrameCallback(onFrame);
  }

  function tick() {  // the marker, its speed, the clock and the playheads follow playback
    const d = Player.drive, m = Player.manifest;
    if (d && m) {
      const t = video.currentTime, p = Player.at(t);
      if (p) {
        marker.setLatLng([p.lat, p.lon]);
        marker.setTooltipContent(`${(p.speed * 3.6).toFixed(0)} km/h · ${p.accel >= 0 ? "+" : ""}${p.accel.toFixed(1)} m/s²`);
      }
      const utc = (Player.track && Player.track.utc0 ? Player.track.utc0 : d.start_utc) + t;
      $("clock").textContent = `${d.name}  ${hms(t)} / ${hms(m.duration)}  ·  ${isoUtc(Math.floor(utc)).replace("T", " ")}`;
      $("scrub-head").style.left = (100 * t / m.duration) + "%";
      const b = Player.sb ? Player.sb.buffered : null;
      let end = 0;
      if (b) for (let i = 0; i < b.length; i++) if (b.start(i) <= t + 0.1) end = Math.max(end, b.end(i));
      $("scrub-buffered").style.width = (100 * end / m.duration) + "%";
      const head = $("tl-head");
      if (head && TL.days && TL.days.includes(Math.floor(d.start_utc / DAY))) {
        const x = timelineX(d, t), row = TL.days.indexOf(Math.floor(d.start_utc / DAY));
        head.setAttribute("x1", x); head.setAttribute("x2", x); head.setAttribute("visibility", "visible");
        head.setAttribute("y1", 2 + row * 20); head.setAttribute("y2", 22 + row * 20);
      }
    }
    requestAnimationFrame(tick);
  }
  requestAnimationFrame(tick);

  // -- clip ------------------------------------------------------------------------------------------
  $("clip").addEventListener("click", async () => {
    const d = Player.drive;
    if (!d) return;
    const links = $("clip-links");
    links.replaceChildren();
    status("making the clip…");
    try {
      const c = await api("/api/clips", { drive: d.id, t: video.currentTime, before: Number($("clip-before").value), after: Number($("clip-after").value) });
      for (const [href, label] of [[c.video, `clip.mp4 (${c.frames} frames from ${c.start.slice(11, 19)})`], [c.gpx, "clip.gpx"]]) {
        if (!href) continue;
        const a = document.createElement("a");
        a.href = href; a.textContent = label; a.setAttribute("download", "");
        links.append(a);
      }
      status("");
    } catch (e) { status("clip: " + e.message, true); }
  });

  // -- lock and forget (hidden with --read-only) -----------------------------------------------------
  $("lock").addEventListener("click", async () => {
    const d = Player.drive;
    if (!d) return;
    try {
      const r = d.locked ? await api(`/api/drives/${d.id}/unlock`, {}) : await api(`/api/drives/${d.id}/lock`, { note: $("lock-note").value || null });
      d.locked = r.locked; d.lock_note = r.lock_note;
      $("lock").textContent = d.locked ? "unlock" : "lock";
      $("lock-note").hidden = d.locked;
      status(`${d.name} ${d.locked ? "locked" : "unlocked"}`);
      applyFilters();
    } catch (e) { status(e.message, true); }
  });

  function confirmDialog(text) {
    return new Promise((ok) => {
      const dlg = $("confirm");
      $("confirm-text").textContent = text;
      const answer = (v) => () => { dlg.close(); ok(v); };
      $("confirm-ok").onclick = answer(true);
      $("confirm-cancel").onclick = answer(false);
      dlg.oncancel = () => ok(false);
      dlg.showModal();
    });
  }

  $("forget").addEventListener("click", async () => {
    const d = Player.drive;
    if (!d) return;
    try {
      status("working out what forgetting changes…");
      const p = await api("/api/forget/preview", { drives: [d.id] });
      const lines = [`Forget ${p.forgotten.join(", ")}? It is no longer listed, found, played or extracted.`,
                     `Frees ${mib(p.bytes_freed)} (${p.bytes_freed} bytes).`];
      for (const [name, needers] of Object.entries(p.kept_as_reference)) {
        lines.push(`${needers.join(", ")} ${needers.length > 1 ? "are" : "is"} coded against ${name.split("~")[0]}: the frames ${needers.length > 1 ? "they need" : "it needs"} stay, hidden, so ${needers.length > 1 ? "they decode" : "it decodes"} bit for bit as before (checked before anything changes).`);
      }
      if (!Object.keys(p.kept_as_reference).length) lines.push("No other drive is coded against it.");
      status("");
      if (!(await confirmDialog(lines.join("\n")))) return;
      status(`forgetting ${d.name}…`);
      const r = await api("/api/forget", { drives: [d.id] });
      Player.close();
      status(`forgot ${r.forgotten.join(", ")}: freed ${mib(r.bytes_freed)}`);
      await loadDrives();
    } catch (e) { status(e.message, true); }
  });

  // -- find: a circle or a box drawn on the map, and a time range -------------------------------------
  let shape = null;
  function setMode(mode) {
    S.mode = S.mode === mode ? null : mode;
    $("find-circle").classList.toggle("on", S.mode === "circle");
    $("find-box").classList.toggle("on", S.mode === "box");
    if (S.mode) map.dragging.disable(); else map.dragging.enable();
  }
  $("find-circle").addEventListener("click", () => setMode("circle"));
  $("find-box").addEventListener("click", () => setMode("box"));
  $("find-clear").addEventListener("click", () => {
    if (shape) shape.remove();
    shape = null; $("found").replaceChildren(); $("find-what").textContent = "";
    if (S.findLayer) S.findLayer.remove();
  });
  let drawing = null;
  map.on("mousedown", (e) => {
    if (!S.mode) return;
    if (shape) shape.remove();
    drawing = { mode: S.mode, from: e.latlng };
    shape = S.mode === "circle" ? L.circle(e.latlng, { radius: 1, color: "#d00", weight: 2, fillOpacity: 0.08 })
      : L.rectangle(L.latLngBounds(e.latlng, e.latlng), { color: "#d00", weight: 2, fillOpacity: 0.08 });
    shape.addTo(map);
  });
  map.on("mousemove", (e) => {
    if (!drawing) return;
    if (drawing.mode === "circle") shape.setRadius(Math.max(1, drawing.from.distanceTo(e.latlng)));
    else shape.setBounds(L.latLngBounds(drawing.from, e.latlng));
  });
  map.on("mouseup", () => {
    if (!drawing) return;
    drawing = null;
    setMode(S.mode);  // back to panning
    runFind();
  });

  function localToIso(v) { return v ? v + (v.length === 16 ? ":00" : "") + "Z" : ""; }
  async function runFind() {
    const q = new URLSearchParams();
    if (shape && shape.getRadius) {
      const c = shape.getLatLng();
      q.set("near", `${c.lat.toFixed(7)},${c.lng.toFixed(7)}`); q.set("radius", Math.max(1, shape.getRadius()).toFixed(1));
    } else if (shape) {
      const b = shape.getBounds();
      q.set("bbox", [b.getWest(), b.getSouth(), b.getEast(), b.getNorth()].map((v) => v.toFixed(7)).join(","));
    }
    if ($("find-from").value) q.set("from", localToIso($("find-from").value));
    if ($("find-to").value) q.set("to", localToIso($("find-to").value));
    const ul = $("found");
    ul.replaceChildren();
    try {
      const found = await api("/api/find?" + q.toString());
      $("find-what").textContent = `${found.length} stretch(es)`;
      if (S.findLayer) S.findLayer.remove();
      S.findLayer = L.layerGroup().addTo(map);
      for (const s of found) {
        const li = document.createElement("li");
        const d = S.drives.find((x) => x.id === s.id);
        li.innerHTML = "<b></b><div class='meta'></div>";
        li.firstChild.textContent = s.drive;
        li.lastChild.textContent = `${s.start.replace("T", " ").slice(0, 19)} · ${hms(s.t1 - s.t0)}` + (s.distance_m !== null ? ` · closest ${s.distance_m.toFixed(0)} m` : "");
        li.addEventListener("click", () => d && Player.open(d, s.t0));
        ul.append(li);
        L.circleMarker([s.lat, s.lon], { radius: 5, color: "#d00" }).addTo(S.findLayer);
      }
    } catch (e) { $("find-what").textContent = e.message; }
  }
  $("find-go").addEventListener("click", runFind);

  // -- start -------------------------------------------------------------------------------------------
  (async function start() {
    try {
      S.info = await api("/api/info");
      document.body.classList.toggle("read-only", S.info.read_only);
      setupTiles(S.info.tiles);
      if (S.info.reports.length) {
        $("reports").hidden = false;
        for (const r of S.info.reports) {
          for (const page of r.pages) {
            const li = document.createElement("li"), a = document.createElement("a");
            a.href = r.base + page; a.target = "_blank"; a.rel = "noopener";
            a.textContent = `${r.kind}: ${r.name}/${page}`;
            li.append(a); $("report-list").append(li);
          }
        }
      }
      await loadDrives();
      document.body.dataset.ready = "1";
    } catch (e) { status("cannot load the archive: " + e.message, true); }
  })();
})();
