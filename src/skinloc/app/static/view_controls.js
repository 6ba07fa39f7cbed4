// The 3D view's controls: the axes and the scale in a corner inset that turns with the camera,
// camera presets, label and axis toggles, the keyboard help (?), and the simulated finger
// that follows the mouse dragged on the skin.
import * as THREE from "/static/vendor/three.bundle.min.js";

const MM = 1000;
const INSET_BG = 0xffffff;
// Presets: where the camera looks from (the skin's frame: z up).
export const PRESETS = {
  top: new THREE.Vector3(0, 0, 1),
  front: new THREE.Vector3(0, -1, 0.25),
  side: new THREE.Vector3(1, 0, 0.25),
};
// Keys of the view, shown in the help with those of the capture pages (app.js handles those).
const KEYS = [
  ["1", "view from the top"], ["2", "view from the front"], ["3", "view from the side"],
  ["T", "face the current target (along the skin's normal there)"], ["R", "reset the view (the whole skin)"],
  ["L", "numbers on or off (the current target's stays)"], ["A", "axes and scale on or off"],
  ["?", "this help"], ["Esc", "close the help"],
];
const CAPTURE_KEYS = [["Space", "capture now"], ["Z", "take back the last touch"], ["S", "skip the target"]];
const MOUSE = [
  ["drag on the skin", "move the simulated finger over it (simulated skin, box ticked); a press near the red target lands on it"],
  ["drag off the skin, or Alt+drag", "turn the view"],
  ["scroll", "zoom"], ["right-drag, Shift+drag", "pan"],
];

export function niceLength(mm) {
  // 1, 2 or 5 times a power of ten, not over ``mm``.
  const p = 10 ** Math.floor(Math.log10(mm));
  return [5, 2, 1].map((k) => k * p).find((v) => v <= mm) || p;
}

const row = ([k, what]) => `<tr><td><kbd>${k}</kbd></td><td>${what}</td></tr>`;

export class ViewControls {
  constructor(viewer) {
    this.viewer = viewer;
    this.axesOn = true;
    this._inset();
    this._toolbar();
    this._help();
    this._finger();
    document.addEventListener("keydown", (ev) => this._key(ev));
  }

