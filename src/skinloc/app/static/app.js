// The skinloc app in the browser: pages, the live stream, and the actions.
import { Viewer, COVERAGE_STOPS } from "/static/viewer.js";
import { LivePage } from "/static/live.js";
import { drawHeat } from "/static/heatmap.js";
import { ExportPage } from "/static/export.js";
import { RecordPanel } from "/static/record.js";
import { TrainEvidence, referenceReady, touchName } from "/static/evidence.js";
import { LivePlot, SensorTrace, TouchView } from "/static/traces.js";
import { LiveSettings } from "/static/settings.js";

const $ = (sel, root = document) => root.querySelector(sel);
const $$ = (sel, root = document) => [...root.querySelectorAll(sel)];
const esc = (s) => String(s ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" }[c]));
const mm = (p) => (p ? p.map((x) => (x * 1000).toFixed(1)).join(", ") : "-");
const fmtErr = (s) => (s && s.mean_mm != null ? `${s.mean_mm.toFixed(1)} ± ${s.std_mm.toFixed(1)} mm` : "-");
// What a validation result says about touches taken back (retaken or undone) and skipped.
function retakenNote(v) {
  if (!v) return "";
  const parts = [];
  if (v.retaken) {
    const all = v.all_attempts ? `; all ${v.n_attempts} attempts: ${fmtErr(v.all_attempts)}` : "";
    parts.push(`${v.retaken} touch${v.retaken > 1 ? "es" : ""} retaken${all}`);
  }
  if (v.skipped) parts.push(`${v.skipped} skipped`);
  if (v.complete === false) parts.push(`incomplete: ${v.n} of ${v.n_planned}`);
  return parts.join(" · ");
}

// A tab keeps its id across reloads (sessionStorage), so a reload keeps control.
let clientId = sessionStorage.getItem("skinloc-client");
if (!clientId) {
  clientId = `tab-${Math.random().toString(36).slice(2, 10)}`;
  sessionStorage.setItem("skinloc-client", clientId);
}

const app = {
  page: "sessions",
  state: null,
  session: null,
  sensors: null,
  frame: null,
  viewer: null,
  live: null, // the live page's tracks and gestures (live.js)
};
window.skinloc = app; // for the end-to-end test and for debugging

// A touch of a recording by its target's number for life: "#6", a retake "#6 (2nd)".
const recName = (rec, i) => touchName(...(rec?.numbers?.[i] || [i + 1, 1]));
// What an earlier validation was: of this model's previous run, or of an earlier model.
const previousName = (prev) => (prev.earlier_model ? "an earlier model's validation" : "previous");

function validationCell(s) {
  // The result, what was retaken; while a new validation runs, the previous one, named so.
  const v = s.validation, prev = s.validation_previous;
  if (v && v.mean_mm != null) {
    const note = retakenNote(v);
    return `${fmtErr(v)}${note ? `<br><span class="flag retaken">${esc(note)}</span>` : ""}`;
  }
  return prev ? `<span class="hint">${previousName(prev)}: ${fmtErr(prev)}${prev.retaken ? ` (${prev.retaken} retaken)` : ""}</span>` : "-";
}

// ------------------------------------------------------------------ talking to the server
// The launch secret the server put in the page: every action and the stream send it back.
const token = document.querySelector('meta[name="skinloc-token"]')?.content ?? "";
async function api(path, body, method = "POST") {
  const opts = { method, headers: { "X-Skinloc-Client": clientId, "X-Skinloc-Token": token } };
  if (body !== undefined) {
    if (body instanceof Blob || body instanceof ArrayBuffer) {
      opts.body = body;
    } else {
      opts.headers["Content-Type"] = "application/json";
      opts.body = JSON.stringify(body);
    }
  }
  const r = await fetch(path, opts);
  let data = null;
  try { data = await r.json(); } catch { data = null; }
  if (!r.ok) {
    const detail = data?.detail;
    const text = typeof detail === "string" ? detail : Array.isArray(detail) ? detail.map((d) => `${d.loc?.slice(-1)[0]}: ${d.msg}`).join("; ") : `HTTP ${r.status}`;
    if (r.status === 409) $("#busy").classList.remove("hidden");
    showMessage(text, true);
    throw new Error(text);
  }
  return data;
}
const get = (path) => fetch(path).then((r) => r.json());
// An action from a click or a key: a refusal is shown in the message line (api does that) and
// ends there, never as an uncaught error of the page.
const act = (path, body) => api(path, body).catch(() => null);

function showMessage(text, error = false) {
  const el = $("#message");
  el.textContent = text || "";
  el.classList.toggle("error", error);
}

let ws = null;
function connectStream() {
  const proto = location.protocol === "https:" ? "wss" : "ws";
  ws = new WebSocket(`${proto}://${location.host}/ws?client=${encodeURIComponent(clientId)}&token=${encodeURIComponent(token)}`);
  ws.onopen = () => $("#offline").classList.add("hidden");
  ws.onclose = () => {
    $("#offline").classList.remove("hidden");
    setTimeout(connectStream, 1000);
  };
  ws.onmessage = (ev) => {
    const msg = JSON.parse(ev.data);
    const handler = handlers[msg.type];
    if (handler) handler(msg);
  };
}

const handlers = {
  state(msg) {
    const prev = app.state;
    app.state = msg;
    // A page opened (or reloaded) while a capture or the live view runs shows it.
    if (!prev && ["calibrate", "validate", "live"].includes(msg.mode) && app.page !== msg.mode) showPage(msg.mode);
    if (msg.session?.id) localStorage.setItem("skinloc-last-session", msg.session.id);
    renderState(prev);
    checkLink();
  },
  heartbeat(msg) {
    // Sent by the server when nothing else is: the app lives; the skin's link is as it says.
    if (app.state?.device && msg.device) {
      app.state.device.link_up = msg.link_up;
      app.state.device.frame_age_s = msg.frame_age_s;
    }
    checkLink();
    if (link.lost) renderLink(); // the time since the last frame grows
  },
  frame(msg) {
    app.frame = msg;
    if (app.state?.device && msg.stats) Object.assign(app.state.device, msg.stats);
    later("frame", () => renderFrame(app.frame));
  },
  sensors(msg) {
    app.sensors = msg;
    renderSensors();
  },
  touch() { refreshSession(); },
  train(msg) {
    if (msg.session && msg.session !== app.state?.session?.id) return; // another session's
    renderTraining(msg);
    if (app.coverageOn && msg && !msg.running && msg.result) toggleCoverage(true); // a new model
  },
  live(msg) { app.live.contacts(msg); app.plot.add(msg); app.settings.add(msg); },
  gesture(msg) { app.live.gesture(msg); },
};

// Every message shows that the app is there.
for (const [k, f] of Object.entries(handlers)) {
  handlers[k] = (msg) => { link.quietMs = 0; f(msg); };
}

// ------------------------------------------------------------------ the skin's link
// The skin's link is what the server says it is: its reader counts a loss when no frame came
// for 0.8 s (or the port closed) and pushes the state at once; every frame carries the link's
// state, and when nothing else goes to the tab a heartbeat (4 a second) says it. The tab never
// calls the link lost by itself: frames that reach it late (a busy server, a busy tab) are not
// a lost link. The app's own silence is another matter, said in other words: no message at all
// for APP_SILENT_MS closes the connection and reconnects ("not answering"). That time is
// counted on the tab's ticks, each at most two ticks long, so a tab that was itself stalled
// (a loaded machine rendering in software) does not take the messages it could not read yet
// for the app's silence; the limit leaves a busy server (20 heartbeats) time to answer.
const APP_SILENT_MS = 6000;
const TICK_MS = 200;
const link = { quietMs: 0, tickAt: performance.now(), lost: false, offline: false };

/** The server said that the skin's link is lost. */
const skinLinkLost = () => app.state?.device?.link_up === false;

function linkLost() {
  // Nothing can be done with the skin now: its link is lost, or the app does not answer.
  if (!app.state?.device) return false;
  return link.offline || skinLinkLost();
}

function checkLink() {
  if (ws !== link.ws) {
    // A new connection: it has said nothing yet, and that is not silence.
    link.ws = ws;
    link.quietMs = 0;
  }
  const open = !!ws && ws.readyState === WebSocket.OPEN;
  if (open && link.quietMs > APP_SILENT_MS) {
    ws.close(); // a connection that went silent: reconnect (onclose says so)
  }
  link.offline = !open;
  const lost = linkLost();
  // What the page shows: lost or not, and why (the skin's link, or the app not answering).
  const shown = `${lost} ${link.offline} ${skinLinkLost()}`;
  if (shown === link.shown) return;
  link.lost = lost;
  link.shown = shown;
  renderLink();
  if (app.page === "calibrate" || app.page === "validate") renderGuided(app.page);
}
setInterval(() => {
  const now = performance.now();
  link.quietMs += Math.min(now - link.tickAt, 2 * TICK_MS);
  link.tickAt = now;
  checkLink();
}, TICK_MS);

function renderLink() {
  const d = app.state?.device;
  document.body.classList.toggle("link-lost", link.lost);
  const banner = $("#linklost");
  banner.classList.toggle("hidden", !skinLinkLost() || link.offline);
  if (link.lost && d) {
    const age = d.frame_age_s ? ` for ${d.frame_age_s.toFixed(1)} s` : "";
    $("#linklost-text").textContent = `No frame from ${d.name}${age}. Waiting for it to come back` +
      `${d.sim ? "" : " (reconnecting to the port)"}; touches are not prompted meanwhile, and nothing recorded is lost.`;
  }
  renderPill();
  if (app.page === "connect") renderDeviceStats(d);
}

function renderPill() {
  const d = app.state?.device;
  const pd = $("#pill-device");
  if (!d) {
    pd.textContent = "no skin";
    pd.className = "pill off";
  } else if (skinLinkLost()) {
    pd.textContent = `${d.name} · link lost`;
    pd.className = "pill bad";
  } else if (link.lost) {
    pd.textContent = `${d.name} · app not answering`;
    pd.className = "pill bad";
  } else {
    pd.textContent = `${d.name} · ${d.rate_hz.toFixed(0)} Hz${d.reconnects ? ` · ${d.reconnects} reconnect${d.reconnects > 1 ? "s" : ""}` : ""}`;
    pd.className = "pill";
  }
  pd.title = pd.textContent;
}

const pending = new Map();
function later(key, fn) {
  // Coalesce bursts of stream messages into one redraw per animation frame.
  if (pending.has(key)) {
    pending.set(key, fn);
    return;
  }
  pending.set(key, fn);
  requestAnimationFrame(() => {
    const f = pending.get(key);
    pending.delete(key);
    f();
  });
}

let sessionFetch = null;
let sessionStale = false;
async function refreshSession() {
  // One request at a time; a refresh asked for meanwhile runs when it ends (never stale).
  if (sessionFetch) {
    sessionStale = true;
    return sessionFetch;
  }
  sessionFetch = get("/api/session").then(async (s) => {
    app.session = s && s.id ? s : null;
    if (app.session && app.meshFor !== app.session.id) {
      // The mesh comes once per session, not with every touch.
      const m = await get("/api/session/mesh");
      app.meshFor = m.id;
      app.viewer.setMesh(m.vertices, m.faces);
    }
    renderSession();
  }).finally(() => {
    sessionFetch = null;
    if (sessionStale) {
      sessionStale = false;
      refreshSession();
    }
  });
  return sessionFetch;
}

// ------------------------------------------------------------------ pages
function showPage(page) {
  app.page = page;
  // The page is in the address, so a reload comes back to it.
  if (location.hash !== `#${page}`) history.replaceState(null, "", `#${page}`);
  for (const b of $$("#nav button")) b.classList.toggle("active", b.dataset.page === page);
  for (const s of $$(".page")) s.classList.toggle("active", s.id === `page-${page}`);
  const slot = $(`.viewer-slot[data-for="${page}"]`);
  // The 3D view lives on the pages that have a place for it, never under the others.
  $("#viewer").classList.toggle("hidden", !slot);
  $("#viewer-legend").classList.toggle("hidden", page !== "validate");
  if (slot) {
    slot.appendChild($("#viewer"));
    app.viewer.resize();
    app.viewPage = page; // the 3D view the Export page saves is this page's, as last seen
  }
  if (page === "sessions") loadSessions();
  if (page === "connect") loadPorts();
  if (page === "export") app.exporter.refresh();
  app.evidence.setVisible((slot ? page : app.viewPage) === "train");
  // What the message line said belongs to the page it was said on, not the next one.
  app.dismissed = app.state?.message ?? "";
  showMessage("");
  renderSession();
  renderState(app.state);
}

// ------------------------------------------------------------------ sessions page
async function loadSessions() {
  const data = await get("/api/sessions");
  $("#data-dir").textContent = `in ${data.root}`;
  const current = app.state?.session?.id;
  const rows = data.sessions.map((s) => `
    <tr class="${s.id === current ? "current" : ""}">
      <td><b>${esc(s.name)}</b><br><span class="hint">${esc(s.id)}</span>${s.error ? `<br><span class="flag">${esc(s.error)}</span>` : ""}</td>
      <td>${s.n_done ?? 0} / ${s.n_planned ?? "?"}</td>
      <td>${s.has_model ? fmtErr(s.holdout) : "-"}</td>
      <td>${validationCell(s)}</td>
      <td class="hint">${esc((s.modified || s.created || "").replace("T", " ").slice(0, 16))}</td>
      <td><button data-open="${esc(s.id)}">${s.id === current ? "Opened" : "Open"}</button></td>
    </tr>`);
  $("#session-list tbody").innerHTML = rows.join("") || `<tr><td colspan="6" class="hint">No session yet: create one.</td></tr>`;
  $("#recording-list tbody").innerHTML = data.recordings.map((r) => `
    <tr><td>${esc(r.name)}${r.error ? `<br><span class="flag">${esc(r.error)}</span>` : ""}</td>
      <td>${r.n_point_logs ?? "-"}</td><td>${r.tx ? `${r.tx} x ${r.rx}` : "-"}</td>
      <td>${r.error ? "" : `<button data-import="${esc(r.path)}">Open as session</button>`}</td></tr>`).join("")
    || `<tr><td colspan="4" class="hint">None.</td></tr>`;
  const meshes = await get("/api/state");
  $("#mesh-select option[value='']").textContent = `default: ${meshes.default_mesh}`;
  // Meshes uploaded before (also before a reload or a restart) stay choosable.
  const listed = new Set($$("#mesh-select option").map((o) => o.value));
  for (const m of await get("/api/meshes")) {
    if (listed.has(m.name)) continue;
    const opt = document.createElement("option");
    opt.value = m.name;
    opt.textContent = m.name;
    $("#mesh-select").appendChild(opt);
  }
}

$("#session-list").addEventListener("click", async (ev) => {
  const id = ev.target.dataset?.open;
  if (!id || !(await act(`/api/sessions/${encodeURIComponent(id)}/open`))) return;
  await refreshSession();
  loadSessions();
  showPage("calibrate");
});
$("#recording-list").addEventListener("click", async (ev) => {
  const path = ev.target.dataset?.import;
  if (!path || !(await act(`/api/recordings/import?path=${encodeURIComponent(path)}`))) return;
  await refreshSession();
  showPage("train");
});
$("#new-session [name=mode]").addEventListener("change", (ev) => {
  $(".only-list").classList.toggle("hidden", ev.target.value !== "list");
});
$("#mesh-upload").addEventListener("change", async (ev) => {
  const file = ev.target.files[0];
  if (!file) return;
  const info = await act(`/api/meshes?filename=${encodeURIComponent(file.name)}`, file);
  if (!info) return;
  const opt = document.createElement("option");
  opt.value = info.name;
  opt.textContent = `${info.name} (${info.n_faces} faces, ${info.extents_mm.join(" x ")} mm)`;
  $("#mesh-select").appendChild(opt);
  $("#mesh-select").value = info.name;
  showMessage(`loaded mesh ${info.name}`);
});
$("#new-session").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  // One session per click: a double click (or Enter then a click) sends one request.
  const button = ev.target.querySelector("button[type=submit]");
  if (button.disabled) return;
  button.disabled = true;
  try {
    await createSession(ev.target);
  } finally {
    button.disabled = false;
  }
});
async function createSession(form) {
  const f = new FormData(form);
  const body = Object.fromEntries(f.entries());
  for (const k of ["n_points", "samples", "baseline_frames", "seed", "n_validation"]) body[k] = Number(body[k]);
  if (!body.mesh_file) delete body.mesh_file;
  if (body.mode !== "list") delete body.targets_csv;
  if (!(await act("/api/sessions", body))) return;
  await refreshSession();
  showPage(app.state?.device ? "calibrate" : "connect");
}

