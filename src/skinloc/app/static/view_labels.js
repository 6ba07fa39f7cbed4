// The 3D view's numbers, placed on screen: each beside its dot, never over another number, the
// view's controls or the current target's ring; a number that finds no free place is hidden
// (the current target's never is). Numbers of dots behind the skin are hidden with their dots.
import * as THREE from "/static/vendor/three.bundle.min.js";

const LABEL_H = 15; // px, the label's box (12 px text)
const LABEL_PAD = 4; // px added to the text's width
const GAP = 3; // px between a dot's edge and its number
// The boxes the numbers keep clear of: the view's own controls and notes.
const OBSTACLES = ".view-inset, .view-toolbar, .viewer-legend, .viewer-touch, .viewer-hint, .viewer-export";
// Where a number may go around its dot, in order of preference: unit directions (x right,
// y down), tried at the dot's edge and then a little farther out.
const AROUND = [[1, 0], [1, -1], [0, -1], [-1, -1], [-1, 0], [-1, 1], [0, 1], [1, 1]]
  .map(([x, y]) => [x / Math.hypot(x, y), y / Math.hypot(x, y)]);

const overlaps = (a, b) => a.x < b.x + b.w && b.x < a.x + a.w && a.y < b.y + b.h && b.y < a.y + a.h;

function candidate(item, [dx, dy], dist, w) {
  // The label box whose edge nearest the dot lies ``dist`` px from it along (dx, dy).
  const cx = item.x + dx * (dist + w / 2), cy = item.y + dy * (dist + LABEL_H / 2);
  return { x: cx - w / 2, y: cy - LABEL_H / 2, w, h: LABEL_H };
}

/**
 * Place labels on screen, the first items first.
 *
 * @param {Array<{x: number, y: number, r: number, w: number, force?: boolean}>} items dot centre
 *   and radius (px), label width (px); ``force`` places it even where everything is taken.
 * @param {Array<{x, y, w, h}>} obstacles boxes no label may cover (px).
 * @param {{w: number, h: number}} bounds the view (px): labels stay inside it.
 * @returns {Array<{x, y, w, h}|null>} each item's box, or null where it found no free place.
 */
export function placeLabels(items, obstacles, bounds) {
  const placed = [];
  // The dots, as boxes; the current target's (its ring) is never covered by another label.
  const dots = items.map((it) => ({ x: it.x - it.r, y: it.y - it.r, w: 2 * it.r, h: 2 * it.r }));
  const inside = (b) => b.x >= 0 && b.y >= 0 && b.x + b.w <= bounds.w && b.y + b.h <= bounds.h;
  const free = (b, self, avoidDots) => inside(b) && !placed.some((p) => p && overlaps(p, b))
    && !obstacles.some((o) => overlaps(o, b))
    && !dots.some((d, k) => k !== self && (avoidDots || items[k].force) && overlaps(d, b));
  return items.map((it, i) => {
    let box = null;
    // Clear of the other dots if it can be, else over a dot but never over another label.
    for (const avoidDots of [true, false]) {
      for (const dist of [it.r + GAP, it.r + GAP + 10]) {
        for (const dir of AROUND) {
          const b = candidate(it, dir, dist, it.w);
          if (free(b, i, avoidDots)) { box = b; break; }
        }
        if (box) break;
      }
      if (box) break;
    }
    if (!box && it.force) {
      box = candidate(it, AROUND[0], it.r + GAP, it.w);
      box.x = Math.max(0, Math.min(bounds.w - box.w, box.x));
      box.y = Math.max(0, Math.min(bounds.h - box.h, box.y));
    }
    placed.push(box);
    return box;
  });
}

export class LabelLayer {
  constructor(viewer) {
    this.viewer = viewer;
    this.enabled = true;
    this.el = document.createElement("div");
    this.el.className = "view-labels";
    viewer.el.appendChild(this.el);
    this.spans = [];
    this.placed = []; // what is shown: {text, x, y, w, h, target}, for tests and exports
    this.key = "";
    this.ray = new THREE.Raycaster();
    this.measure = document.createElement("canvas").getContext("2d");
    this.measure.font = "600 12px system-ui, sans-serif";
    this.widths = new Map();
  }

  width(text) {
    if (!this.widths.has(text)) this.widths.set(text, Math.ceil(this.measure.measureText(text).width) + LABEL_PAD);
    return this.widths.get(text);
  }

  obstacles() {
    const base = this.viewer.el.getBoundingClientRect();
    return [...this.viewer.el.querySelectorAll(OBSTACLES)].map((e) => e.getBoundingClientRect())
      .filter((r) => r.width > 0 && r.height > 0)
      .map((r) => ({ x: r.left - base.left, y: r.top - base.top, w: r.width, h: r.height }));
  }

  render() {
    const v = this.viewer, cam = v.camera;
    const w = v.el.clientWidth, h = v.el.clientHeight;
    if (!w || !h) return;
    const obstacles = this.obstacles();
    const key = [v.labelsVersion, this.enabled, w, h, ...cam.matrixWorld.elements, ...cam.projectionMatrix.elements,
      ...obstacles.flatMap((o) => [o.x, o.y, o.w, o.h])].map((x) => (typeof x === "number" ? x.toFixed(3) : x)).join(",");
    if (key === this.key) return;
    this.key = key;
    const items = this.collect(w, h);
    const boxes = placeLabels(items, obstacles, { w, h });
    this.placed = [];
    items.forEach((it, i) => { if (boxes[i]) this.placed.push({ ...boxes[i], text: it.text, target: it.force }); });
    this.draw();
  }

  collect(w, h) {
    // The labels to show, most important first: the current target's, then the nearest.
    const v = this.viewer;
    const items = [];
    const seen = new Set();
    for (const g of Object.values(v.groups)) {
      if (!g.visible) continue;
      for (const o of g.children) {
        const lab = o.userData.label;
        if (!lab) continue;
        const force = lab.priority === 0;
        if (!force && !this.enabled) continue;
        const { x, y, r, ndc, depth } = v.screenAt(o.position, lab.radiusMm, w, h);
        if (ndc.z > 1 || Math.abs(ndc.x) > 1.2 || Math.abs(ndc.y) > 1.2) continue;
        if (!force && this.hidden(o.position, depth)) continue;
        items.push({ x, y, r: Math.max(2, r), w: this.width(lab.text), text: lab.text, force, priority: lab.priority, depth });
      }
    }
    items.sort((a, b) => a.priority - b.priority || a.depth - b.depth);
    // The current target's number is also a planned dot's: shown once, at the target.
    return items.filter((it) => !seen.has(it.text) && seen.add(it.text));
  }

  hidden(p, depth) {
    // Behind the skin: the skin is hit well before the dot on the way from the camera.
    const v = this.viewer;
    if (!v.skin) return false;
    const dir = p.clone().sub(v.camera.position).normalize();
    this.ray.set(v.camera.position, dir);
    this.ray.far = depth;
    const hit = this.ray.intersectObject(v.skin)[0];
    return !!hit && hit.distance < depth - 2;
  }

  draw() {
    while (this.spans.length < this.placed.length) {
      const s = document.createElement("span");
      s.className = "view-label";
      this.el.appendChild(s);
      this.spans.push(s);
    }
    this.spans.forEach((s, i) => {
      const b = this.placed[i];
      s.classList.toggle("hidden", !b);
      if (!b) return;
      s.textContent = b.text;
      s.classList.toggle("target", !!b.target);
      s.style.transform = `translate(${b.x.toFixed(1)}px, ${b.y.toFixed(1)}px)`;
      s.style.width = `${b.w}px`;
    });
  }
}
