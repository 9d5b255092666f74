"""The map's interactive page: one self-contained HTML file of a frame's map, rotatable.

The same layers as ``map.png`` (`vibrissa.figures.map_figure.MapLayers`, built once for both
pictures): the contacts coloured by whisker (the figure's palette), the noise points
(black crosses), each object's known mesh in the figure's colours (``viridis`` of its distance
to the true surface or of its std, the same scale), the unknown part in faint grey, the true
objects as grey wireframes (`map_figure.wireframe`), the robot path and the whisker mounts; a
legend with a switch per layer beside the scene (it folds away, and the scene takes its place:
"hide key", or ``map.html#nokey``), the figure's title and status line, axes in mm. The view opens on the
objects and all of the robot's path and mounts.

No network and no library: the data is JSON in the page (lengths in mm rounded to 1 um), drawn
by a small viewer in plain JavaScript on a 2D canvas (no GPU needed, so a headless browser
draws it too): an orthographic view, triangles flat-shaded (the mean of their vertices' values)
and drawn back to front with the points and lines (painter's algorithm). Drag to rotate, wheel
to zoom, shift-drag to pan, double-click to reset. Once drawn, the page sets ``data-drawn`` on
``<body>`` to the number of things drawn (a test in a browser reads it).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from vibrissa.figures.map_figure import (
    MAX_POINTS_SHOWN,
    MM,
    SCALE_PERCENTILE,
    FloatArray,
    MapLayers,
    bounding_box,
    colour_scale,
    mounts,
    thousands,
    whisker_colours,
    wireframe,
)

MAX_PATH_SAMPLES = 2_000
"""Robot path samples in the page at most (every k-th beyond, and the last)."""

LUT_SIZE = 256
"""Entries of the mesh colour table (``viridis``)."""


def _mm(p: Any) -> list[float]:
    """Lengths ``p`` (any shape), m, as a flat list in mm rounded to 1 um."""
    flat = np.round(np.asarray(p, dtype=np.float64).reshape(-1) * MM, 3)
    return [float(x) for x in flat]


def _hex(rgba: Any) -> str:
    r, g, b = (int(round(255 * float(c))) for c in tuple(rgba)[:3])
    return f"#{r:02x}{g:02x}{b:02x}"


def page_data(layers: MapLayers) -> dict[str, Any]:
    """What the page draws, JSON-ready, lengths in mm: the layers as ``plot_map`` draws them
    (the same palette, colour scale, wireframes, mounts and point cap)."""
    import matplotlib

    points = np.asarray(layers.points, dtype=np.float64).reshape(-1, 3)
    ids = np.asarray(layers.whisker_ids, dtype=object)
    labels = np.asarray(layers.labels)
    shown = np.arange(0, len(points), max(1, -(-len(points) // MAX_POINTS_SHOWN)))
    colour = whisker_colours(layers)
    names, colours = list(colour), list(colour.values())
    index = {name: i for i, name in enumerate(names)}
    contact = shown[labels[shown] >= 0]
    noise = shown[labels[shown] < 0]

    # The figure's colour scale: viridis from 0 to a percentile of the vertices' values; a
    # triangle in the colour of its vertices' mean.
    top, largest = colour_scale(layers.meshes)
    values = [np.asarray(mesh.values)[mesh.triangles].mean(axis=1) * MM
              for mesh in layers.meshes]  # per triangle, mm
    cmap = matplotlib.colormaps["viridis"]
    lut = [_hex(cmap(i / (LUT_SIZE - 1))) for i in range(LUT_SIZE)]
    meshes = []
    for mesh, face in zip(layers.meshes, values, strict=True):
        level = np.clip(np.round(face / top * (LUT_SIZE - 1)), 0, LUT_SIZE - 1)
        meshes.append({
            "name": mesh.name,
            "v": _mm(mesh.vertices), "t": np.asarray(mesh.triangles).reshape(-1).tolist(),
            "c": level.astype(np.int64).tolist(),
            "uv": _mm(mesh.unknown_vertices),
            "ut": np.asarray(mesh.unknown_triangles).reshape(-1).tolist(),
            "max_std_mm": round(mesh.max_std_m * MM, 6),
        })

    # The true objects as plot_map draws them: each the grid around the points nearest to it.
    near_of = np.zeros(len(shown), dtype=np.int64)
    if len(shown) and len(layers.true_objects) > 1:
        near_of = np.argmin([t.distance(points[shown]) for t in layers.true_objects], axis=0)
    grids = [wireframe(true, points[shown][near_of == i])
             for i, true in enumerate(layers.true_objects)]
    true = [{"name": t.name, "shape": list(g.shape[1:]), "p": _mm(np.moveaxis(g, 0, -1))}
            for t, g in zip(layers.true_objects, grids, strict=True)]

    path: dict[str, Any] | None = None
    robot: list[FloatArray] = []
    if layers.path is not None:
        p_WR = layers.path.p_WR
        rows = np.unique(np.r_[np.arange(0, len(p_WR), max(1, -(-len(p_WR)
                                                                  // MAX_PATH_SAMPLES))),
                               len(p_WR) - 1])
        clamps = mounts(layers.path, layers.whiskers)
        path = {"p": _mm(p_WR[rows]),
                "mounts": [{"w": index[w.name], "clamp": _mm(p_WC), "tip": _mm(tip)}
                           for w, p_WC, tip in clamps]}
        robot = [p_WR, *[a for _, p_WC, tip in clamps for a in (p_WC, tip)]]

    # The initial view: the objects (contacts in an object, meshes, true objects) and all of
    # the robot's path and mounts, as map.png's top view (its 3D view cuts the path).
    focus: list[FloatArray] = [points[labels >= 0] if np.any(labels >= 0) else points]
    focus += [np.asarray(mesh.vertices).reshape(-1, 3) for mesh in layers.meshes]
    focus += [g.reshape(3, -1).T for g in grids]
    focus = [f for f in [*focus, *robot] if len(f)]
    lo, hi = bounding_box(focus, 0.05) if focus else (np.full(3, -0.05), np.full(3, 0.05))
    return {
        "title": layers.title,
        "subtitle": layers.subtitle,
        "status": layers.status,
        "whiskers": [{"name": name, "colour": _hex(colour),
                      "count": thousands(int(np.sum(ids == name)))}
                     for name, colour in zip(names, colours, strict=True)],
        "points": _mm(points[contact]),
        "w": [index[name] for name in ids[contact]],
        "noise": _mm(points[noise]),
        "n_noise": thousands(int(np.sum(labels < 0))),
        "meshes": meshes,
        "lut": lut,
        "colour_by": layers.colour_by,
        "colour_max_mm": round(top, 6),
        "largest_mm": round(largest, 6),
        "colour_percentile": SCALE_PERCENTILE,
        "true": true,
        "path": path,
        "box": [_mm(lo), _mm(hi)],
    }


def embedded_json(data: Any) -> str:
    """``data`` as JSON that is safe inside a ``<script>`` element: ``<``, ``>`` and ``&``
    written as ``\\u`` escapes, so that no text in it (a whisker's name) can end the element
    or open another."""
    text = json.dumps(data, ensure_ascii=False, separators=(",", ":"), allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def write_page(path: str | Path, layers: MapLayers) -> None:
    """Write the page of ``layers`` to ``path`` (HTML, UTF-8)."""
    html = _PAGE.replace("/*DATA*/", embedded_json(page_data(layers)), 1)
    Path(path).write_text(html, encoding="utf-8")


# The title and status elements are filled by the script (textContent: names are text, never markup).
_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>vibrissa map</title>
<style>
html, body { margin: 0; height: 100%; overflow: hidden; background: #fff;
  font: 13px/1.35 system-ui, sans-serif; color: #222; }
#view { position: absolute; left: 0; top: 0; width: calc(100% - 330px); height: 100%;
  cursor: grab; }
body.nokey #view { width: 100%; }
#head { position: absolute; left: 12px; top: 8px; right: 340px; pointer-events: none; }
#head h1 { font-size: 17px; margin: 0 0 4px 0; font-weight: 600; }
#head p { margin: 0 0 4px 0; font-size: 12px; font-style: italic; color: #333; }
#head p:empty { display: none; }
#head pre { margin: 0; font: 11px/1.3 system-ui, sans-serif; color: #444; white-space: pre-wrap; }
#key { position: absolute; right: 8px; top: 8px; width: 310px; max-height: calc(100% - 16px);
  overflow-y: auto; background: rgba(255,255,255,0.92); border: 1px solid #ccc;
  border-radius: 4px; padding: 8px 10px; box-sizing: border-box; }
#key h2 { font-size: 12px; margin: 6px 0 3px 0; }
#key label { display: block; }
.sw { display: inline-block; width: 10px; height: 10px; border-radius: 50%;
  margin: 0 5px 0 2px; vertical-align: -1px; }
.sq { border-radius: 0; }
#bar { height: 10px; margin: 3px 0 1px 0; }
#bar-ticks { display: flex; justify-content: space-between; font-size: 11px; }
#hint { color: #666; font-size: 11px; margin-top: 6px; }
#fold { float: right; font-size: 11px; cursor: pointer; color: #06c; border: 0;
  background: none; padding: 0; }
#key.folded { width: auto; }
#key.folded > :not(#fold) { display: none; }
</style></head>
<body>
<canvas id="view"></canvas>
<div id="head"><h1 id="title"></h1><p id="status"></p><pre id="subtitle"></pre></div>
<div id="key"></div>
<script type="application/json" id="map-data">/*DATA*/</script>
<script>
"use strict";
const D = JSON.parse(document.getElementById("map-data").textContent);
const canvas = document.getElementById("view");
const ctx = canvas.getContext("2d");
const show = {contacts: true, noise: true, known: true, unknown: true, truth: true, path: true};
let drawn = false;  // the scene is built and drawn once (then a fold of the key redraws it)

function el(tag, text, cls) {
  const e = document.createElement(tag);
  if (text !== undefined) e.textContent = text;
  if (cls) e.className = cls;
  return e;
}
function rgb(hex) {
  return [parseInt(hex.slice(1, 3), 16), parseInt(hex.slice(3, 5), 16),
          parseInt(hex.slice(5, 7), 16)];
}
function plural(n, word) { return n + " " + word + (n === 1 ? "" : "s"); }

// --- the legend: title, a switch per layer, whisker colours, the colour bar ---
document.getElementById("title").textContent = D.title;
document.getElementById("status").textContent = D.status;
document.getElementById("subtitle").textContent = D.subtitle;
document.title = D.title;
const key = document.getElementById("key");
function toggle(name, label, swatch, square) {
  const row = el("label");
  const box = el("input");
  box.type = "checkbox"; box.checked = true;
  box.addEventListener("change", () => { show[name] = box.checked; draw(); });
  row.append(box);
  if (swatch) { const s = el("span", "", square ? "sw sq" : "sw"); s.style.background = swatch;
                row.append(s); }
  row.append(document.createTextNode(label));
  key.append(row);
}
// the key can fold away from what it covers (the robot path runs beyond the objects' box)
const fold = el("button", "hide key"); fold.id = "fold";
fold.addEventListener("click", () => {
  const folded = key.classList.toggle("folded");
  fold.textContent = folded ? "show key" : "hide key";
  document.body.classList.toggle("nokey", folded);  // the scene takes the key's place
  if (drawn) redraw();
});
key.append(fold, el("h2", "layers"));
if (location.hash === "#nokey") fold.click();  // a link to the page without its key
if (D.points.length) toggle("contacts", "contacts, coloured by whisker");
if (D.noise.length) toggle("noise", "noise: " + D.n_noise + " points in no object", "#000");
let nKnown = 0, nUnknown = 0;
for (const m of D.meshes) { nKnown += m.t.length / 3; nUnknown += m.ut.length / 3; }
if (nKnown) toggle("known", "surface estimate, known: " + plural(nKnown, "triangle"),
                   "#21918c", true);
if (nUnknown) {
  const limits = [...new Set(D.meshes.filter(m => m.max_std_mm > 0)
                              .map(m => m.max_std_mm.toPrecision(2)))];
  toggle("unknown", "unknown: std above " + limits.join(" / ") + " mm", "#d9d9d9", true);
}
if (D.true.length) toggle("truth", (D.true.length > 1 ? "true objects (" : "true object (") +
                          D.true.map(t => t.name).join(", ") + ")", "#808080", true);
if (D.path) toggle("path", "robot path, whisker mounts (start, middle, end)", "#000", true);
if (D.whiskers.length) {
  key.append(el("h2", "whiskers"));
  for (const w of D.whiskers) {
    const row = el("div");
    const s = el("span", "", "sw"); s.style.background = w.colour;
    row.append(s, document.createTextNode(w.name + ": " + w.count + " contacts"));
    key.append(row);
  }
}
if (nKnown) {
  key.append(el("h2", D.colour_by + " [mm]"));
  const bar = el("div"); bar.id = "bar";
  const stops = [];
  for (let i = 0; i < D.lut.length; i += 32) stops.push(D.lut[i]);
  stops.push(D.lut[D.lut.length - 1]);
  bar.style.background = "linear-gradient(to right, " + stops.join(", ") + ")";
  const ticks = el("div"); ticks.id = "bar-ticks";
  const above = D.largest_mm > D.colour_max_mm;
  ticks.append(el("span", "0"), el("span", (D.colour_max_mm / 2).toPrecision(2)),
               el("span", D.colour_max_mm.toPrecision(2) + (above ? "+" : "")));
  key.append(bar, ticks, el("div", above
    ? "the end: " + D.colour_percentile + "th percentile of the vertices; the largest " +
      D.largest_mm.toPrecision(2)
    : "the end: the largest", "hint"));
}
key.append(el("div", "drag: rotate, wheel: zoom, shift-drag: pan, double-click: reset",
              "hint"));

// --- the scene as primitives: 0 triangle, 1 point, 2 cross, 3 segment ---
// Each primitive: kind, layer, 2 or 3 vertex indices into P (x, y, z, mm), a fill style.
const P = [];
function vertex(x, y, z) { P.push(x, y, z); return P.length / 3 - 1; }
const prims = [];
function add(kind, layer, a, b, c, style, extra) {
  prims.push({kind, layer, a, b, c, style, extra});
}
function addMesh(v, t, layer, styleOf) {
  const base = P.length / 3;
  for (let i = 0; i < v.length; i += 3) vertex(v[i], v[i + 1], v[i + 2]);
  for (let i = 0; i < t.length; i += 3) {
    const a = base + t[i], b = base + t[i + 1], c = base + t[i + 2];
    // the triangle's unit normal, for flat shading (either side faces the light)
    const ux = P[3*b] - P[3*a], uy = P[3*b+1] - P[3*a+1], uz = P[3*b+2] - P[3*a+2];
    const vx = P[3*c] - P[3*a], vy = P[3*c+1] - P[3*a+1], vz = P[3*c+2] - P[3*a+2];
    let nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    const n = Math.hypot(nx, ny, nz) || 1;
    add(0, layer, a, b, c, styleOf(i / 3), [nx / n, ny / n, nz / n]);
  }
}
for (const m of D.meshes) {
  addMesh(m.uv, m.ut, "unknown", () => null);
  addMesh(m.v, m.t, "known", j => rgb(D.lut[m.c[j]]));
}
const wcol = D.whiskers.map(w => w.colour);
for (let i = 0; i < D.points.length; i += 3) {
  add(1, "contacts", vertex(D.points[i], D.points[i + 1], D.points[i + 2]), -1, -1,
      wcol[D.w[i / 3]]);
}
for (let i = 0; i < D.noise.length; i += 3) {
  add(2, "noise", vertex(D.noise[i], D.noise[i + 1], D.noise[i + 2]), -1, -1, "#000");
}
const labels = [];
for (const t of D.true) {
  const [nu, nv] = t.shape, base = P.length / 3;
  for (let i = 0; i < t.p.length; i += 3) vertex(t.p[i], t.p[i + 1], t.p[i + 2]);
  for (let u = 0; u < nu; u++) for (let v = 0; v < nv; v++) {
    const here = base + u * nv + v;
    if (v + 1 < nv) add(3, "truth", here, here + 1, -1, "rgba(128,128,128,0.7)", 0.6);
    if (u + 1 < nu) add(3, "truth", here, here + nv, -1, "rgba(128,128,128,0.7)", 0.6);
  }
  let sx = 0, sy = 0, zmax = -Infinity;
  for (let i = 0; i < t.p.length; i += 3) {
    sx += t.p[i]; sy += t.p[i + 1]; zmax = Math.max(zmax, t.p[i + 2]);
  }
  const n = t.p.length / 3;
  labels.push({text: t.name, at: vertex(sx / n, sy / n, zmax)});
}
if (D.path) {
  const p = D.path.p, base = P.length / 3;
  for (let i = 0; i < p.length; i += 3) vertex(p[i], p[i + 1], p[i + 2]);
  for (let i = 1; i < p.length / 3; i++) add(3, "path", base + i - 1, base + i, -1, "#000", 1.2);
  for (const m of D.path.mounts) {
    for (let i = 0; i < m.clamp.length; i += 3) {
      const a = vertex(m.clamp[i], m.clamp[i + 1], m.clamp[i + 2]);
      const b = vertex(m.tip[i], m.tip[i + 1], m.tip[i + 2]);
      add(3, "path", a, b, -1, wcol[m.w], 2.0);
      add(1, "path", a, -1, -1, "#000");
    }
  }
}

// --- the view: orthographic, z up, azimuth and elevation as matplotlib's 3D axes ---
const lo = D.box[0], hi = D.box[1];
const centre = [0, 1, 2].map(k => (lo[k] + hi[k]) / 2);
const span = Math.max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) || 1;
const diagonal = Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) || 1;  // fits any view
let az, elev, zoom, pan;
function reset() { az = -60; elev = 30; zoom = 1; pan = [0, 0]; }
reset();
const N = P.length / 3;
const SX = new Float64Array(N), SY = new Float64Array(N), SZ = new Float64Array(N);

function axes() {
  // three axes from the box's low corner, with ticks at round numbers of mm
  const out = [];
  const step = niceStep(span / 5);
  for (let k = 0; k < 3; k++) {
    const from = lo.slice(), to = lo.slice();
    to[k] = hi[k];
    out.push({line: [from, to]});
    for (let x = Math.ceil(lo[k] / step) * step; x <= hi[k] + 1e-9; x += step) {
      const at = lo.slice(); at[k] = x;
      out.push({tick: at, text: fmt(x)});
    }
    const end = lo.slice(); end[k] = hi[k] + 0.06 * span;
    out.push({tick: end, text: "xyz"[k] + " [mm]", bold: true});
  }
  return out;
}
function niceStep(x) {
  const e = Math.pow(10, Math.floor(Math.log10(x)));
  const f = x / e;
  return (f < 1.5 ? 1 : f < 3.5 ? 2 : f < 7.5 ? 5 : 10) * e;
}
function fmt(x) { return Math.abs(x) < 1e-9 ? "0" : (+x.toPrecision(6)).toString(); }

function draw() {
  const W = canvas.clientWidth, H = canvas.clientHeight, dpr = window.devicePixelRatio || 1;
  if (canvas.width !== Math.round(W * dpr) || canvas.height !== Math.round(H * dpr)) {
    canvas.width = Math.round(W * dpr); canvas.height = Math.round(H * dpr);
  }
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, W, H);
  const a = az * Math.PI / 180, e = elev * Math.PI / 180;
  const d = [Math.cos(e) * Math.cos(a), Math.cos(e) * Math.sin(a), Math.sin(e)];  // to viewer
  const r = [-Math.sin(a), Math.cos(a), 0];  // screen right
  const u = [-Math.sin(e) * Math.cos(a), -Math.sin(e) * Math.sin(a), Math.cos(e)];  // up
  const scale = zoom * 0.95 * Math.min(W, H - 60) / diagonal;
  const cx = W / 2 + pan[0], cy = H / 2 + 20 + pan[1];
  for (let i = 0; i < N; i++) {
    const x = P[3*i] - centre[0], y = P[3*i+1] - centre[1], z = P[3*i+2] - centre[2];
    SX[i] = cx + scale * (x * r[0] + y * r[1]);
    SY[i] = cy - scale * (x * u[0] + y * u[1] + z * u[2]);
    SZ[i] = x * d[0] + y * d[1] + z * d[2];
  }
  // the axes first, under the scene
  const project = q => {
    const x = q[0] - centre[0], y = q[1] - centre[1], z = q[2] - centre[2];
    return [cx + scale * (x * r[0] + y * r[1]), cy - scale * (x * u[0] + y * u[1] + z * u[2])];
  };
  ctx.font = "11px system-ui, sans-serif"; ctx.textAlign = "center";
  ctx.textBaseline = "middle";
  for (const item of axes()) {
    if (item.line) {
      const [p, q] = item.line.map(project);
      ctx.strokeStyle = "#555"; ctx.lineWidth = 1;
      ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(q[0], q[1]); ctx.stroke();
    } else {
      const [x, y] = project(item.tick);
      ctx.fillStyle = "#555";
      ctx.font = (item.bold ? "bold " : "") + "11px system-ui, sans-serif";
      if (!item.bold) { ctx.fillRect(x - 1.5, y - 1.5, 3, 3); ctx.fillText(item.text, x, y + 10); }
      else ctx.fillText(item.text, x, y);
    }
  }
  // light from the upper left of the viewer
  const L = [0, 1, 2].map(k => 0.8 * d[k] + 0.45 * u[k] - 0.35 * r[k]);
  const ln = Math.hypot(...L);
  const lift = 0.004 * span;  // points on a surface stay in front of its triangles
  const live = [], depth = [];
  for (const p of prims) {
    if (!show[p.layer]) continue;
    let z;
    if (p.kind === 0) z = (SZ[p.a] + SZ[p.b] + SZ[p.c]) / 3;
    else if (p.kind === 3) z = (SZ[p.a] + SZ[p.b]) / 2;
    else z = SZ[p.a] + lift;
    depth.push(z); live.push(p);
  }
  const order = Array.from(live.keys()).sort((i, j) => depth[i] - depth[j]);
  for (const i of order) {
    const p = live[i];
    if (p.kind === 0) {
      ctx.beginPath();
      ctx.moveTo(SX[p.a], SY[p.a]); ctx.lineTo(SX[p.b], SY[p.b]); ctx.lineTo(SX[p.c], SY[p.c]);
      ctx.closePath();
      if (p.style === null) {
        ctx.fillStyle = "rgba(170,170,170,0.15)"; ctx.fill();
      } else {
        const n = p.extra;
        const lit = 0.35 + 0.65 * Math.abs((n[0] * L[0] + n[1] * L[1] + n[2] * L[2]) / ln);
        const c = p.style;
        ctx.fillStyle = "rgb(" + Math.round(c[0] * lit) + "," + Math.round(c[1] * lit) + "," +
                        Math.round(c[2] * lit) + ")";
        ctx.fill();
        ctx.strokeStyle = ctx.fillStyle; ctx.lineWidth = 0.5; ctx.stroke();  // no seams
      }
    } else if (p.kind === 1) {
      ctx.fillStyle = p.style;
      ctx.beginPath(); ctx.arc(SX[p.a], SY[p.a], 2.2, 0, 2 * Math.PI); ctx.fill();
    } else if (p.kind === 2) {
      ctx.strokeStyle = p.style; ctx.lineWidth = 1.2;
      const x = SX[p.a], y = SY[p.a];
      ctx.beginPath(); ctx.moveTo(x - 4, y - 4); ctx.lineTo(x + 4, y + 4);
      ctx.moveTo(x - 4, y + 4); ctx.lineTo(x + 4, y - 4); ctx.stroke();
    } else {
      ctx.strokeStyle = p.style; ctx.lineWidth = p.extra;
      ctx.beginPath(); ctx.moveTo(SX[p.a], SY[p.a]); ctx.lineTo(SX[p.b], SY[p.b]); ctx.stroke();
    }
  }
  if (show.truth) {
    ctx.fillStyle = "#4d4d4d"; ctx.font = "italic 12px system-ui, sans-serif";
    for (const l of labels) ctx.fillText(l.text, SX[l.at], SY[l.at] - 10);
  }
  return order.length;
}

// --- interaction ---
let drag = null, pending = false;
function redraw() {
  if (pending) return;
  pending = true;
  requestAnimationFrame(() => { pending = false; draw(); });
}
canvas.addEventListener("pointerdown", ev => {
  drag = {x: ev.clientX, y: ev.clientY, pan: ev.shiftKey || ev.button !== 0};
  canvas.setPointerCapture(ev.pointerId); canvas.style.cursor = "grabbing";
});
canvas.addEventListener("pointermove", ev => {
  if (!drag) return;
  const dx = ev.clientX - drag.x, dy = ev.clientY - drag.y;
  drag.x = ev.clientX; drag.y = ev.clientY;
  if (drag.pan) { pan[0] += dx; pan[1] += dy; }
  else { az -= 0.4 * dx; elev = Math.max(-90, Math.min(90, elev + 0.4 * dy)); }
  redraw();
});
canvas.addEventListener("pointerup", () => { drag = null; canvas.style.cursor = "grab"; });
canvas.addEventListener("contextmenu", ev => ev.preventDefault());
canvas.addEventListener("wheel", ev => {
  ev.preventDefault();
  zoom *= Math.exp(-0.0015 * ev.deltaY);
  redraw();
}, {passive: false});
canvas.addEventListener("dblclick", () => { reset(); redraw(); });
window.addEventListener("resize", redraw);
document.body.dataset.drawn = String(draw());
drawn = true;
</script>
</body></html>
"""
