// Traces over time, drawn on plain canvases:
// - click a sensor on any heat map: its raw counts over the last 10 s, with the baseline the heat
//   maps subtract and its noise band (baseline ± 3 σ of its untouched frames), updated 4 times/s;
// - the Live page: each track's strength and position (x, y, z) over the last 10 s, as
//   Foxglove's Plot panel draws them;
// - click a touch in a touch list: its mean image, and its frames one by one (a slider) with the
//   peak sensor and the total over the frames.
import { drawHeat } from "/static/heatmap.js";

const TRACE_S = 10;
const COLOURS = document.querySelector('meta[name="skinloc-track-colours"]')?.content.split(" ") ?? ["#2f6fde"];

// A canvas sized for its CSS box at the screen's pixel ratio; its 2D context in CSS pixels.
function context(canvas, cssH) {
  const dpr = window.devicePixelRatio || 1;
  const cssW = canvas.clientWidth || 400;
  if (canvas.width !== Math.round(cssW * dpr) || canvas.height !== Math.round(cssH * dpr)) {
    canvas.width = Math.round(cssW * dpr);
    canvas.height = Math.round(cssH * dpr);
    canvas.style.height = `${cssH}px`;
  }
  const g = canvas.getContext("2d");
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, cssW, cssH);
  return [g, cssW, cssH];
}

// Round ticks over [lo, hi].
function ticks(lo, hi, n = 4) {
  const raw = (hi - lo) / n || 1;
  const p = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * p).find((s) => s >= raw);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) out.push(+v.toFixed(6));
  return out;
}

// Axes of a plot box; returns the value-to-pixel maps.
function axes(g, box, [x0, x1], [y0, y1], { xLabel = "", yLabel = "" } = {}) {
  const { L, T, W, H } = box;
  const X = (x) => L + ((x - x0) / (x1 - x0 || 1)) * W;
  const Y = (y) => T + H - ((y - y0) / (y1 - y0 || 1)) * H;
  g.strokeStyle = "#c5cad4";
  g.lineWidth = 1;
  g.strokeRect(L + 0.5, T + 0.5, W, H);
  g.fillStyle = "#6b7385";
  g.font = "10px system-ui, sans-serif";
  g.textAlign = "right";
  g.textBaseline = "middle";
  for (const v of ticks(y0, y1)) g.fillText(String(v), L - 3, Y(v));
  g.textAlign = "center";
  g.textBaseline = "top";
  for (const v of ticks(x0, x1, 5)) g.fillText(String(v), X(v), T + H + 3);
  if (xLabel) g.fillText(xLabel, L + W / 2, T + H + 15);
  if (yLabel) {
    g.save();
    g.translate(9, T + H / 2);
    g.rotate(-Math.PI / 2);
    g.fillText(yLabel, 0, -6);
    g.restore();
  }
  return [X, Y];
}

function line(g, xs, ys, X, Y, colour, dash = []) {
  if (!xs.length) return;
  g.strokeStyle = colour;
  g.lineWidth = 1.4;
  g.setLineDash(dash);
  g.beginPath();
  xs.forEach((x, i) => (i ? g.lineTo(X(x), Y(ys[i])) : g.moveTo(X(x), Y(ys[i]))));
  g.stroke();
  g.setLineDash([]);
}

// A floating panel with a title and a close button; one of each kind at a time.
function popup(kind, title) {
  let el = document.querySelector(`.trace-pop[data-kind="${kind}"]`);
  if (!el) {
    el = document.createElement("div");
    el.className = "trace-pop";
    el.dataset.kind = kind;
    el.innerHTML = `<div class="trace-head"><b class="trace-title"></b><button type="button" class="small trace-close" title="close">×</button></div><div class="trace-body"></div>`;
    document.body.appendChild(el);
    el.querySelector(".trace-close").addEventListener("click", () => el.dispatchEvent(new Event("close")));
  }
  el.querySelector(".trace-title").textContent = title;
  el.classList.remove("hidden");
  return el;
}

