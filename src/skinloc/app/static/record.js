// Record: the live stream (raw frames; the live view's contacts and gestures while it runs) to
// an HDF5 or MCAP file in the session's folder, with its duration and size while it runs.
import { fmtBytes } from "/static/export.js";

export class RecordPanel {
  // el: an empty element to fill; act(path, body): a page action (errors shown, never thrown).
  constructor(el, { act, esc }) {
    this.el = el;
    this.esc = esc;
    this.act = act;
    this.timer = null;
    el.classList.add("record");
    el.innerHTML = `
      <h3>Record <small>raw frames, contacts and gestures</small></h3>
      <div class="buttons">
        <select class="rec-format" title="File format">
          <option value="h5">HDF5 (skinloc info, replay)</option>
        </select>
        <button type="button" class="rec-start">Record</button>
        <button type="button" class="rec-stop" disabled>Stop recording</button>
      </div>
      <div class="rec-state hint">Not recording.</div>`;
    el.querySelector(".rec-start").addEventListener("click", async () => {
      const status = await act("/api/record/start", { format: el.querySelector(".rec-format").value });
      if (status) this.render(status);
    });
    el.querySelector(".rec-stop").addEventListener("click", async () => {
      const out = await act("/api/record/stop");
      if (out) this.render(out);
    });
    this.poll(); // the formats this install can write
  }

  // formats: {value: label} the server can write; only those are offered.
  offer(formats) {
    const select = this.el.querySelector(".rec-format");
    const have = [...select.options].map((o) => o.value).join(",");
    if (have === Object.keys(formats).join(",")) return;
    const keep = select.value;
    select.innerHTML = Object.entries(formats)
      .map(([k, label]) => `<option value="${this.esc(k)}">${this.esc(label)}</option>`)
      .join("");
    if (keep in formats) select.value = keep;
  }

  // status: the state message's ``recording`` (null when none runs) or /api/record's answer.
  render(status) {
    if (status?.formats) this.offer(status.formats);
    const on = !!status?.running;
    this.el.querySelector(".rec-start").disabled = on;
    this.el.querySelector(".rec-stop").disabled = !on;
    this.el.querySelector(".rec-format").disabled = on;
    const line = this.el.querySelector(".rec-state");
    line.classList.toggle("on", on);
    if (on) {
      const n = (k, word) => `${k} ${word}${k === 1 ? "" : "s"}`;
      line.textContent = `${status.seconds.toFixed(1)} s, ${fmtBytes(status.bytes)}: ${n(status.frames, "frame")}, ${n(status.contacts, "contact")}, ${n(status.gestures, "gesture")} (${status.name})`;
      if (!this.timer) this.timer = setInterval(() => this.poll(), 500);
      return;
    }
    clearInterval(this.timer);
    this.timer = null;
    const last = status?.last;
    if (last?.name) {
      const href = `/api/export/files/${encodeURIComponent(last.name)}`;
      line.innerHTML = `Recorded ${last.seconds.toFixed(1)} s, ${fmtBytes(last.bytes)}: <a href="${href}" download>${this.esc(last.name)}</a>${last.error ? ` <span class="flag">${this.esc(last.error)}</span>` : ""}`;
    } else if (status === null || status?.running === false) {
      if (!line.querySelector("a")) line.textContent = "Not recording.";
    }
  }

  async poll() {
    const r = await fetch("/api/record").catch(() => null);
    const data = r?.ok ? await r.json() : null;
    if (data) this.render(data);
  }
}
