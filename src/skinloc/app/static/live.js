// The live page: every contact of a frame on the skin (a mark per track, in its colour, with
// its trail), a row per track, and the last gestures recognised.
import { TRACK_COLOURS } from "/static/viewer.js";

const GESTURES_SHOWN = 8;
// A track sends a contact every frame while it lasts; one silent this long has ended (its
// "end" may have been dropped on the way to a slow tab).
const TRACK_STALE_MS = 500;
const ARROWS = { up: "↑", down: "↓", left: "←", right: "→" };

export class LivePage {
  constructor(viewer, { $, esc, mm, later, mode }) {
    Object.assign(this, { viewer, $, esc, mm, later, mode });
    this.tracks = new Map(); // by key: the newest contact, the colour, when it came
    this.gestures = []; // newest first
    setInterval(() => this.dropStale(), 200);
  }

  contacts(msg) {
    // Every contact of a frame, one per track: each point joins its track's trail at once;
    // the panel is drawn once per display frame.
    const now = performance.now();
    for (const c of msg.contacts) {
      const key = c.track_id >= 0 ? `t${c.track_id}` : `u${c.touch_id}`;
      const ended = c.state === "end";
      // The finger's colour, chosen by the server (skinloc.live.contact.colour_index).
      const colour = c.colour;
      const point = c.position_m && c.position_m.every((v) => v != null) ? c.position_m : null;
      this.viewer.trackContact(key, colour, point, c.uncertainty_mm, ended);
      if (ended) this.tracks.delete(key);
      else this.tracks.set(key, { contact: c, colour, at: now });
      this.holding(c.track_id, c.timestamp_s ?? msg.timestamp_s, ended);
    }
    this.later("live", () => this.render());
  }

  // A long press is reported once held long enough (its end_s is that moment), while the
  // finger may still be down: its row follows the track until it lifts, so a 6 s hold says 6 s.
  // A track judged lifted because it fell silent (`stale`) was only late when it speaks again
  // (a tab or server that lagged half a second): its row follows it again until its end.
  holding(trackId, t, ended, stale = false) {
    let changed = false;
    for (const g of this.gestures) {
      if (g.kind !== "long_press" || !(g.track_ids || []).includes(trackId)) continue;
      if (g.released && !g.stale) continue; // lifted: its own end came
      if (Number.isFinite(t) && g.start_s != null) g.held_s = Math.max(g.held_s ?? 0, t - g.start_s);
      g.released = ended;
      g.stale = stale;
      changed = true;
    }
    if (changed) this.later("gestures", () => this.renderGestures());
  }

  gesture(msg) {
    this.gestures.unshift({ ...msg, received: new Date() });
    this.gestures.length = Math.min(this.gestures.length, GESTURES_SHOWN);
    this.later("gestures", () => this.renderGestures());
  }

  clear(gesturesToo = false) {
    this.viewer.clearLive();
    this.tracks.clear();
    this.later("live", () => this.render());
    if (gesturesToo) {
      this.gestures = [];
      this.renderGestures();
    }
  }

  dropStale() {
    const now = performance.now();
    let dropped = false;
    for (const [key, t] of this.tracks) {
      if (now - t.at <= TRACK_STALE_MS) continue;
      this.tracks.delete(key);
      this.viewer.endTrack(key);
      this.holding(t.contact.track_id, NaN, true, true); // its end lost on the way: held so far
      dropped = true;
    }
    if (dropped) this.later("live", () => this.render());
  }

  render() {
    const { $, mm } = this;
    const el = $("#live-state");
    const tracks = [...this.tracks.values()].sort((a, b) => a.colour - b.colour);
    // Whether it runs at all, then what it sees.
    const mode = this.mode?.();
    el.textContent = tracks.length ? `${tracks.length} contact${tracks.length > 1 ? "s" : ""}`
      : mode === "live" ? "not touched" : mode === "baseline" ? "Keep the skin untouched: baseline" : "Stopped: press Start";
    el.className = `big-state ${tracks.length ? "touch" : "idle"}`;
    // No stale rows from the last touch: only the tracks that last.
    $("#live-tracks tbody").innerHTML = tracks.map(({ contact: c, colour }) => {
      const swatch = TRACK_COLOURS[colour % TRACK_COLOURS.length];
      const unc = c.uncertainty_mm != null ? `± ${c.uncertainty_mm.toFixed(1)}` : "-";
      return `<tr><td><span class="swatch" style="background:${swatch}"></span>${c.track_id >= 0 ? c.track_id : "-"}</td>
        <td>${mm(c.position_m)}</td><td>${unc}</td><td>${c.strength != null ? c.strength.toFixed(0) : "-"}</td>
        <td class="confidence"><div class="conf"><div class="progress thin"><div style="width:${Math.round(100 * (c.confidence ?? 0))}%"></div></div>
          <span>${c.confidence != null ? c.confidence.toFixed(2) : "-"}</span></div></td></tr>`;
    }).join("") || `<tr><td colspan="5" class="hint">No contact.</td></tr>`;
  }

  renderGestures() {
    const { $, esc } = this;
    const time = (d) => d.toTimeString().slice(0, 8);
    $("#live-gestures").innerHTML = this.gestures.map((g) => {
      const dir = g.direction ? ` ${ARROWS[g.direction] ?? ""} ${esc(g.direction)}` : "";
      let span = g.end_s != null && g.start_s != null ? ` · ${(g.end_s - g.start_s).toFixed(2)} s` : "";
      if (g.kind === "long_press") {
        const held = Math.max(g.held_s ?? 0, g.end_s - g.start_s);
        span = ` · ${g.released ? "held" : "holding"} ${held.toFixed(2)} s${g.released ? "" : "…"}`;
      }
      const n = (g.track_ids || []).length;
      const ids = n ? ` · track${n > 1 ? "s" : ""} ${g.track_ids.map(esc).join(", ")}` : "";
      return `<li><b>${esc(String(g.kind).replace(/_/g, " "))}</b>${dir}<span class="hint"> · ${time(g.received)}${span}${ids}</span></li>`;
    }).join("") || `<li class="hint">None yet.</li>`;
  }
}