// ------------------------------------------------------------------ a sensor's trace
export class SensorTrace {
  constructor() {
    this.sensor = null;
    this.timer = null;
    // Any heat map: a click on a cell opens that sensor's trace (the cell geometry is the one
    // drawHeat keeps on the canvas).
    document.addEventListener("click", (ev) => {
      const c = ev.target;
      if (!(c instanceof HTMLCanvasElement) || !c._heat) return;
      const h = c._heat, r = c.getBoundingClientRect();
      const j = Math.floor((ev.clientX - r.left - h.pad) / h.cell);
      const i = Math.floor((ev.clientY - r.top - h.pad) / h.cell);
      if (i >= 0 && j >= 0 && i < h.tx && j < h.rx) this.open(i, j);
    });
  }

  open(tx, rx) {
    this.sensor = [tx, rx];
    this.el = popup("sensor", `Sensor TX ${tx}, RX ${rx}: last ${TRACE_S} s`);
    this.el.dataset.tx = tx;
    this.el.dataset.rx = rx;
    const body = this.el.querySelector(".trace-body");
    if (!body.querySelector("canvas")) {
      body.innerHTML = `<canvas class="trace-canvas"></canvas><div class="hint trace-note"></div>`;
      this.el.addEventListener("close", () => this.close());
    }
    clearInterval(this.timer);
    this.timer = setInterval(() => this.poll(), 250);
    this.poll();
  }

  close() {
    clearInterval(this.timer);
    this.timer = null;
    this.sensor = null;
    this.el?.classList.add("hidden");
  }

  async poll() {
    if (!this.sensor) return;
    const [tx, rx] = this.sensor;
    const r = await fetch(`/api/trace/sensor?tx=${tx}&rx=${rx}&seconds=${TRACE_S}`).catch(() => null);
    const d = r?.ok ? await r.json() : null;
    if (!d || !this.sensor || d.tx !== this.sensor[0] || d.rx !== this.sensor[1]) {
      if (r && !r.ok) this.el.querySelector(".trace-note").textContent = (await r.json().catch(() => ({}))).detail || "no trace";
      return;
    }
    this.draw(d);
  }

  draw(d) {
    const canvas = this.el.querySelector("canvas");
    const [g, w, h] = context(canvas, 190);
    const box = { L: 48, T: 8, W: w - 58, H: h - 40 };
    const vals = d.counts;
    const band = d.baseline != null && d.noise != null ? [d.baseline - d.band_sigma * d.noise, d.baseline + d.band_sigma * d.noise] : null;
    const all = [...vals, ...(band || []), ...(d.baseline != null ? [d.baseline] : [])];
    let lo = Math.min(...all), hi = Math.max(...all);
    if (!Number.isFinite(lo)) [lo, hi] = [0, 1];
    const pad = Math.max((hi - lo) * 0.08, 2);
    const [X, Y] = axes(g, box, [-TRACE_S, 0], [lo - pad, hi + pad], { xLabel: "s before now", yLabel: "counts" });
    if (band) {
      g.fillStyle = "rgba(47,111,222,0.13)";
      g.fillRect(box.L, Y(band[1]), box.W, Y(band[0]) - Y(band[1]));
    }
    if (d.baseline != null) line(g, [-TRACE_S, 0], [d.baseline, d.baseline], X, Y, "#6b7385", [5, 4]);
    line(g, d.t_s, vals, X, Y, "#d1493b");
    this.el.dataset.points = String(vals.length);
    const last = vals.length ? vals[vals.length - 1] : null;
    this.el.querySelector(".trace-note").textContent = d.baseline == null
      ? "No baseline yet (the zero level is measured first)."
      : `now ${last ?? "-"} counts; baseline ${d.baseline.toFixed(1)} (dashed); band ± ${d.band_sigma} σ = ± ${(d.band_sigma * (d.noise ?? 0)).toFixed(1)} counts (noise from untouched frames)`;
  }
}

