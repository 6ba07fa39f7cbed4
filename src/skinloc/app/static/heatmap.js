// A TX x RX heat map on a canvas, with flagged sensors and lines marked, its colour scale with
// units underneath, and the value of the cell under the mouse.

const LEGEND_H = 30;

// A "nice" scale at or above v: 1, 2 or 5 x 10^k (so it does not flicker with every frame).
function niceCeil(v) {
  const p = 10 ** Math.floor(Math.log10(Math.max(v, 1e-9)));
  for (const m of [1, 2, 5, 10]) if (m * p >= v) return m * p;
  return 10 * p;
}

// The scale of a map whose caller gives none: steady, robust, lockable. It follows the second
// largest |value| of the sensors not flagged noisy or dead (one wild sensor saturates instead
// of setting the scale for all), rounded up to a nice step; it rises at once and falls only
// after 2 s below the next step down. A locked scale stays as it is (the box under the map).
const SCALE_FALL_MS = 2000;
function steadyScale(canvas, values, minScale, status) {
  const st = canvas._scale || (canvas._scale = { value: 0, lowSince: null, locked: false });
  if (st.locked && st.value) return st.value;
  const mags = (values || []).map((v, k) => (Number.isFinite(v) && !["noisy", "dead"].includes(status?.[k]) ? Math.abs(v) : 0))
    .sort((a, b) => b - a);
  const robust = mags.length > 1 ? mags[1] : mags[0] || 0;
  const want = niceCeil(Math.max(minScale, robust));
  const now = performance.now();
  if (want >= st.value) {
    st.value = want;
    st.lowSince = null;
  } else if (st.lowSince == null) {
    st.lowSince = now;
  } else if (now - st.lowSince > SCALE_FALL_MS) {
    st.value = want;
    st.lowSince = null;
  }
  return st.value;
}

// Under a map of sensors: the lock of its scale and what the outlines mean.
function addControls(canvas, withStatus) {
  if (canvas._controls) return canvas._controls;
  const box = document.createElement("div");
  box.className = "heat-controls hint";
  box.innerHTML = `<label class="check" title="keep the colour scale as it is now"><input type="checkbox" class="heat-lock"> lock scale</label>` +
    (withStatus ? `<div class="heat-key" title="outlines: flagged sensors and lines"><span class="key noisy"></span>noisy
      <span class="key weak"></span>weak <span class="key dead"></span>dead <span class="key line"></span>flagged line</div>` : "");
  canvas.insertAdjacentElement("afterend", box);
  const lock = box.querySelector(".heat-lock");
  lock.addEventListener("change", () => {
    const st = canvas._scale || (canvas._scale = { value: 0, lowSince: null, locked: false });
    st.locked = lock.checked;
    lock.blur(); // the capture keys stay with the page
  });
  canvas._controls = box;
  return box;
}

function colour(t) {
  // t in [-1, 1]: blue below zero, white at zero, yellow -> red above.
  if (t < 0) {
    const k = Math.min(1, -t);
    return `rgb(${Math.round(255 - 170 * k)},${Math.round(255 - 120 * k)},255)`;
  }
  const k = Math.min(1, t);
  if (k < 0.5) {
    const u = k / 0.5;
    return `rgb(255,255,${Math.round(255 - 200 * u)})`;
  }
  const u = (k - 0.5) / 0.5;
  return `rgb(${Math.round(255 - 40 * u)},${Math.round(255 - 200 * u)},${Math.round(55 - 40 * u)})`;
}