// ------------------------------------------------------------------ connect page
async function loadPorts() {
  const ports = await get("/api/ports").catch(() => []);
  const sel = $("#source-select");
  const keep = sel.value;
  sel.innerHTML = `<option value="sim">simulated skin</option>` + ports.map((p) =>
    `<option value="${esc(p.device)}">${esc(p.device)} ${p.likely_arduino ? "(Arduino?)" : p.virtual ? "(virtual skin)" : ""} ${esc(p.description || "")}</option>`).join("");
  if ([...sel.options].some((o) => o.value === keep)) sel.value = keep;
  markConnected(true);
}

function markConnected(rebuilt = false) {
  // The Source selector names the skin that is connected, and selects it.
  const sel = $("#source-select");
  const source = app.state?.device?.options?.source;
  const mark = " ● connected";
  for (const o of [...sel.options]) {
    if (o.value === source) continue;
    if (o.dataset.extra) o.remove();
    else if (o.textContent.endsWith(mark)) o.textContent = o.textContent.slice(0, -mark.length);
  }
  if (!source) return;
  let opt = [...sel.options].find((o) => o.value === source);
  if (!opt) {
    opt = document.createElement("option");
    opt.value = source;
    opt.textContent = source;
    opt.dataset.extra = "1";
    sel.appendChild(opt);
  }
  if (!opt.textContent.endsWith(mark)) opt.textContent += mark;
  // What is connected is selected, unless the person picked another source to connect.
  if (!app.pickedSource && (rebuilt || app.shownSource !== source)) {
    app.shownSource = source;
    sel.value = source;
  }
}
$("#refresh-ports").addEventListener("click", loadPorts);
$("#source-select").addEventListener("change", () => { app.pickedSource = true; });
$("#connect-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const f = Object.fromEntries(new FormData(ev.target).entries());
  const body = {
    source: f.port.trim() || f.source,
    tx: Number(f.tx), rx: Number(f.rx), baud: Number(f.baud), format: f.format,
  };
  if (await act("/api/connect", body)) app.pickedSource = false;
});
$("#disconnect-btn").addEventListener("click", () => act("/api/disconnect"));
$("#rezero").addEventListener("click", () => act("/api/rezero"));

