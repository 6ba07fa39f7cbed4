// The Train page's evidence: each touch's error when predicted by a model that did not see it
// (cross-validated, or the held-out check's touches only), as a dot on the 3D skin coloured by
// its error and as a histogram with the mean and p95 marked.
import * as THREE from "/static/vendor/three.bundle.min.js";
import { errorColor } from "/static/viewer.js";

const MM = 1000;

// ``k`` as an ordinal: 1st, 2nd, 3rd, 4th, ... 11th, 21st.
export const ordinal = (k) => `${k}${k % 100 >= 10 && k % 100 <= 20 ? "th" : ({ 1: "st", 2: "nd", 3: "rd" }[k % 10] || "th")}`;
// A touch by its target's number for life: "#6", and a retake "#6 (2nd)".
export const touchName = (number, attempt = 1) => `#${number}${attempt > 1 ? ` (${ordinal(attempt)})` : ""}`;

// A round bin width giving about ``want`` bins over [0, hi].
function binWidth(hi, want = 10) {
  const raw = Math.max(hi, 1e-9) / want;
  const p = 10 ** Math.floor(Math.log10(raw));
  return [1, 2, 2.5, 5, 10].map((m) => m * p).find((w) => w >= raw);
}

// The top of the colour scale, mm: the errors' p95 rounded up (20 mm at least, as on Validate),
// so that a session of large errors still shows which touches are worse.
export function scaleTop(errors) {
  const e = errors.filter((x) => Number.isFinite(x)).sort((a, b) => a - b);
  const p95 = e.length ? quantile(e, 0.95) : 0;
  if (p95 <= 20) return 20;
  const step = binWidth(p95, 10);
  return Math.ceil(p95 / step) * step;
}
// ``mm`` on the scale [0, top] in the colours of the validation errors (green to red).
export const scaledColour = (mm, top) => errorColor((20 * mm) / top);

const quantile = (sorted, q) => {
  const x = (sorted.length - 1) * q, k = Math.floor(x);
  return k + 1 < sorted.length ? sorted[k] + (x - k) * (sorted[k + 1] - sorted[k]) : sorted[k];
};

// The histogram of ``errors`` (mm) as SVG: one bar a bin (its count above it, the touches in
// its title), the mean and the 95th percentile as dashed lines.
export function histogramSvg(errors, { width = 420, height = 190 } = {}) {
  const e = errors.filter((x) => Number.isFinite(x));
  if (!e.length) return "";
  const sorted = [...e].sort((a, b) => a - b);
  const mean = e.reduce((a, b) => a + b, 0) / e.length;
  const p95 = quantile(sorted, 0.95);
  const w = binWidth(sorted[sorted.length - 1]);
  const nBins = Math.max(1, Math.ceil((sorted[sorted.length - 1] + 1e-9) / w));
  const counts = new Array(nBins).fill(0);
  for (const x of e) counts[Math.min(nBins - 1, Math.floor(x / w))] += 1;
  const L = 34, R = 10, T = 34, B = 30, pw = width - L - R, ph = height - T - B;
  const top = Math.max(...counts);
  const hi = scaleTop(e);
  const X = (mm) => L + (mm / (nBins * w)) * pw;
  const Y = (n) => T + ph - (n / top) * ph;
  const out = [`<svg class="hist" xmlns="http://www.w3.org/2000/svg" width="${width}" height="${height}" viewBox="0 0 ${width} ${height}" role="img" aria-label="histogram of the errors">`];
  counts.forEach((n, k) => {
    if (!n) return;
    const x0 = X(k * w), x1 = X((k + 1) * w);
    const colour = `#${scaledColour((k + 0.5) * w, hi).getHexString()}`;
    out.push(`<rect class="bin" data-count="${n}" x="${(x0 + 1).toFixed(1)}" y="${Y(n).toFixed(1)}" width="${Math.max(1, x1 - x0 - 2).toFixed(1)}" height="${(T + ph - Y(n)).toFixed(1)}" fill="${colour}"><title>${n} touch${n > 1 ? "es" : ""}, ${(k * w).toFixed(1)} to ${((k + 1) * w).toFixed(1)} mm</title></rect>`);
    out.push(`<text x="${((x0 + x1) / 2).toFixed(1)}" y="${(Y(n) - 3).toFixed(1)}" font-size="10" text-anchor="middle" fill="#1d2330">${n}</text>`);
  });
  out.push(`<line x1="${L}" y1="${T + ph}" x2="${L + pw}" y2="${T + ph}" stroke="#667"/>`);
  const ticks = nBins <= 12 ? nBins : Math.ceil(nBins / 2);
  for (let k = 0; k <= nBins; k += Math.ceil(nBins / ticks)) {
    out.push(`<text x="${X(k * w).toFixed(1)}" y="${T + ph + 13}" font-size="10" text-anchor="middle" fill="#556">${+(k * w).toFixed(1)}</text>`);
  }
  out.push(`<text x="${L + pw / 2}" y="${height - 3}" font-size="11" text-anchor="middle" fill="#556">error (mm)</text>`);
  out.push(`<text x="10" y="${T + ph / 2}" font-size="11" text-anchor="middle" fill="#556" transform="rotate(-90 10 ${T + ph / 2})">touches</text>`);
  for (const [v, name] of [[mean, "mean"], [p95, "p95"]]) {
    out.push(`<line class="mark-${name}" x1="${X(v).toFixed(1)}" y1="${name === "mean" ? 12 : 24}" x2="${X(v).toFixed(1)}" y2="${T + ph}" stroke="#1d2330" stroke-dasharray="4 3"/>`);
    // The label on the side with room (the p95 line is often near the right end).
    const right = X(v) > L + pw - 60;
    out.push(`<text x="${(X(v) + (right ? -3 : 3)).toFixed(1)}" y="${name === "mean" ? 10 : 22}" font-size="10" text-anchor="${right ? "end" : "start"}" fill="#1d2330">${name} ${v.toFixed(1)}</text>`);
  }
  out.push("</svg>");
  return out.join("");
}

