// Live settings: the live pipeline's thresholds and filter, saved to the session's skins file
// (what `skinloc run --config` reads) and applied at once; and the measured latency of the
// pipeline (frame in to contact out), from the contacts the page receives.
const LATENCY_N = 200;

export class LiveSettings {
  // after: the element the panel follows; statsTable: the Live page's stats (a latency row
  // is added); act(path, body): a page action (errors shown, never thrown).
  constructor(after, statsTable, { act, esc }) {
    this.act = act;
    this.esc = esc;
    this.latencies = [];
    const row = document.createElement("tr");
    row.innerHTML = `<th title="processing latency of the live pipeline, frame in to contact out: median (95th percentile) of the last ${LATENCY_N} contacts">Latency</th><td id="live-latency">-</td>`;
    statsTable.querySelector("tbody")?.appendChild(row) ?? statsTable.appendChild(row);
    this.el = document.createElement("details");
    this.el.className = "live-settings";
    this.el.innerHTML = `<summary><b>Settings</b> <small>detection thresholds, filter</small></summary>
      <form class="form settings-form"></form>
      <div class="buttons"><button type="button" class="primary settings-save">Save and apply</button>
        <button type="button" class="settings-defaults">Defaults</button></div>
      <div class="hint settings-where"></div>`;
    after.after(this.el);
    this.el.addEventListener("toggle", () => { if (this.el.open) this.load(); });
    this.el.querySelector(".settings-save").addEventListener("click", () => this.save(false));
    this.el.querySelector(".settings-defaults").addEventListener("click", () => this.save(true));
  }

  async load() {
    const r = await fetch("/api/live/settings").catch(() => null);
    const d = r ? await r.json().catch(() => null) : null;
    const form = this.el.querySelector(".settings-form");
    if (!r?.ok || !d) {
      form.innerHTML = `<p class="hint">${this.esc(d?.detail || "no settings: open a session")}</p>`;
      return;
    }
    this.render(d);
  }

  render(d) {
    const esc = this.esc;
    this.fields = d.fields;
    this.el.querySelector(".settings-form").innerHTML = d.fields.map((f) => {
      const id = `set-${f.name}`;
      let input;
      if (f.kind === "bool") {
        input = `<input type="checkbox" id="${id}" name="${f.name}"${f.value ? " checked" : ""}>`;
      } else if (f.name === "filter") {
        input = `<select id="${id}" name="${f.name}">${["one-euro", "none"].map((o) => `<option${o === f.value ? " selected" : ""}>${o}</option>`).join("")}</select>`;
      } else {
        const step = f.kind === "int" ? "1" : "any";
        input = `<input type="number" id="${id}" name="${f.name}" step="${step}" value="${f.value}">`;
      }
      const changed = f.value !== f.default ? ` <span class="hint">(default ${esc(String(f.default))})</span>` : "";
      return `<label title="${esc(f.help)}"><span><code>${esc(f.name)}</code>${changed}</span>${input}<small class="hint">${esc(f.help)}</small></label>`;
    }).join("");
    this.el.querySelector(".settings-where").innerHTML = d.saved
      ? `Saved in the session's <code>${esc(d.file)}</code>: <code>${esc(d.command)}</code> in the sessions folder runs the same pipeline.`
      : `The defaults; saving writes the session's <code>${esc(d.file)}</code>, which <code>skinloc run --config</code> reads.`;
  }

  async save(defaults) {
    const values = {};
    for (const f of this.fields || []) {
      const input = this.el.querySelector(`[name="${f.name}"]`);
      if (defaults) values[f.name] = f.default;
      else if (input.type === "checkbox") values[f.name] = input.checked;
      else if (input.type === "number") values[f.name] = f.kind === "int" ? parseInt(input.value, 10) : parseFloat(input.value);
      else values[f.name] = input.value;
    }
    const d = await this.act("/api/live/settings", { values });
    if (d) this.render(d);
  }

  // A live message: keep its contacts' latency, show the median and p95 at most 4 times a second.
  add(msg) {
    for (const c of msg.contacts || []) if (Number.isFinite(c.latency_us)) this.latencies.push(c.latency_us);
    if (this.latencies.length > LATENCY_N) this.latencies.splice(0, this.latencies.length - LATENCY_N);
    const now = performance.now();
    if (now - (this.shown || 0) < 250 || !this.latencies.length) return;
    this.shown = now;
    const s = [...this.latencies].sort((a, b) => a - b);
    const q = (p) => s[Math.min(s.length - 1, Math.floor(p * s.length))];
    const ms = (us) => (us / 1000).toFixed(us < 10_000 ? 2 : 1);
    const el = document.getElementById("live-latency");
    el.textContent = `${ms(q(0.5))} ms (p95 ${ms(q(0.95))} ms)`;
    el.dataset.n = String(s.length);
  }
}