export function drawHeat(canvas, values, tx, rx, opts = {}) {
  if (!canvas) return;
  const dpr = window.devicePixelRatio || 1;
  const cssW = canvas.clientWidth || 300;
  const pad = 26;
  const cell = (cssW - pad - 4) / rx;
  const cssH = pad + cell * tx + 4 + LEGEND_H;
  if (canvas.width !== Math.round(cssW * dpr) || canvas.height !== Math.round(cssH * dpr)) {
    canvas.width = Math.round(cssW * dpr);
    canvas.height = Math.round(cssH * dpr);
    canvas.style.height = `${cssH}px`;
    canvas.style.aspectRatio = "auto";
  }
  const g = canvas.getContext("2d");
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, cssW, cssH);
  const status = opts.status || [];
  const badTx = new Map((opts.txLines || []).map((l) => [l.index, l.status]));
  const badRx = new Map((opts.rxLines || []).map((l) => [l.index, l.status]));
  let scale = opts.scale;
  if (!scale) {
    scale = steadyScale(canvas, values, opts.minScale ?? 40, opts.status);
    addControls(canvas, !!opts.status);
  }
  const off = opts.offset ?? 0;
  g.font = `${Math.max(9, Math.min(12, cell / 3.2))}px system-ui, sans-serif`;
  g.textAlign = "center";
  g.textBaseline = "middle";
  for (let j = 0; j < rx; j++) {
    g.fillStyle = badRx.has(j) ? "#d13b3b" : "#6b7385";
    g.fillText(`R${j}`, pad + (j + 0.5) * cell, pad / 2);
  }
  for (let i = 0; i < tx; i++) {
    g.fillStyle = badTx.has(i) ? "#d13b3b" : "#6b7385";
    g.fillText(`T${i}`, pad / 2, pad + (i + 0.5) * cell);
  }
  for (let i = 0; i < tx; i++) {
    for (let j = 0; j < rx; j++) {
      const k = i * rx + j;
      const v = values ? values[k] : null;
      const x = pad + j * cell, y = pad + i * cell;
      g.fillStyle = v == null || !Number.isFinite(v) ? "#eceef2" : colour((v - off) / scale);
      g.fillRect(x + 1, y + 1, cell - 2, cell - 2);
      if (opts.labels && v != null && Number.isFinite(v) && cell > 26) {
        g.fillStyle = "#1d2330";
        g.fillText(opts.fmt ? opts.fmt(v) : Math.round(v), x + cell / 2, y + cell / 2);
      }
      const s = status[k];
      if (s && s !== "ok") {
        g.strokeStyle = s === "noisy" ? "#e08a00" : s === "dead" ? "#555" : "#d13b3b";
        g.lineWidth = 2.5;
        if (s === "weak") g.setLineDash([4, 3]);
        g.strokeRect(x + 2, y + 2, cell - 4, cell - 4);
        g.setLineDash([]);
        if (s === "dead") {
          g.beginPath();
          g.moveTo(x + 4, y + 4); g.lineTo(x + cell - 4, y + cell - 4);
          g.moveTo(x + cell - 4, y + 4); g.lineTo(x + 4, y + cell - 4);
          g.stroke();
        }
      }
    }
  }
  legend(g, pad, pad + cell * tx + 8, cell * rx, off, scale, opts);
  canvas._heat = { values, tx, rx, pad, cell, status, unit: opts.unit || "", fmt: opts.fmt, scale };
  hover(canvas);
  for (const [i] of badTx) {
    g.strokeStyle = "#d13b3b"; g.lineWidth = 1.5;
    g.strokeRect(pad, pad + i * cell, cell * rx, cell);
  }
  for (const [j] of badRx) {
    g.strokeStyle = "#d13b3b"; g.lineWidth = 1.5;
    g.strokeRect(pad + j * cell, pad, cell, cell * tx);
  }
}

function legend(g, x, y, w, off, scale, opts) {
  // The colour bar: what a colour means, in the map's unit.
  const signed = opts.signed !== false;
  const lo = signed ? off - scale : off, hi = off + scale;
  const n = 60;
  for (let k = 0; k < n; k++) {
    const v = lo + ((k + 0.5) / n) * (hi - lo);
    g.fillStyle = colour((v - off) / scale);
    g.fillRect(x + (k * w) / n, y, w / n + 0.5, 8);
  }
  g.strokeStyle = "#c5cad4";
  g.lineWidth = 1;
  g.strokeRect(x + 0.5, y + 0.5, w - 1, 8);
  const f = (v) => (Math.abs(hi - lo) >= 20 ? Math.round(v) : v.toFixed(1));
  g.fillStyle = "#6b7385";
  g.font = "11px system-ui, sans-serif";
  g.textBaseline = "top";
  g.textAlign = "left";
  g.fillText(`${f(lo)}`, x, y + 11);
  g.textAlign = "right";
  g.fillText(`≥ ${f(hi)} ${opts.unit || ""}`.trim(), x + w, y + 11);
  if (signed) {
    g.textAlign = "center";
    g.fillText(`${f(off)}`, x + w / 2, y + 11);
  }
}

let tip = null;
function hover(canvas) {
  if (canvas.dataset.hover) return;
  canvas.dataset.hover = "1";
  const hide = () => tip && tip.classList.add("hidden");
  canvas.addEventListener("mouseleave", hide);
  canvas.addEventListener("mousemove", (ev) => {
    const h = canvas._heat;
    if (!h) return;
    const r = canvas.getBoundingClientRect();
    const j = Math.floor((ev.clientX - r.left - h.pad) / h.cell);
    const i = Math.floor((ev.clientY - r.top - h.pad) / h.cell);
    if (i < 0 || j < 0 || i >= h.tx || j >= h.rx) { hide(); return; }
    const k = i * h.rx + j;
    const v = h.values ? h.values[k] : null;
    const text = v == null || !Number.isFinite(v) ? "-" : h.fmt ? h.fmt(v) : String(Math.round(v * 10) / 10);
    const s = h.status[k];
    if (!tip) {
      tip = document.createElement("div");
      tip.className = "heat-tip hidden";
      document.body.appendChild(tip);
    }
    tip.textContent = `TX ${i}, RX ${j}: ${text} ${h.unit}${s && s !== "ok" ? ` (${s})` : ""}`;
    tip.style.left = `${ev.clientX + 12}px`;
    tip.style.top = `${ev.clientY + 12}px`;
    tip.classList.remove("hidden");
  });
}