// The real skin's curves and the probing floor (GET /api/accuracy/reference), drawn beside the
// session's own; fetched once, the chart shows the session's curves alone until they arrive.
let reference = null;
export const referenceReady = fetch("/api/accuracy/reference")
  .then((r) => (r.ok ? r.json() : null))
  .then((j) => { reference = j; })
  .catch(() => {});

const CURVE_STYLE = {
  prior: { colour: "#2563eb", label: "this session, with the prior" },
  noPrior: { colour: "#d97706", label: "this session, without" },
  "default": { colour: "#2563eb", dash: "5 4", label: "real skin, with the prior" },
  "default, no prior": { colour: "#d97706", dash: "5 4", label: "real skin, without" },
  paper: { colour: "#6b7280", dash: "2 3", label: "real skin, the paper's network" },
};

// Error against calibration touches as SVG: the session's held-out error with and without the
// map prior (``curve``: prior_curve's sizes, prior_mm, no_prior_mm), the real skin's reference
// curves dashed, and the probing floor dotted. Touches on a log axis.
export function curveSvg(curve, ref = reference, { width = 420, height = 210 } = {}) {
  if (!curve?.sizes?.length) return "";
  const lines = [
    ["prior", curve.sizes, curve.prior_mm],
    ["noPrior", curve.sizes, curve.no_prior_mm],
  ];
  for (const [name, c] of Object.entries(ref?.curves ?? {})) {
    if (CURVE_STYLE[name]) lines.push([name, c.sizes, c.mean_mm]);
  }
  const floor = ref?.probing_floor_mm;
  const xs = lines.flatMap(([, x]) => x), ys = lines.flatMap(([, , y]) => y).filter(Number.isFinite);
  const x0 = Math.log(Math.min(...xs)), x1 = Math.log(Math.max(...xs) * 1.05);
  const yTop = Math.max(...ys, floor ?? 0) * 1.08;
  const L = 36, R = 10, T = 10, B = 64, pw = width - L - R, ph = height - T - B;
  const X = (n) => L + ((Math.log(n) - x0) / Math.max(x1 - x0, 1e-9)) * pw;
  const Y = (mm) => T + ph - (mm / yTop) * ph;
  const out = [`<svg class="curve" xmlns="http://www.w3.org/2000/svg" width="${width}" height="${height}" viewBox="0 0 ${width} ${height}" role="img" aria-label="error against calibration touches">`];
  out.push(`<line x1="${L}" y1="${T + ph}" x2="${L + pw}" y2="${T + ph}" stroke="#667"/><line x1="${L}" y1="${T}" x2="${L}" y2="${T + ph}" stroke="#667"/>`);
  for (const n of [...new Set(xs)].sort((a, b) => a - b)) {
    out.push(`<text x="${X(n).toFixed(1)}" y="${T + ph + 12}" font-size="10" text-anchor="middle" fill="#556">${n}</text>`);
  }
  const step = binWidth(yTop, 4);
  for (let v = 0; v <= yTop; v += step) {
    out.push(`<text x="${L - 3}" y="${(Y(v) + 3).toFixed(1)}" font-size="10" text-anchor="end" fill="#556">${+v.toFixed(1)}</text>`);
  }
  out.push(`<text x="${L + pw / 2}" y="${T + ph + 25}" font-size="11" text-anchor="middle" fill="#556">calibration touches</text>`);
  out.push(`<text x="9" y="${T + ph / 2}" font-size="11" text-anchor="middle" fill="#556" transform="rotate(-90 9 ${T + ph / 2})">mean error (mm)</text>`);
  if (Number.isFinite(floor)) {
    out.push(`<line class="floor" x1="${L}" y1="${Y(floor).toFixed(1)}" x2="${L + pw}" y2="${Y(floor).toFixed(1)}" stroke="#059669" stroke-dasharray="1 3"><title>probing floor ${floor} mm</title></line>`);
  }
  const legend = [];
  for (const [name, sx, sy] of lines) {
    const st = CURVE_STYLE[name];
    const pts = sx.map((n, k) => [n, sy[k]]).filter(([, y]) => Number.isFinite(y));
    if (!pts.length) continue;
    const d = pts.map(([n, y], k) => `${k ? "L" : "M"}${X(n).toFixed(1)},${Y(y).toFixed(1)}`).join("");
    out.push(`<path class="line-${name.replace(/[^a-z]+/gi, "-")}" d="${d}" fill="none" stroke="${st.colour}" stroke-width="${name === "prior" || name === "noPrior" ? 2 : 1.3}"${st.dash ? ` stroke-dasharray="${st.dash}"` : ""}><title>${st.label}: ${pts.map(([n, y]) => `${n}: ${y} mm`).join(", ")}</title></path>`);
    legend.push([st, name]);
  }
  if (Number.isFinite(floor)) legend.push([{ colour: "#059669", dash: "1 3", label: `probing floor ${floor} mm` }, "floor"]);
  legend.forEach(([st, name], k) => {
    const lx = L + (k % 2) * (pw / 2), ly = T + ph + 38 + Math.floor(k / 2) * 12;
    out.push(`<line x1="${lx}" y1="${ly - 3}" x2="${lx + 16}" y2="${ly - 3}" stroke="${st.colour}" stroke-width="${name === "prior" || name === "noPrior" ? 2 : 1.3}"${st.dash ? ` stroke-dasharray="${st.dash}"` : ""}/><text x="${lx + 20}" y="${ly}" font-size="10" fill="#1d2330">${st.label}</text>`);
  });
  out.push("</svg>");
  return out.join("");
}

