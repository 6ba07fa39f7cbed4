// The Recalibrate page: pick a model, k guided touches, the old model against the recalibrated
// one. The touches go through the guided capture's own actions (/api/capture/...); the 3D view
// (app.js) shows the target, as on the Calibrate page.
const card = document.querySelector("#recal-card");
const $ = (sel) => card.querySelector(sel);
const token = document.querySelector('meta[name="skinloc-token"]')?.content ?? "";
const esc = (s) => String(s ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));
const client = () => sessionStorage.getItem("skinloc-client") || "anonymous";

async function post(path, body) {
  const headers = { "X-Skinloc-Client": client(), "X-Skinloc-Token": token };
  const opts = { method: "POST", headers };
  if (body instanceof Blob) opts.body = body;
  else if (body !== undefined) { headers["Content-Type"] = "application/json"; opts.body = JSON.stringify(body); }
  const r = await fetch(path, opts);
  const data = await r.json().catch(() => null);
  if (!r.ok) {
    const d = data?.detail;
    const text = typeof d === "string" ? d : `HTTP ${r.status}`;
    $(".recal-guide").textContent = text;
    $(".recal-guide").className = "recal-guide error";
    throw new Error(text);
  }
  return data;
}
const act = (path, body) => post(path, body).then(refresh).catch(() => null);

let models = "";
function renderModels(list) {
  const key = JSON.stringify(list);
  if (key === models) return;
  models = key;
  const sel = $(".recal-model");
  const was = sel.value;
  sel.innerHTML = list.map((m) => `<option value="${esc(m.kind)}:${esc(m.id)}">${esc(m.name)}</option>`).join("")
    || '<option value="">no trained model yet: train one, or upload a model file</option>';
  if ([...sel.options].some((o) => o.value === was)) sel.value = was;
}

// Before (the old model untouched on the new touches, each dot a touch) against after (the
// recalibrated model's cross-validated error), in mm, on one scale.
function chart(r) {
  if (r.before_mm == null) return "";
  const dots = r.before_per_touch_mm || [];
  const top = Math.max(r.before_mm, r.after_mm ?? 0, ...dots, 1) * 1.15;
  const W = 360, H = 180, x0 = 60, base = H - 24, y = (v) => base - ((base - 10) * v) / top;
  const bar = (i, v, label, cls) => v == null
    ? `<text x="${x0 + 40 + i * 140}" y="${base - 4}" class="hint">n/a</text><text x="${x0 + 40 + i * 140}" y="${H - 6}">${label}</text>`
    : `<rect class="${cls}" x="${x0 + 20 + i * 140}" y="${y(v)}" width="80" height="${base - y(v)}"></rect>`
      + `<text x="${x0 + 30 + i * 140}" y="${y(v) - 4}">${v.toFixed(1)} mm</text><text x="${x0 + 20 + i * 140}" y="${H - 6}">${label}</text>`;
  // each touch a dot in a strip right of the "before" bar (off its label)
  const pts = dots.map((v, i) => `<circle cx="${x0 + 106 + (24 * (i + 0.5)) / dots.length}" cy="${y(v)}" r="2.5" class="touch-dot"></circle>`).join("");
  const ticks = [0, top / 2, top].map((v) => `<text x="4" y="${y(v) + 4}">${v.toFixed(0)}</text>`).join("");
  return `<svg class="recal-chart" viewBox="0 0 ${W} ${H}" width="${W}" height="${H}" role="img" aria-label="error before and after, mm">
    <line x1="${x0}" y1="${base}" x2="${W}" y2="${base}" stroke="currentColor"></line>${ticks}
    ${bar(0, r.before_mm, "old model untouched", "before")}${pts}${bar(1, r.after_mm, "recalibrated", "after")}
    <style>.recal-chart text{font:11px sans-serif;fill:currentColor}.recal-chart .before{fill:#c77}.recal-chart .after{fill:#6a6}.recal-chart .touch-dot{fill:#333}</style></svg>`;
}

function renderResult(st) {
  const el = $(".recal-result");
  const job = st.job, r = st.result;
  if (job?.running) { el.innerHTML = "<p>Recalibrating…</p>"; return; }
  if (job?.error) { el.innerHTML = `<p class="error">Recalibration failed: ${esc(job.error)}</p>`; return; }
  if (!r) { el.innerHTML = ""; return; }
  const after = r.after_mm == null ? "not cross-validated (fewer than 2 touches, or a network)" : `${r.after_mm.toFixed(1)} mm (cross-validated: each touch scored by a model fitted without it)`;
  el.innerHTML = `<h3>Result: ${esc(r.method)}</h3>
    <p>${esc(r.summary)}</p>
    ${chart(r)}
    <table><tr><th>On the ${r.n_touches} new touches</th><th>mean error</th></tr>
    <tr><td>old model untouched (${esc(r.from)})</td><td>${r.before_mm == null ? "-" : `${r.before_mm.toFixed(1)} ± ${r.before_std_mm.toFixed(1)} mm`}</td></tr>
    <tr><td>recalibrated</td><td>${esc(after)}</td></tr></table>
    ${r.caveat ? `<p class="warn-box">${esc(r.caveat)}</p>` : ""}
    <p>Saved as <code class="recal-file">${esc(r.model_file)}</code> in the session's folder, beside the old model (which is unchanged).</p>`;
}

function renderGuide(st) {
  const g = $(".recal-guide");
  const s = window.skinloc?.state;
  if (st.mode === "recalibrate" && s?.guided) {
    const gd = s.guided;
    g.textContent = `Touch target #${gd.number} (${gd.index + 1} of ${gd.total}): ${gd.phase === "capturing" ? "hold still" : "press it and hold"}`;
  } else if (st.mode === "baseline") {
    g.textContent = "Keep the skin untouched: capturing the baseline";
  } else {
    g.textContent = st.message || "";
  }
  // the prompt big while a capture runs; the app's message line, as a hint, otherwise
  g.className = ["recalibrate", "baseline"].includes(st.mode) ? "recal-guide big-state" : "recal-guide hint";
  const busy = ["recalibrate", "baseline"].includes(st.mode) || st.job?.running;
  $(".recal-start").disabled = !!busy;
  for (const b of [".recal-now", ".recal-undo", ".recal-skip", ".recal-stop"]) $(b).disabled = st.mode !== "recalibrate";
}

async function refresh() {
  const st = await fetch("/api/recalibrate").then((r) => r.json());
  renderModels(st.models);
  renderGuide(st);
  renderResult(st);
  return st;
}

$(".recal-start").addEventListener("click", () => {
  const [kind, ...rest] = $(".recal-model").value.split(":");
  const id = rest.join(":");
  const body = { k: Number($(".recal-k").value) };
  if (kind === "session") body.session = id;
  else if (kind === "file") body.file = id;
  act("/api/recalibrate/start", body);
});
$(".recal-upload").addEventListener("change", async (ev) => {
  const f = ev.target.files?.[0];
  if (!f) return;
  await post(`/api/recalibrate/models?filename=${encodeURIComponent(f.name)}`, f).catch(() => null);
  ev.target.value = "";
  refresh();
});
for (const [cls, what] of [[".recal-now", "now"], [".recal-undo", "undo"], [".recal-skip", "skip"], [".recal-stop", "stop"]]) {
  $(cls).addEventListener("click", () => act(`/api/capture/${what}`));
}

// Polled while the tab is shown (the app's state stream carries the guided target).
setInterval(() => {
  if (card.closest(".page")?.classList.contains("active")) refresh().catch(() => null);
}, 700);
refresh().catch(() => null);