// ------------------------------------------------------------------ the live tracks over time
export class LivePlot {
  constructor(after) {
    this.el = document.createElement("div");
    this.el.className = "live-plot";
    this.el.innerHTML = `<h3>Over time <small>last ${TRACE_S} s, one colour per track</small></h3>
      <canvas class="plot-strength"></canvas><canvas class="plot-position"></canvas>
      <div class="hint">Position: x solid, y dashed, z dotted (mm).</div>`;
    after.after(this.el);
    this.tracks = new Map(); // track id -> {colour, t: [], s: [], x: [], y: [], z: []}
    this.now = null;
    this.pending = false;
    // Contacts come only while something touches: between them the plot keeps moving on the
    // page's clock (stream time = page time - offset), so old tracks scroll out, not freeze.
    this.offset = null;
    this.ticker = null;
  }

  tick() {
    if (!this.tracks.size || this.offset === null) {
      clearInterval(this.ticker);
      this.ticker = null;
      return;
    }
    this.now = Math.max(this.now, performance.now() / 1000 - this.offset);
    this.draw();
  }

  add(msg) {
    const t = msg.timestamp_s;
    if (!Number.isFinite(t)) return;
    this.now = t;
    this.offset = performance.now() / 1000 - t;
    if (!this.ticker) this.ticker = setInterval(() => this.tick(), 250);
    for (const c of msg.contacts || []) {
      if (c.state === "idle" || !c.position_m || c.position_m[0] == null) continue;
      const id = c.track_id >= 0 ? c.track_id : c.touch_id;
      let tr = this.tracks.get(id);
      if (!tr) {
        tr = { colour: COLOURS[(c.colour ?? 0) % COLOURS.length], t: [], s: [], x: [], y: [], z: [] };
        this.tracks.set(id, tr);
      }
      tr.t.push(t);
      tr.s.push(c.strength ?? NaN);
      tr.x.push(c.position_m[0] * 1000);
      tr.y.push(c.position_m[1] * 1000);
      tr.z.push(c.position_m[2] * 1000);
    }
    if (!this.pending) {
      this.pending = true;
      setTimeout(() => { this.pending = false; this.draw(); }, 100);
    }
  }

  clear() {
    this.tracks.clear();
    this.now = null;
    this.offset = null;
    this.draw();
  }

  draw() {
    const now = this.now;
    for (const [id, tr] of this.tracks) {
      let k = 0;
      while (k < tr.t.length && now - tr.t[k] > TRACE_S) k++;
      if (k) for (const a of ["t", "s", "x", "y", "z"]) tr[a].splice(0, k);
      if (!tr.t.length) this.tracks.delete(id);
    }
    const rel = (tr) => tr.t.map((t) => t - now);
    const plot = (canvas, keys, label) => {
      const [g, w, h] = context(canvas, 120);
      const box = { L: 48, T: 6, W: w - 58, H: h - 34 };
      const vals = [...this.tracks.values()].flatMap((tr) => keys.flatMap((k) => tr[k])).filter(Number.isFinite);
      let lo = vals.length ? Math.min(...vals) : 0, hi = vals.length ? Math.max(...vals) : 1;
      const pad = Math.max((hi - lo) * 0.08, 1);
      const [X, Y] = axes(g, box, [-TRACE_S, 0], [lo - pad, hi + pad], { xLabel: "s before now", yLabel: label });
      for (const tr of this.tracks.values()) {
        keys.forEach((k, n) => line(g, rel(tr), tr[k], X, Y, tr.colour, [[], [5, 3], [1.5, 2.5]][n]));
      }
    };
    plot(this.el.querySelector(".plot-strength"), ["s"], "strength");
    plot(this.el.querySelector(".plot-position"), ["x", "y", "z"], "mm");
    this.el.dataset.tracks = String(this.tracks.size);
    this.el.dataset.points = String([...this.tracks.values()].reduce((n, tr) => n + tr.t.length, 0));
  }
}