  // ---------------------------------------------------------------- inset: axes and scale
  _inset() {
    const v = this.viewer;
    this.inset = document.createElement("div");
    this.inset.className = "view-inset";
    this.inset.innerHTML = `<div class="view-axes"><span class="ax x">x</span><span class="ax y">y</span><span class="ax z">z</span></div>
      <div class="view-scale" title="length on the skin at its centre"><div class="bar"></div><span></span></div>`;
    v.el.appendChild(this.inset);
    this.insetScene = new THREE.Scene();
    const colours = [0xd13b3b, 0x1e9e5a, 0x2f6fde];
    colours.forEach((c, k) => {
      const end = new THREE.Vector3().setComponent(k, 1);
      const line = new THREE.Line(new THREE.BufferGeometry().setFromPoints([new THREE.Vector3(), end]),
        new THREE.LineBasicMaterial({ color: c }));
      const tip = new THREE.Mesh(new THREE.ConeGeometry(0.07, 0.22, 12), new THREE.MeshBasicMaterial({ color: c }));
      tip.position.copy(end);
      tip.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), end);
      this.insetScene.add(line, tip);
    });
    this.insetCamera = new THREE.OrthographicCamera(-1.6, 1.6, 1.6, -1.6, 0.1, 10);
  }

  render() {
    // After the main view: the inset's axes turned as the camera is, and the scale bar.
    const v = this.viewer, r = v.renderer;
    if (!this.axesOn || !v.el.clientWidth) return;
    const box = this.inset.querySelector(".view-axes");
    const b = box.getBoundingClientRect(), c = r.domElement.getBoundingClientRect();
    const size = b.width, x = b.left - c.left, top = b.top - c.top;
    if (!size) return;
    const cam = this.insetCamera;
    cam.position.copy(v.viewDirection()).multiplyScalar(3);
    cam.quaternion.copy(v.camera.quaternion);
    cam.updateMatrixWorld();
    const bottom = v.el.clientHeight - top - size;
    const clear = r.getClearColor(new THREE.Color());
    r.setScissorTest(true);
    r.setScissor(x, bottom, size, size);
    r.setViewport(x, bottom, size, size);
    r.setClearColor(INSET_BG);
    r.clear();
    r.render(this.insetScene, cam);
    r.setScissorTest(false);
    r.setViewport(0, 0, v.el.clientWidth, v.el.clientHeight);
    r.setClearColor(clear);
    ["x", "y", "z"].forEach((name, k) => {
      const p = new THREE.Vector3().setComponent(k, 1.28).project(cam);
      const span = this.inset.querySelector(`.ax.${name}`);
      const clamp = (q, hi) => Math.max(1, Math.min(hi, q));
      span.style.left = `${clamp(((p.x + 1) / 2) * size - 4, size - 10)}px`;
      span.style.top = `${clamp(((1 - p.y) / 2) * size - 8, size - 17)}px`;
    });
    // Millimetres per pixel at the orbit centre (the skin's middle): a round length ~60 px.
    const dist = v.camera.position.distanceTo(v.controls.target);
    const mmPerPx = (2 * dist * Math.tan(THREE.MathUtils.degToRad(v.camera.fov) / 2)) / v.el.clientHeight;
    const len = niceLength(60 * mmPerPx);
    this.inset.querySelector(".view-scale .bar").style.width = `${(len / mmPerPx).toFixed(1)}px`;
    this.inset.querySelector(".view-scale span").textContent = `${len} mm`;
  }

  setAxes(on) {
    this.axesOn = on;
    this.inset.classList.toggle("hidden", !on);
    this.toolbar.querySelector("[data-toggle=axes]").checked = on;
    this.viewer.dirty = true;
  }

  setLabels(on) {
    this.viewer.labels.enabled = on;
    this.toolbar.querySelector("[data-toggle=labels]").checked = on;
    this.viewer.dirty = true;
  }

  // ---------------------------------------------------------------- presets and toggles
  _toolbar() {
    this.toolbar = document.createElement("div");
    this.toolbar.className = "view-toolbar";
    this.toolbar.innerHTML = `
      <button data-view="top" title="view from the top (1)">Top</button>
      <button data-view="front" title="view from the front (2)">Front</button>
      <button data-view="side" title="view from the side (3)">Side</button>
      <button data-view="target" title="face the current target (T)">Target</button>
      <button data-view="reset" title="the whole skin (R)">Reset</button>
      <label title="numbers (L)"><input type="checkbox" data-toggle="labels" checked> 123</label>
      <label title="axes and scale (A)"><input type="checkbox" data-toggle="axes" checked> axes</label>
      <button data-help title="keys and mouse (?)">?</button>`;
    this.viewer.el.appendChild(this.toolbar);
    this.toolbar.addEventListener("click", (ev) => {
      const b = ev.target.closest("button");
      if (b?.dataset.view) this.preset(b.dataset.view);
      if (b && "help" in b.dataset) this.toggleHelp();
      // The keys drive the capture: a clicked control must not keep them.
      if (ev.target.matches("button, input")) ev.target.blur();
    });
    this.toolbar.addEventListener("change", (ev) => {
      const t = ev.target.dataset.toggle;
      if (t === "labels") this.setLabels(ev.target.checked);
      if (t === "axes") this.setAxes(ev.target.checked);
    });
  }

  preset(name) {
    const v = this.viewer;
    if (!v.skin) return;
    if (name === "reset") v.overview();
    else if (name === "target") {
      if (v.targetPoint) v.lookAt(v.targetPoint, v.targetNormal);
    } else if (PRESETS[name]) v.flyTo(PRESETS[name]);
  }

  // ---------------------------------------------------------------- keyboard help
  _help() {
    this.help = document.createElement("div");
    this.help.className = "view-help hidden";
    this.help.setAttribute("role", "dialog");
    this.help.innerHTML = `<div class="view-help-card">
      <h2>Keys and mouse <small>press ? or Esc to close</small></h2>
      <h3>3D view</h3><table>${KEYS.map(row).join("")}</table>
      <h3>Calibrate and Validate</h3><table>${CAPTURE_KEYS.map(row).join("")}</table>
      <h3>Mouse on the 3D view</h3><table>${MOUSE.map(row).join("")}</table></div>`;
    document.body.appendChild(this.help);
    this.help.addEventListener("click", (ev) => { if (ev.target === this.help) this.toggleHelp(false); });
  }

  toggleHelp(on = this.help.classList.contains("hidden")) {
    this.help.classList.toggle("hidden", !on);
    // The keys drive the view and the capture, not a toolbar button left with the focus.
    if (this.toolbar.contains(document.activeElement)) document.activeElement.blur();
  }

  _key(ev) {
    const typing = ev.target.closest?.("textarea, select, input:not([type=checkbox]):not([type=radio]):not([type=button]):not([type=submit])");
    if (typing || ev.ctrlKey || ev.metaKey || ev.altKey) return;
    if (ev.key === "?") { ev.preventDefault(); this.toggleHelp(); return; }
    if (ev.key === "Escape" && !this.help.classList.contains("hidden")) { this.toggleHelp(false); return; }
    if (!this.viewer.el.offsetParent) return; // the view is not on this page
    const k = ev.key.toLowerCase();
    const view = { 1: "top", 2: "front", 3: "side", t: "target", r: "reset" }[k];
    if (view) { ev.preventDefault(); this.preset(view); }
    if (k === "l") this.setLabels(!this.viewer.labels.enabled);
    if (k === "a") this.setAxes(!this.axesOn);
  }

  // ---------------------------------------------------------------- the simulated finger
  _finger() {
    // A press on the skin puts the finger there and a drag moves it; a press off the skin (or
    // with Alt) turns the view as before. The path goes with its event times, one request at
    // a time carrying every point since the last: the server plays it at the mouse's pace, so
    // a slow server delays a stroke but never turns it into a slow one or a jump.
    const v = this.viewer, el = v.renderer.domElement;
    this.drag = null;
    const down = (ev) => {
      if (!v.touchMode || !v.onTouch || ev.button !== 0 || ev.altKey || ev.shiftKey || ev.ctrlKey) return;
      let p = v.hit(ev.clientX, ev.clientY);
      if (!p) return;
      // A press near the red target lands on it: the target is easy to hit with the mouse.
      if (v.targetPoint && this._screenDistance(v.targetPoint, ev) < 16) p = v.targetPoint.clone();
      // Before the orbit controls see it (they listen on the same element).
      ev.stopImmediatePropagation();
      ev.preventDefault();
      try {
        el.setPointerCapture(ev.pointerId); // the drag goes on outside the view
      } catch {
        // a pointer the browser does not track (a synthetic event): moves over the view only
      }
      this.drag = { id: ev.pointerId };
      this._send(ev.timeStamp, [p.x / MM, p.y / MM, p.z / MM]);
    };
    const move = (ev) => {
      if (!this.drag || ev.pointerId !== this.drag.id) return;
      ev.stopImmediatePropagation();
      const p = v.hit(ev.clientX, ev.clientY);
      if (p) this._send(ev.timeStamp, [p.x / MM, p.y / MM, p.z / MM]); // off the skin: it stays
    };
    const up = (ev) => {
      if (!this.drag || ev.pointerId !== this.drag.id) return;
      ev.stopImmediatePropagation();
      this.drag = null;
      this._send(ev.timeStamp, null);
    };
    el.addEventListener("pointerdown", down, { capture: true });
    el.addEventListener("pointermove", move, { capture: true });
    el.addEventListener("pointerup", up, { capture: true });
    el.addEventListener("pointercancel", up, { capture: true });
    this.outbox = { busy: false, path: [] };
  }

  _screenDistance(p, ev) {
    const r = this.viewer.renderer.domElement.getBoundingClientRect();
    const s = p.clone().project(this.viewer.camera);
    return Math.hypot(r.left + ((s.x + 1) / 2) * r.width - ev.clientX, r.top + ((1 - s.y) / 2) * r.height - ev.clientY);
  }

  async _send(ms, point) {
    // ``ms``: the event's time (ms, the page's clock)
    const o = this.outbox;
    o.path.push([ms / 1000, point]);
    if (o.busy) return;
    o.busy = true;
    try {
      while (o.path.length) {
        const path = o.path.splice(0, 1000); // the server takes at most 1000 points a request
        await this.viewer.onTouch(path);
      }
    } finally {
      o.busy = false;
    }
  }
}