export class TrainEvidence {
  constructor(viewer) {
    this.viewer = viewer;
    this.group = new THREE.Group();
    this.group.name = "touch-errors";
    this.group.visible = false;
    viewer.scene.add(this.group);
    // One of the view's groups: its numbers are placed by the label layer (view_labels.js).
    viewer.groups.evidence = this.group;
    this.geometry = new THREE.SphereGeometry(2.4, 14, 10);
    this.key = "";
  }

  // The evidence's HTML under the training result (``h``: the session's held-out result).
  html(h) {
    const te = h?.touch_errors;
    if (!te?.error_mm?.length) return "";
    const order = te.index.map((_, k) => [te.error_mm[k], this.name(te, k)]).sort((a, b) => b[0] - a[0]);
    const worst = order.slice(0, 3).map(([e, name]) => `${name}: ${e.toFixed(1)} mm`).join(", ");
    return `<div class="evidence">
      <h3>Error of each touch <small>predicted by a model that did not see it (${te.how}, ${te.error_mm.length} touches)</small></h3>
      ${histogramSvg(te.error_mm)}
      <p class="hint">Worst: ${worst}. On the 3D view each touch is a dot at its target, numbered and coloured by its error:
      <span class="err-scale"><span class="bar"></span> 0 to ≥ ${scaleTop(te.error_mm)} mm</span></p></div>${this.curveHtml(h)}`;
  }

  // The session's error against calibration touches with and without the map prior.
  curveHtml(h) {
    const c = h?.prior_curve;
    if (!c?.sizes?.length) return "";
    const ref = reference ? ` Dashed: the real skin (trained on ${reference.trained_on}, tested on ${reference.tested_on.join(", ")}).` : "";
    return `<div class="prior-curve"><h3>Error against touches <small>this session's held-out touches, models of evenly spread subsets with the map prior and without</small></h3>
      ${curveSvg(c)}<p class="hint">The prior is used up to the touches where it helped on simulated skins; above, both are one model.${ref}</p></div>`;
  }

  // Touch ``k`` of ``te``: its target's number (older results: its position).
  name(te, k) {
    return touchName(te.number?.[k] ?? te.index[k] + 1, te.attempt?.[k] ?? 1);
  }

  // The dots on the skin: ``h.touch_errors`` placed at the calibration's targets ``done``,
  // each with its touch's number.
  update(h, done) {
    const te = h?.touch_errors;
    const key = te && done ? `${te.index.join(",")}:${te.error_mm.join(",")}:${done.length}` : "";
    if (key === this.key) return;
    this.key = key;
    while (this.group.children.length) {
      const c = this.group.children.pop();
      c.material?.dispose(); // the numbers are bare objects
    }
    this.viewer.labelsVersion += 1;
    if (te && done) {
      const top = scaleTop(te.error_mm);
      te.index.forEach((i, k) => {
        if (!done[i]) return;
        const m = new THREE.Mesh(this.geometry, new THREE.MeshStandardMaterial({ color: scaledColour(te.error_mm[k], top) }));
        m.position.set(done[i][0] * MM, done[i][1] * MM, done[i][2] * MM);
        m.userData = { index: i, error_mm: te.error_mm[k] };
        this.group.add(m);
        this.group.add(this.viewer._label(this.name(te, k).slice(1), m.position.clone(), 2.4));
      });
    }
    this.viewer.dirty = true;
  }

  setVisible(on) {
    if (this.group.visible !== on) this.viewer.dirty = true;
    this.group.visible = on;
  }
}