function renderSensors() {
  const s = app.sensors, st = app.state?.device;
  if (!s || !st) return;
  drawHeat($("#heat-noise"), s.noise, st.tx, st.rx, { status: s.status, labels: true, fmt: (v) => v.toFixed(1), minScale: 10, unit: "counts", signed: false });
  drawHeat($("#heat-snr"), s.snr_db, st.tx, st.rx, { status: s.status, labels: true, fmt: (v) => v.toFixed(0), scale: 25, offset: 20, unit: "dB" });
  $("#snr-from").textContent = s.snr_from === "session" ? "from the session's touches" : "peak since zero / noise";
  const lines = [...s.tx_lines.map((l) => `TX ${l.index}: ${l.status}`), ...s.rx_lines.map((l) => `RX ${l.index}: ${l.status}`)];
  const sensors = s.status.map((v, k) => (v !== "ok" ? `T${Math.floor(k / st.rx)} R${k % st.rx}: ${v}` : null)).filter(Boolean);
  $("#line-report").innerHTML = `${lines.length ? `<b>Lines:</b> ${lines.map(esc).join(", ")}` : "No dead or noisy line."}<br>` +
    `${sensors.length ? `<b>Sensors:</b> ${sensors.map(esc).join(", ")}` : "No flagged sensor."}<br>` +
    `Mean SNR: ${s.mean_snr_db == null ? "-" : `${s.mean_snr_db.toFixed(1)} dB`}`;
}

