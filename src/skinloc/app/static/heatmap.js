// A TX x RX heat map on a canvas, with flagged sensors and lines marked.

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
  const cssH = pad + cell * tx + 4;
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
    scale = opts.minScale ?? 40;
    for (const v of values || []) if (Number.isFinite(v)) scale = Math.max(scale, Math.abs(v));
  }
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
      const off = opts.offset ?? 0;
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
  for (const [i] of badTx) {
    g.strokeStyle = "#d13b3b"; g.lineWidth = 1.5;
    g.strokeRect(pad, pad + i * cell, cell * rx, cell);
  }
  for (const [j] of badRx) {
    g.strokeStyle = "#d13b3b"; g.lineWidth = 1.5;
    g.strokeRect(pad + j * cell, pad, cell, cell * tx);
  }
}