// ------------------------------------------------------------------ a recorded touch
export class TouchView {
  constructor({ esc }) {
    this.esc = esc;
    // A click on a touch's row (not on its buttons) in the Calibrate or Validate touch list.
    document.addEventListener("click", (ev) => {
      const row = ev.target.closest?.(".guided .touches tbody tr");
      if (!row || ev.target.closest("button, input, a")) return;
      // The row's touch (0-based) and its name: its target's number, "#6 (2nd)" for a retake.
      const i = Number(row.dataset.index);
      if (row.dataset.index === undefined || !Number.isInteger(i) || i < 0) return;
      const kind = row.closest(".guided").dataset.kind;
      this.open(i, kind === "validate" ? "validation" : "calibration", row.cells[0]?.textContent);
    });
  }

  async open(index, recording, name = `#${index + 1}`) {
    const r = await fetch(`/api/session/touch?index=${index}&recording=${recording}`).catch(() => null);
    const d = r ? await r.json().catch(() => null) : null;
    const el = popup("touch", `${recording === "validation" ? "Validation" : "Calibration"} touch ${name}`);
    this.el = el;
    if (!r?.ok || !d) {
      el.querySelector(".trace-body").innerHTML = `<p class="hint">${this.esc(d?.detail || "cannot read the touch")}</p>`;
      return;
    }
    if (!el.dataset.wired) {
      el.dataset.wired = "1";
      el.addEventListener("close", () => el.classList.add("hidden"));
    }
    el.dataset.index = index;
    el.dataset.frames = d.frames.length;
    const flags = d.flags.length ? ` <span class="flag">${this.esc(d.flags.join(", "))}</span>` : "";
    el.querySelector(".trace-body").innerHTML = `
      <div class="hint">target ${d.target.map((x) => (x * 1000).toFixed(1)).join(", ")} mm; ${d.frames.length} frames${flags}</div>
      <div class="touch-maps">
        <div><h3>Mean image</h3><canvas class="heat touch-mean"></canvas></div>
        <div><h3>Frame <span class="frame-no">1</span> of ${d.frames.length}</h3><canvas class="heat touch-frame"></canvas></div>
      </div>
      <input type="range" class="frame-slider" min="1" max="${d.frames.length}" value="1" aria-label="frame">
      <canvas class="touch-series"></canvas>
      <div class="hint">Over the frames: the peak sensor of the mean image (solid) and the mean over all sensors (dashed), counts above the baseline.</div>`;
    // One colour scale for the mean and every frame: the largest magnitude of the touch.
    const scale = Math.max(10, ...d.frames.flat().map(Math.abs));
    drawHeat(el.querySelector(".touch-mean"), d.mean, d.tx, d.rx, { scale, unit: "counts" });
    const slider = el.querySelector(".frame-slider");
    const show = () => {
      const k = Number(slider.value) - 1;
      el.querySelector(".frame-no").textContent = String(k + 1);
      drawHeat(el.querySelector(".touch-frame"), d.frames[k], d.tx, d.rx, { scale, unit: "counts" });
      this.series(d, k);
    };
    slider.addEventListener("input", show);
    show();
  }

  series(d, current) {
    const canvas = this.el.querySelector(".touch-series");
    const [g, w, h] = context(canvas, 110);
    const box = { L: 48, T: 6, W: w - 58, H: h - 34 };
    const peak = d.mean.indexOf(Math.max(...d.mean));
    const xs = d.frames.map((_, k) => k + 1);
    const top = d.frames.map((f) => f[peak]);
    const avg = d.frames.map((f) => f.reduce((a, b) => a + b, 0) / f.length);
    const all = [...top, ...avg];
    const lo = Math.min(0, ...all), hi = Math.max(1, ...all);
    const [X, Y] = axes(g, box, [1, Math.max(2, xs.length)], [lo, hi * 1.08], { xLabel: "frame", yLabel: "counts" });
    line(g, xs, top, X, Y, "#d1493b");
    line(g, xs, avg, X, Y, "#2f6fde", [5, 3]);
    g.strokeStyle = "#1d2330";
    g.beginPath();
    g.moveTo(X(current + 1), box.T);
    g.lineTo(X(current + 1), box.T + box.H);
    g.stroke();
  }
}