function renderDeviceStats(d) {
  const lost = link.lost;
  const rows = d ? [
    ["Skin", esc(d.name)], ["Grid", `${d.tx} TX x ${d.rx} RX`], ["Frame rate", lost ? "-" : `${d.rate_hz.toFixed(1)} Hz`],
    ["Received", d.received], ["Dropped", d.dropped], ["Corrupted", d.corrupted], ["Lost frames", d.lost],
    ["Overflow", d.overflow], ["Reconnects", d.reconnects], ["Link losses", d.link_losses ?? 0],
    ["Link", skinLinkLost() ? `<b class="bad">LOST</b>${d.frame_age_s ? ` (no frame for ${d.frame_age_s.toFixed(1)} s)` : ""}`
      : lost ? "the app is not answering" : "up"],
    ...(d.error && lost ? [["Error", `<span class="error-text">${esc(d.error)}</span>`]] : []),
  ] : [["Skin", "not connected"]];
  $("#device-stats").innerHTML = rows.map(([k, v]) => `<tr><th>${k}</th><td>${v}</td></tr>`).join("");
}

// ------------------------------------------------------------------ guided capture (calibrate, validate)
function guidedPanel(kind) {
  const el = $(`.guided[data-kind="${kind}"]`);
  if (el.dataset.built) return el;
  el.dataset.built = "1";
  const isCal = kind === "calibrate";
  el.innerHTML = `
    <h2>${isCal ? "Calibrate" : "Validate"}</h2>
    <div class="reopen hidden">
      <p class="hint">No session is open (the app may have restarted). Open one to go on where it stopped:</p>
      <div class="buttons"><select class="reopen-select"></select><button class="primary reopen-btn">Open</button></div>
    </div>
    ${isCal ? "" : `<label class="check">Touches <input type="number" class="n-val" min="1" max="500" value="20" style="width:70px"></label>`}
    <div class="buttons">
      <button class="primary start">${isCal ? "Start / resume" : "Start"}</button>
      <button class="stop">Pause</button>
    </div>
    <div class="count hint"></div>
    <div class="progress"><div class="bar-total"></div></div>
    <div class="big-state idle">-</div>
    <div class="progress"><div class="bar-capture"></div></div>
    <div class="buttons">
      <button class="now" title="Space">Capture now <kbd>Space</kbd></button>
      <button class="undo" title="Z: take back the last touch (also after Complete)">Undo <kbd>Z</kbd></button>
      <button class="skip" title="S">Skip <kbd>S</kbd></button>
    </div>
    <div class="next-step hidden">${isCal
      ? `<p class="hint">Next: train the localiser on these touches (flagged touches are listed there first).</p><div class="buttons"><button class="primary" data-go="train">Train</button></div>`
      : `<p class="hint">Next: use the model live, or train again after retaking touches.</p><div class="buttons"><button class="primary" data-go="live">Live</button><button data-go="train">Train</button></div>`}</div>
    <label class="check"><input type="checkbox" class="finger"> scripted finger touches each target</label>
    <div class="target-info hint"></div>
    ${isCal ? `<div class="hint sheets">Printable targets: <a class="svg" target="_blank">SVG</a> · <a class="pdf" target="_blank">PDF</a></div>` : `<div class="val-result"></div>
    <label class="check"><input type="checkbox" class="coverage"> coverage map: the model's expected error on the skin</label>
    <div class="coverage-legend hint hidden"></div>`}
    <canvas class="heat guided-heat"></canvas>
    <div class="touches"><table>
      <thead><tr><th>#</th><th>Position (mm)</th>${isCal ? "" : "<th>Error (mm)</th>"}<th>Flags</th>${isCal ? "<th>Leave out</th>" : ""}<th></th></tr></thead>
      <tbody></tbody></table></div>`;
  if (!isCal) $(".n-val", el).addEventListener("input", (ev) => { ev.target.dataset.touched = "1"; });
  $(".start", el).addEventListener("click", () => (isCal ? act("/api/calibrate/start")
    : act("/api/validate/start", { n_points: Number($(".n-val", el).value) })));
  $(".stop", el).addEventListener("click", () => act("/api/capture/stop"));
  $(".now", el).addEventListener("click", () => act("/api/capture/now"));
  $(".undo", el).addEventListener("click", () => undo(kind));
  $(".skip", el).addEventListener("click", () => act("/api/capture/skip"));
  $(".finger", el).addEventListener("change", (ev) => act("/api/finger", { on: ev.target.checked }));
  for (const b of $$(".next-step button", el)) b.addEventListener("click", () => showPage(b.dataset.go));
  if (!isCal) $(".coverage", el).addEventListener("change", (ev) => toggleCoverage(ev.target.checked));
  // A clicked button or box must not keep the keyboard: Space, Z and S drive the capture.
  el.addEventListener("click", (ev) => {
    if (ev.target.matches("button, input[type=checkbox]")) ev.target.blur();
  });
  $(".reopen-btn", el).addEventListener("click", async () => {
    const id = $(".reopen-select", el).value;
    if (!id) return;
    if (await act(`/api/sessions/${encodeURIComponent(id)}/open`)) await refreshSession();
  });
  $(".touches", el).addEventListener("click", (ev) => {
    const i = ev.target.dataset?.retake;
    if (i !== undefined) act("/api/capture/retake", { index: Number(i), recording: isCal ? "calibration" : "validation" });
  });
  $(".touches", el).addEventListener("change", (ev) => {
    if (ev.target.classList.contains("leave-out")) leaveOut(ev.target);
  });
  return el;
}

const PHASE_TEXT = {
  wait_touch: ["Touch the red target and hold still", "touch"],
  capturing: ["Hold still: capturing", "capture"],
  wait_release: ["Lift your finger", "lift"],
};

async function offerSessions(el) {
  // After a restart nothing is open: offer the sessions, the last one this browser used first.
  if (el.dataset.offered && performance.now() - Number(el.dataset.offered) < 5000) return;
  el.dataset.offered = String(performance.now());
  const data = await get("/api/sessions");
  const last = localStorage.getItem("skinloc-last-session");
  const list = [...data.sessions].filter((s) => !s.error)
    .sort((a, b) => (b.id === last) - (a.id === last) || String(b.modified || "").localeCompare(String(a.modified || "")));
  $(".reopen-select", el).innerHTML = list.map((s) =>
    `<option value="${esc(s.id)}">${esc(s.name)} (${s.n_done ?? 0} / ${s.n_planned ?? "?"})</option>`).join("")
    || `<option value="">no session yet: create one on the Sessions page</option>`;
  $(".reopen-btn", el).disabled = !list.length;
}

// The coverage map (validate page): expected error of the trained model, GET /api/session/coverage,
// as a colour on the skin, its scale, and beside it the errors measured on touches.
const VIEWER_LEGEND = $("#viewer-legend").innerHTML;
async function toggleCoverage(on) {
  const legend = $(".coverage-legend", guidedPanel("validate"));
  app.coverageOn = on;
  app.viewer.clear("coverage");
  legend.classList.toggle("hidden", !on);
  $("#viewer-legend").innerHTML = VIEWER_LEGEND;
  if (!on) { renderSession(); return; }
  legend.textContent = "computing the coverage map...";
  const r = await fetch("/api/session/coverage");
  const c = await r.json();
  if (!r.ok) { legend.textContent = c.detail || "no coverage map"; return; }
  app.viewer.setCoverage(c.points, c.expected_mm, c.scale_mm);
  const [lo, hi] = c.scale_mm;
  const e = c.expected_error_mm;
  const bar = `<div class="bar" style="background:linear-gradient(to right,${COVERAGE_STOPS.join(",")})"></div>
    <div class="ticks"><span>≤ ${lo.toFixed(1)}</span><span>${((lo + hi) / 2).toFixed(1)}</span><span>≥ ${hi.toFixed(1)} mm</span></div>`;
  // The 3D view's legend says what the colours are now: the coverage map, not validation errors.
  $("#viewer-legend").innerHTML = `<div><b>Coverage map</b>: expected error, mm</div>${bar}
    <div class="hint">predicted by the model at each place; the dots are the validation touches</div>`;
  const m = c.measured || {};
  const measured = [
    m.holdout ? `${m.holdout.how ? "cross-validated" : "held-out"} touches: mean ${m.holdout.mean_mm.toFixed(1)}, p95 ${m.holdout.p95_mm.toFixed(1)} mm` : "",
    m.validation ? `validation: mean ${m.validation.mean_mm.toFixed(1)}, p95 ${m.validation.p95_mm.toFixed(1)} mm` : "",
  ].filter(Boolean);
  const worst = Math.max(...[m.holdout, m.validation].filter(Boolean).map((x) => x.p95_mm));
  const compare = measured.length
    ? `Measured on ${measured.join("; ")}. ${worst > 1.5 * e.p90
      ? `The measured tail is ${(worst / e.p90).toFixed(1)} times the map's p90: the map ranks places (where the sensors see a touch poorly), it does not predict bad touches or how a finger presses; trust the measured errors for the figure.`
      : "The map's p90 is close to the measured tail."}`
    : "No measured error to compare with yet: validate.";
  legend.innerHTML = `<div><b>Coverage map</b>: the trained model's <i>expected</i> error at each place on the skin, in mm
    (predicted from its response map and the sensor noise, not measured).</div>${bar}
    <div>Over the skin: mean ${e.mean.toFixed(1)} mm, p90 ${e.p90.toFixed(1)} mm; ${(100 * c.blind_fraction).toFixed(0)} % above ${c.blind_threshold_mm} mm by this prediction.</div>
    <div class="measured">${esc(compare)}</div>`;
  renderSession();
}

function renderGuided(kind) {
  const el = guidedPanel(kind);
  const st = app.state;
  const mode = kind === "calibrate" ? "calibrate" : "validate";
  const active = st?.mode === mode;
  const g = active ? st.guided : null;
  // Only the open session's progress: never what a tab remembers from before a restart.
  const current = app.session && app.session.id === st?.session?.id ? app.session : null;
  const rec = current?.[kind === "calibrate" ? "calibration" : "validation"];
  $(".reopen", el).classList.toggle("hidden", !!st?.session || !st);
  if (st && !st.session) offerSessions(el);
  else delete el.dataset.offered;
  const total = g ? g.total : rec?.planned?.length ?? 0;
  const done = g ? g.index : rec?.done?.length ?? 0;
  $(".count", el).textContent = total ? `${done} of ${total} touches recorded` : "";
  $(".bar-total", el).style.width = total ? `${(100 * done) / total}%` : "0";
  $(".finger", el).checked = !!st?.finger;
  for (const b of $$(".now, .skip", el)) b.disabled = !active || link.lost;
  // Undo takes back the last touch also once paused or complete (it prompts that target again).
  $(".undo", el).disabled = link.lost || !st?.device || st?.mode === "baseline" || !(rec?.done?.length);
  $(".stop", el).disabled = !active;
  $(".start", el).disabled = !st?.session || !st?.device || st?.mode === "baseline" || link.lost;
  const state = $(".big-state", el);
  if (st?.device && link.lost) {
    // The server's last word on the skin first: a busy app does not hide a lost link.
    state.textContent = skinLinkLost() ? "Link lost: waiting for the skin" : "The app is not answering: reconnecting";
    state.className = "big-state lost";
  } else if (st?.mode === "baseline") {
    state.textContent = "Keep the skin untouched: baseline";
    state.className = "big-state lift";
  } else if (!active) {
    state.textContent = !st?.device ? "Connect a skin first" : !st?.session ? "Open a session first"
      : done && done >= total ? "Complete" : done ? `Paused at ${done} of ${total}: press Start to go on` : "Ready: press Start";
    state.className = "big-state idle";
  } else {
    const [text, cls] = PHASE_TEXT[app.frame?.capture?.phase || g.phase] || ["-", "idle"];
    state.textContent = text;
    state.className = `big-state ${cls}`;
  }
  $(".target-info", el).textContent = g?.target ? `Target ${touchName(g.number, g.attempt)} at ${mm(g.target)} mm` : "";
  const complete = !active && st?.mode !== "baseline" && !!current && total > 0 && done >= total;
  $(".next-step", el).classList.toggle("hidden", !complete || (kind === "validate" && !st?.session?.has_model));
  if (kind === "calibrate") $(".sheets", el).classList.toggle("hidden", !current);
  if (kind === "calibrate" && current) {
    $(".svg", el).href = `/api/sessions/${app.session.id}/targets.svg`;
    $(".pdf", el).href = `/api/sessions/${app.session.id}/targets.pdf`;
  }
  if (kind === "validate") {
    const input = $(".n-val", el);
    if (!input.dataset.touched && st?.session?.n_validation) input.value = st.session.n_validation;
    const v = app.state?.session?.validation;
    const note = retakenNote(v);
    const prev = st?.session?.validation_previous;
    $(".val-result", el).innerHTML = v && v.mean_mm != null ? `<div class="result">${fmtErr(v)}</div><div class="hint">mean ± std over ${v.n} touches (median ${v.median_mm.toFixed(1)}, p95 ${v.p95_mm.toFixed(1)} mm)</div>` +
      (note ? `<div class="flag retaken">${esc(note)}</div>` : "")
      : prev?.earlier_model ? `<div class="hint val-earlier">The model was trained again: its validation so far scored ${fmtErr(prev)} on the earlier model${prev.file ? ` (kept as ${esc(prev.file)})` : ""}. Validate to score this one.</div>`
      : prev ? `<div class="hint">Previous validation (kept as ${esc(prev.file)}): ${fmtErr(prev)}${prev.retaken ? `, ${prev.retaken} retaken` : ""}</div>` : "";
  }
  const rows = (rec?.done || []).map((p, i) => {
    const flags = rec.flags?.[i] || [];
    const err = rec.errors_mm?.[i];
    const out = kind === "calibrate"
      ? `<td><input type="checkbox" class="leave-out" data-index="${i}" title="leave this touch out of training until put back" ${rec.left_out?.[i] ? "checked" : ""}></td>` : "";
    return `<tr data-index="${i}"><td class="touch-name">${esc(recName(rec, i))}</td><td>${p.map((x) => (x * 1000).toFixed(0)).join(", ")}</td>${kind === "validate" ? `<td>${err != null ? err.toFixed(1) : ""}</td>` : ""}
      <td class="flags">${flags.map((f) => `<span class="flag ${esc(f)}">${esc(FLAG_WORDS[f] || f)}</span>`).join("")}</td>${out}
      <td><button data-retake="${i}" title="take this touch back (kept in the history) and touch its target again">Retake</button></td></tr>`;
  }).reverse();
  $(".touches tbody", el).innerHTML = rows.join("") || `<tr><td colspan="5" class="hint">No touch recorded yet.</td></tr>`;
}

// Take back the last touch of the page's recording: during capture the server's undo; once
// paused or complete, a retake of that touch (which prompts its target again).
function undo(kind) {
  if (app.state?.mode === kind) return act("/api/capture/undo");
  const rec = app.session?.[kind === "calibrate" ? "calibration" : "validation"];
  const n = rec?.done?.length ?? 0;
  if (!n) return showMessage("nothing to undo: no touch recorded yet", true);
  return act("/api/capture/retake", { index: n - 1, recording: kind === "calibrate" ? "calibration" : "validation" });
}

document.addEventListener("keydown", (ev) => {
  // Typing in a text field keeps its keys; a checkbox or button that has focus does not.
  const typing = ev.target.closest?.("textarea, select, input:not([type=checkbox]):not([type=radio]):not([type=button]):not([type=submit])");
  if (typing || link.lost || ev.ctrlKey || ev.metaKey || ev.altKey) return;
  const kind = app.page;
  if (!["calibrate", "validate"].includes(kind)) return;
  // Z works on its page whenever there is a touch to take back, "Complete" included;
  // Space and S only while capturing. Backspace does nothing: too easy to hit by accident.
  if (ev.key === "z" || ev.key === "Z") {
    ev.preventDefault();
    if (app.state?.session && app.state?.device && app.state.mode !== "baseline") undo(kind);
    return;
  }
  if (app.state?.mode !== kind) return;
  if (ev.code === "Space") { ev.preventDefault(); act("/api/capture/now"); }
  if (ev.key === "s" || ev.key === "S") { ev.preventDefault(); act("/api/capture/skip"); }
});

// ------------------------------------------------------------------ train page
// Before training: every touch, the flagged ones first, each to leave out (it stays out of every
// training until put back: POST /api/train/leave_out) or to retake. The flags are the words of
// ``skinloc check`` (the same code); nothing is left out unless the researcher says so.
const FLAG_WORDS = { off_target: "off target", weak: "weak", short: "short", forced: "forced", saturated: "saturated" };
const flagHtml = (flags) => flags.map((f) => `<span class="flag ${esc(f)}">${esc(FLAG_WORDS[f] || f)}</span>`).join("");
// Leave a touch out, or put it back, from a checkbox (``data-index``); the list follows.
async function leaveOut(box) {
  box.disabled = true;
  await act("/api/train/leave_out", { index: Number(box.dataset.index), out: box.checked });
  await refreshSession();
}
function renderGate() {
  const el = $("#train-gate");
  const cal = app.session?.calibration;
  const n = cal?.done?.length ?? 0;
  if (!app.session || !n) {
    el.innerHTML = app.session ? `<p class="hint">No touch recorded yet: calibrate first.</p>` : "";
    delete el.dataset.key;
    return;
  }
  const touches = cal.done.map((_, i) => ({ index: i, flags: cal.flags?.[i] || [], out: !!cal.left_out?.[i] }));
  const key = `${app.session.id}:${JSON.stringify(touches)}:${JSON.stringify(cal.numbers)}`;
  if (el.dataset.key === key) return;
  el.dataset.key = key;
  const flagged = touches.filter((t) => t.flags.length);
  const out = touches.filter((t) => t.out);
  const counts = {};
  for (const t of flagged) for (const f of t.flags) counts[f] = (counts[f] || 0) + 1;
  const summary = Object.entries(counts).map(([f, k]) => `${k} ${FLAG_WORDS[f] || f}`).join(", ");
  const order = [...flagged, ...touches.filter((t) => !t.flags.length)];
  el.innerHTML = `<p><b>${n} touches</b> recorded; ${flagged.length ? `<b>${flagged.length} flagged</b> (${esc(summary)}), listed first` : "none flagged"};
      <b class="gate-out">${out.length} left out</b>${out.length ? ` (${esc(out.map((t) => recName(cal, t.index)).join(", "))})` : ""}.
      Any touch can be left out (it stays out until put back) or retaken; the result lists what went in.</p>
    <div class="gate-scroll"><table class="list gate-list"><thead><tr><th>Touch</th><th>Flags</th><th>Leave out</th><th></th></tr></thead><tbody>
    ${order.map((t) => `<tr data-index="${t.index}" class="${t.out ? "left-out" : ""}"><td class="touch-name">${esc(recName(cal, t.index))}</td>
      <td>${flagHtml(t.flags)}</td>
      <td><input type="checkbox" class="leave-out" data-index="${t.index}" ${t.out ? "checked" : ""}></td>
      <td><button data-gate-retake="${t.index}">Retake</button></td></tr>`).join("")}</tbody></table></div>`;
}
$("#train-gate").addEventListener("change", (ev) => {
  if (ev.target.classList.contains("leave-out")) leaveOut(ev.target);
});
$("#train-gate").addEventListener("click", async (ev) => {
  const i = ev.target.dataset?.gateRetake;
  if (i === undefined) return;
  if (await act("/api/capture/retake", { index: Number(i), recording: "calibration" })) showPage("calibrate");
});
$("#train-result").addEventListener("click", async (ev) => {
  const d = ev.target.dataset || {};
  if (d.dropTouch !== undefined) {
    ev.target.disabled = true;
    if (await act("/api/train/leave_out", { index: Number(d.dropTouch), out: true })) act("/api/train");
    refreshSession();
  } else if (d.retakeTouch !== undefined) {
    if (await act("/api/capture/retake", { index: Number(d.retakeTouch), recording: "calibration" })) showPage("calibrate");
  }
});
$("#train-btn").addEventListener("click", async (ev) => {
  ev.currentTarget.disabled = true; // at once: a second click would only be refused
  await act("/api/train");
  renderTraining();
});
function renderTraining(t) {
  t = t || app.state?.training;
  const bar = $("#train-bar");
  // Each touch's error on the skin: the session's result, none while training runs.
  app.evidence.update(t?.running ? null : app.state?.session?.holdout, app.session?.calibration?.done);
  renderGate();
  if (t && t.session && t.session !== app.state?.session?.id) t = null; // another session's
  if (!t) {
    const h = app.state?.session?.holdout;
    bar.style.width = "0";
    $("#train-phase").textContent = "";
    $("#train-btn").disabled = !app.state?.session;
    $("#train-result").innerHTML = h ? resultHtml(h) : "";
    return;
  }
  if (t.running) {
    const phases = ["cross-validation", "final model", "with and without the map prior"];
    const k = Math.max(0, phases.indexOf(t.phase));
    const frac = (k + (t.total ? t.done / t.total : 0)) / phases.length;
    bar.style.width = `${Math.round(100 * frac)}%`;
    $("#train-phase").textContent = `training: ${t.phase}`;
    $("#train-btn").disabled = true;
    $("#train-result").innerHTML = ""; // no earlier result under the running bar
    return;
  }
  $("#train-btn").disabled = false;
  bar.style.width = t.result ? "100%" : "0";
  $("#train-phase").textContent = t.error ? `failed: ${t.error}` : "";
  $("#train-result").innerHTML = t.result ? resultHtml(t.result) : "";
}
// A training's touches by number (``number``, ``attempt``; older results: ``index`` only).
const entryName = (t) => touchName(t.number ?? t.index + 1, t.attempt ?? 1);
const touchList = (list) => list.map((t) => `${entryName(t)}${t.flags?.length ? ` (${t.flags.map((f) => FLAG_WORDS[f] || f).join(", ")})` : ""}`).join(", ");
function resultHtml(h) {
  const rec = h.n_recorded ?? h.n_point_logs;
  const outList = (h.left_out || []).map((t) => `<li>${esc(entryName(t))}: ${esc(t.why || "left out")}${t.flags?.length ? `; flagged ${esc(t.flags.map((f) => FLAG_WORDS[f] || f).join(", "))}` : ""}</li>`).join("");
  const inputs = `<p class="train-inputs">${h.left_out?.length ? `Trained on ${h.n_point_logs} of ${rec} touches.` : `Trained on all ${h.n_point_logs} touches.`}
    ${h.went_in ? `<span class="went-in">In: ${esc(h.went_in.map(entryName).join(", "))}.</span>` : ""}</p>
    ${outList ? `<div class="left-out-list">Left out:<ul>${outList}</ul></div>` : ""}
    ${h.flagged_kept?.length ? `<p class="hint">Flagged but kept: ${esc(touchList(h.flagged_kept))}.</p>` : ""}`;
  // Older results (before the cross-validation): their held-out figure, named so.
  const figure = h.ci95_mm
    ? `<div class="result">${h.mean_mm.toFixed(1)} mm <small class="ci">95 % interval ${h.ci95_mm[0].toFixed(1)} to ${h.ci95_mm[1].toFixed(1)} mm</small></div>
    <div class="hint">mean error of every touch predicted by a model that did not see it (${esc(h.how)} over all ${h.n_point_logs} touches; std ${h.std_mm.toFixed(1)}, median ${h.median_mm.toFixed(1)}, p95 ${h.p95_mm.toFixed(1)} mm; the interval: bootstrap over the touches).
    The final model learnt from all ${h.n_point_logs} touches${h.train_s != null ? ` (${h.train_s} s in all)` : ""}.</div>`
    : `<div class="result">${fmtErr(h)}</div><div class="hint">error on ${h.n_test} held-out touches (an older training: train again for the cross-validated error).</div>`;
  return `${figure}${inputs}${influenceHtml(h)}${app.evidence.html(h)}
    <p class="hint next-hint">Next: <b>Validate</b> on fresh touches, or try it on <b>Live</b>.</p>`;
}
// Which touch hurts the cross-validated error most (skinloc.evaluation.influence): the fall of
// the other touches' cross-validated error when it is left out too.
function influenceHtml(h) {
  const inf = h.influence;
  if (!inf || !inf.suspects?.length) return "";
  const s = inf.suspects[0];
  const cal = app.session?.calibration;
  const flags = (cal?.flags || [])[s.index] || [];
  const name = `${recName(cal, s.index)}${flags.length ? ` (${flags.map((f) => FLAG_WORDS[f] || f).join(", ")})` : ""}`;
  const big = s.gain_mm >= Math.max(1, 0.1 * s.others_with_mm);
  const how = `cross-validated error of the other touches ${s.others_with_mm.toFixed(1)} mm with it, ${s.others_without_mm.toFixed(1)} mm without it (${inf.n_folds}-fold; its own error ${s.error_mm.toFixed(1)} mm)`;
  if (!big) {
    return `<p class="influence hint">No single touch stands out: the most suspect, ${esc(name)}, moves the ${how}.</p>`;
  }
  return `<div class="influence warn-box"><b>Touch ${esc(name)} hurts the cross-validated error most</b>: ${how}.
    <div class="buttons"><button data-drop-touch="${s.index}">Leave it out and train again</button>
    <button data-retake-touch="${s.index}">Retake it</button></div></div>`;
}

// ------------------------------------------------------------------ live page
$("#live-start").addEventListener("click", async (ev) => {
  // Disabled at once: the start takes a while (the first one compiles), a repeat click would
  // queue behind it; the server's state says when it may be pressed again.
  ev.currentTarget.disabled = true;
  app.live.clear(true);
  app.plot.clear();
  await act("/api/live/start");
  renderLiveButtons();
});
// Start waits while a start prepares the pipeline or captures its baseline.
function renderLiveButtons() {
  const st = app.state;
  $("#live-start").disabled = !!st?.live_starting || st?.mode === "baseline";
  $("#live-start").textContent = st?.live_starting ? "Starting..." : "Start";
}
$("#live-stop").addEventListener("click", () => act("/api/capture/stop"));

// ------------------------------------------------------------------ rendering the state
function renderState(prev) {
  const st = app.state;
  if (!st) return;
  const mine = !st.lease || st.lease === clientId;
  $("#busy").classList.toggle("hidden", mine);
  // The server's message when it changes (a refusal shown meanwhile stays until then), never
  // one said on another page before this one was opened.
  if (st.message !== prev?.message && st.message !== app.dismissed) {
    app.dismissed = null;
    showMessage(st.message);
  }
  const d = st.device;
  link.lost = linkLost();
  renderLink();
  markConnected();
  if (d?.sim && !prev?.device?.sim && !$("#mouse-touch").checked) {
    $("#mouse-touch").checked = true; // the simulated skin again: the mouse touches it
    $("#mouse-touch").dispatchEvent(new Event("change"));
  }
  if (!d?.sim && $("#mouse-touch").checked) {
    $("#mouse-touch").checked = false; // only the simulated skin can be touched with the mouse
    $("#mouse-touch").dispatchEvent(new Event("change"));
  }
  const ps = $("#pill-session");
  ps.textContent = st.session ? st.session.name : "no session";
  ps.className = `pill ${st.session ? "" : "off"}`;
  $("#touch-toggle").classList.toggle("hidden", !d?.sim);
  if (st.session?.id !== prev?.session?.id) {
    // Another session: nothing of the last one stays on the pages (its coverage map, its
    // live tracks and gestures).
    if (app.coverageOn) {
      app.coverageOn = false;
      $(".coverage", guidedPanel("validate")).checked = false;
      $(".coverage-legend", guidedPanel("validate")).classList.add("hidden");
      $("#viewer-legend").innerHTML = VIEWER_LEGEND;
      app.viewer.clear("coverage");
    }
    app.live.clear(true);
    if (app.settings.el.open) app.settings.load();
  }
  if (st.session?.id !== prev?.session?.id || st.mode !== prev?.mode || st.guided?.index !== prev?.guided?.index) {
    refreshSession();
  }
  if (st.mode !== prev?.mode) app.live.render();
  if (st.live_starting !== prev?.live_starting || st.mode !== prev?.mode) renderLiveButtons();
  if (app.page === "calibrate") renderGuided("calibrate");
  if (app.page === "validate") renderGuided("validate");
  if (app.page === "train") renderTraining(st.training);
  const exportKey = (x) => `${x?.session?.id}:${x?.session?.has_model}:${x?.session?.validation?.n_attempts}:${x?.mode}`;
  if (app.page === "export" && exportKey(st) !== exportKey(prev)) app.exporter.refresh();
  // A recording started or ended (here, in another tab, or by a disconnect): its state.
  if (!!st.recording !== !!prev?.recording) app.record.poll();
  const g = st.guided;
  const wanted = g?.target ?? null;
  const key = wanted ? wanted.join(",") : "";
  if (key !== app.targetKey) {
    app.targetKey = key;
    app.viewer.setTarget(wanted, true, wanted ? g.number : null);
  }
  if (st.mode !== "live" && prev?.mode === "live") app.live.clear();
  $("#live-rate").textContent = d && !link.lost ? `${d.rate_hz.toFixed(1)} Hz` : "-";
}

function renderSession() {
  const s = app.session, v = app.viewer;
  const page = app.page;
  if (!s) {
    // Nothing open (or the app restarted): no old progress, no old dots.
    for (const g of ["planned", "done", "errors", "target", "coverage"]) v.clear(g);
    app.meshFor = null;
    app.targetKey = "";
    if (page === "calibrate") renderGuided("calibrate");
    if (page === "validate") renderGuided("validate");
    return;
  }
  if (page === "validate" && s.validation.error) {
    showMessage(s.validation.error, true);
  } else if (!["validate", "live", "train"].includes(page) && s.calibration.error) {
    showMessage(s.calibration.error, true);
  }
  // The 3D view shows what the last page with a view showed (the Export page saves that view).
  const view = app.viewPage || "calibrate";
  if (view === "validate" && !s.validation.error) {
    const val = s.validation;
    const pred = val.predicted || [];
    v.setErrors(val.done.slice(0, pred.length), pred, val.errors_mm || []);
    v.setPlanned(val.planned.slice(val.done.length), val.done.length);
    v.show(["errors", "planned", "target", ...(app.coverageOn ? ["coverage"] : [])]);
  } else if (view === "live") {
    v.show(["live"]);
  } else if (view === "train") {
    v.show(["evidence"]); // the touches' errors only (evidence.js)
  } else if (view === "calibrate" && !s.calibration.error) {
    const cal = s.calibration;
    v.setPlanned(cal.planned.slice(cal.done.length), cal.done.length);
    v.setDone(cal.done, cal.flags || [], (cal.numbers || []).map(([k]) => k));
    v.show(["planned", "done", "target"]);
  }
  if (page === "calibrate") renderGuided("calibrate");
  if (page === "validate") renderGuided("validate");
  if (page === "train") renderTraining();
}

function renderFrame(msg) {
  const opts = { status: app.sensors?.status, txLines: app.sensors?.tx_lines, rxLines: app.sensors?.rx_lines };
  if (app.page === "connect") drawHeat($("#heat-connect"), msg.delta, msg.tx, msg.rx, { ...opts, labels: true, unit: "counts" });
  if (app.page === "calibrate" || app.page === "validate") {
    const el = guidedPanel(app.page);
    drawHeat($(".guided-heat", el), msg.delta, msg.tx, msg.rx, { ...opts, unit: "counts" });
    const c = msg.capture;
    $(".bar-capture", el).style.width = c ? `${c.phase === "capturing" ? (100 * c.n) / c.of : c.phase === "wait_touch" ? 0 : 100}%` : "0";
    app.viewer.setTargetState(c?.phase === "capturing" ? "capturing" : msg.touched ? "touched" : "waiting");
    // A frame drawn after the link was lost (drawn late, at the next display frame) must not
    // bring the touch prompt back.
    if (c && ["calibrate", "validate"].includes(app.state?.mode) && !link.lost) {
      const [text, cls] = PHASE_TEXT[c.phase] || ["-", "idle"];
      const state = $(".big-state", el);
      state.textContent = c.phase === "capturing" ? `${text} ${c.n}/${c.of}` : msg.touched && c.phase === "wait_touch" ? "Touch detected: hold still" : text;
      state.className = `big-state ${cls}`;
    }
  }
  if (app.page === "live") drawHeat($("#heat-live"), msg.delta, msg.tx, msg.rx, { ...opts, unit: "counts" });
  const d = app.state?.device;
  if (d && performance.now() - (app.lastPill || 0) > 500) {
    app.lastPill = performance.now();
    renderPill();
    $("#live-rate").textContent = link.lost ? "-" : `${d.rate_hz.toFixed(1)} Hz`;
    if (app.page === "connect") renderDeviceStats(d);
  }
}

// ------------------------------------------------------------------ start
app.viewer = new Viewer($("#viewer"));
app.live = new LivePage(app.viewer, { $, esc, mm, later, mode: () => app.state?.mode });
app.exporter = new ExportPage($("#export-card"), { viewer: app.viewer, esc, sessionId: () => app.state?.session?.id });
app.evidence = new TrainEvidence(app.viewer);
referenceReady.then(() => renderTraining()); // the real skin's curves beside the session's
app.sensorTrace = new SensorTrace();
app.plot = new LivePlot($("#heat-live"));
app.touchView = new TouchView({ esc });
app.settings = new LiveSettings($("#record-panel"), $("#live-rate").closest("table"), { act, esc });
app.record = new RecordPanel($("#record-panel"), { act, esc });
app.viewer.onTouch = (path) => api("/api/sim/touch", { path }).catch(() => {});
const touchByMouse = () => {
  // The view's controls (view_controls.js): a drag on the skin moves the simulated finger.
  app.viewer.touchMode = $("#mouse-touch").checked;
  $("#viewer-hint").textContent = app.viewer.touchMode
    ? "drag on the skin: the finger · off it or Alt+drag: turn · ? keys" : "drag to turn, scroll to zoom · ? keys";
};
$("#mouse-touch").addEventListener("change", touchByMouse);
touchByMouse();
for (const b of $$("#nav button")) b.addEventListener("click", () => showPage(b.dataset.page));
$("#takeover").addEventListener("click", async () => {
  if (await act("/api/lease")) $("#busy").classList.add("hidden");
});
connectStream();
refreshSession();
const asked = location.hash.slice(1);
showPage($$("#nav button").some((b) => b.dataset.page === asked) ? asked : "sessions");
