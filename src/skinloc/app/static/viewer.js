// The skin in 3D: mesh, targets, touches, the live tracks and the validation error map.
// Coordinates arrive in metres and are shown in millimetres.
import * as THREE from "/static/vendor/three.bundle.min.js";
import { LabelLayer } from "/static/view_labels.js";
import { ViewControls } from "/static/view_controls.js";

const MM = 1000;
const v3 = (p) => new THREE.Vector3(p[0] * MM, p[1] * MM, p[2] * MM);

export function errorColor(mm) {
  // green (0 mm) -> yellow (10 mm) -> red (20 mm and more)
  const t = Math.max(0, Math.min(1, mm / 20));
  return new THREE.Color().setHSL((1 - t) * 0.33, 0.8, 0.45);
}

// The coverage map's colours, t in [0, 1] (low to high expected error): dark blue, teal,
// yellow-green, orange. Not the validation errors' green-to-red, whose scale is fixed in mm.
export const COVERAGE_STOPS = ["#2c3e8f", "#1f9e89", "#b5de2b", "#f98e09"];
export function coverageColor(t) {
  const x = Math.max(0, Math.min(1, t)) * (COVERAGE_STOPS.length - 1);
  const k = Math.min(Math.floor(x), COVERAGE_STOPS.length - 2);
  return new THREE.Color(COVERAGE_STOPS[k]).lerp(new THREE.Color(COVERAGE_STOPS[k + 1]), x - k);
}

const TRAIL = 60; // points of a track's trail
const TRAIL_STEP_MM = 0.5; // a point joins the trail once the track has moved this far
const TRACK_MARKS = 6; // tracks drawn at once
// The fingers' palette is the server's (skinloc.live.contact.TRACK_COLOURS, shared with the
// ROS 2 and Foxglove sinks), written into the page.
export const TRACK_COLOURS = document.querySelector('meta[name="skinloc-track-colours"]').content.split(" ");

class TrackMark {
  // One track's dot, halo and trail; the trail is one fixed buffer drawn up to its length.
  constructor(group, dotGeometry, haloGeometry) {
    this.dot = new THREE.Mesh(dotGeometry, new THREE.MeshStandardMaterial({ color: 0x2f6fde }));
    this.halo = new THREE.Mesh(haloGeometry,
      new THREE.MeshBasicMaterial({ color: 0x2f6fde, transparent: true, opacity: 0.18, depthWrite: false }));
    this.buf = new Float32Array(TRAIL * 3);
    const geo = new THREE.BufferGeometry();
    this.pos = new THREE.BufferAttribute(this.buf, 3);
    this.pos.setUsage(THREE.DynamicDrawUsage);
    geo.setAttribute("position", this.pos);
    geo.setDrawRange(0, 0);
    // Predictions lie a little inside or outside the surface: the trail is drawn over the skin.
    this.line = new THREE.Line(geo, new THREE.LineBasicMaterial({ color: 0x2f6fde, depthTest: false, transparent: true }));
    this.line.frustumCulled = false;
    this.line.renderOrder = 5;
    group.add(this.dot, this.halo, this.line);
    this.clear();
  }

  begin(key, colour) {
    this.key = key;
    this.live = true;
    this.startedAt = performance.now();
    this.n = 0;
    this.line.geometry.setDrawRange(0, 0);
    for (const m of [this.dot.material, this.halo.material, this.line.material]) m.color.set(colour);
    this.dot.material.emissive.set(colour).multiplyScalar(0.3);
    this.line.material.opacity = 1;
  }

  add(x, y, z, uncertaintyMm) {
    this.dot.position.set(x, y, z);
    this.dot.visible = true;
    const r = Number.isFinite(uncertaintyMm) ? Math.max(4, uncertaintyMm) : 0;
    this.halo.visible = r > 0;
    this.halo.position.set(x, y, z);
    this.halo.scale.setScalar(r || 1);
    const j = 3 * (this.n - 1);
    if (this.n && Math.hypot(x - this.buf[j], y - this.buf[j + 1], z - this.buf[j + 2]) < TRAIL_STEP_MM) {
      return; // a finger held still keeps the trail of where it came from
    }
    if (this.n === TRAIL) {
      this.buf.copyWithin(0, 3); // the oldest point goes
      this.n -= 1;
    }
    const i = 3 * this.n;
    this.buf[i] = x;
    this.buf[i + 1] = y;
    this.buf[i + 2] = z;
    this.n += 1;
    this.pos.needsUpdate = true;
    this.line.geometry.setDrawRange(0, this.n);
  }

  resume() {
    // ended for its silence only (the live page's stale rule): the same track goes on
    this.live = true;
    this.line.material.opacity = 1;
  }

  end() {
    this.live = false;
    this.dot.visible = this.halo.visible = false;
    this.line.material.opacity = 0.35;
  }

  clear() {
    this.end();
    this.key = null;
    this.startedAt = 0;
    this.n = 0;
    this.line.geometry.setDrawRange(0, 0);
  }
}
// Whether WebGL runs on the CPU (no GPU, or the GPU blocked): the renderer's name says so.
function softwareGl(renderer) {
  const gl = renderer.getContext();
  const info = gl.getExtension("WEBGL_debug_renderer_info");
  const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
  return /swiftshader|llvmpipe|softpipe|software/i.test(name);
}

export class Viewer {
  constructor(el) {
    this.el = el;
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
    this.renderer.setClearColor(0xf7f8fb);
    el.prepend(this.renderer.domElement);
    // With no GPU (SwiftShader, llvmpipe) a draw at 1440 x 900 costs about 35 ms of CPU: motion
    // (a flight, the orbit's damping) is drawn at most 20 times a second there, not as fast as
    // the draws go. A user who asks for less motion gets no flights at all.
    this.minFrameMs = softwareGl(this.renderer) ? 50 : 0;
    this.lastDraw = -Infinity;
    this.lessMotion = window.matchMedia("(prefers-reduced-motion: reduce)");
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 1, 5000);
    this.camera.up.set(0, 0, 1);
    this.controls = new THREE.OrbitControls(this.camera, this.renderer.domElement);
    this.controls.enableDamping = true;
    this.controls.addEventListener("change", () => { this.dirty = true; });
    this.dirty = true;
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8890a0, 1.6));
    const sun = new THREE.DirectionalLight(0xffffff, 1.4);
    sun.position.set(200, -300, 400);
    this.scene.add(sun);
    this.groups = {};
    for (const name of ["skin", "planned", "done", "target", "live", "errors", "coverage"]) {
      this.groups[name] = new THREE.Group();
      this.scene.add(this.groups[name]);
    }
    this.center = new THREE.Vector3();
    this.radius = 100;
    this.fly = null;
    this.marks = [];
    this.onTouch = null;
    this.touchMode = false;
    this.raycaster = new THREE.Raycaster();
    this.labelsVersion = 0;
    // Drawn over the view after each render: the numbers (placed on screen so that none
    // overlaps another) and the corner inset with the axes and the scale.
    this.labels = new LabelLayer(this);
    // The current target's pulse: a CSS halo over its ring, placed after each render. A pulse
    // drawn in WebGL redrew the whole view 12 times a second while a touch was awaited (about
    // 0.9 of a core in software WebGL at 1440 x 900).
    this.pulse = document.createElement("div");
    this.pulse.className = "target-pulse hidden";
    el.appendChild(this.pulse);
    this.controlsUi = new ViewControls(this);
    new ResizeObserver(() => this.resize()).observe(el);
    this.resize();
    const tick = (t) => {
      this._animate(t);
      requestAnimationFrame(tick);
    };
    requestAnimationFrame(tick);
  }

  resize() {
    this.dirty = true;
    const w = this.el.clientWidth, h = this.el.clientHeight;
    if (!w || !h) return; // hidden: fit when shown
    const aspect = w / h;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = aspect;
    this.camera.updateProjectionMatrix();
    if (this.skin && Math.abs(aspect - (this.fitAspect || 0)) > 0.02) {
      // A narrower or wider view: keep the direction, move so the whole skin fits again.
      this.fitAspect = aspect;
      const dir = this.camera.position.clone().sub(this.controls.target).normalize();
      this.camera.position.copy(this.controls.target).add(dir.multiplyScalar(this.fitDistance()));
      this.controls.update();
    }
  }

  fitDistance() {
    // Distance at which the bounding sphere fits the narrower of the two fields of view.
    const vfov = THREE.MathUtils.degToRad(this.camera.fov);
    const hfov = 2 * Math.atan(Math.tan(vfov / 2) * this.camera.aspect);
    return (1.0 * this.radius) / Math.sin(Math.min(vfov, hfov) / 2);
  }

  clear(name) {
    this.dirty = true;
    this.labelsVersion += 1;
    const g = this.groups[name];
    while (g.children.length) {
      const c = g.children.pop();
      c.geometry?.dispose?.();
      if (c.isSprite) c.material.dispose();
    }
  }

  setMesh(vertices, faces) {
    const key = `${vertices.length}:${faces.length}:${vertices[0]}`;
    if (key === this.meshKey) return;
    this.meshKey = key;
    this.clear("skin");
    const geo = new THREE.BufferGeometry();
    geo.setAttribute("position", new THREE.Float32BufferAttribute(vertices.flat().map((x) => x * MM), 3));
    geo.setIndex(faces.flat());
    geo.computeVertexNormals();
    this.skinGeometry = geo;
    const mesh = new THREE.Mesh(geo, new THREE.MeshStandardMaterial({
      color: 0xe3c9ad, roughness: 0.85, metalness: 0, side: THREE.DoubleSide,
      polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1,
    }));
    this.skin = mesh;
    this.groups.skin.add(mesh);
    const edges = new THREE.LineSegments(new THREE.EdgesGeometry(geo, 25),
      new THREE.LineBasicMaterial({ color: 0xb59a80 }));
    this.groups.skin.add(edges);
    geo.computeBoundingSphere();
    this.center.copy(geo.boundingSphere.center);
    this.radius = geo.boundingSphere.radius;
    this.controls.target.copy(this.center);
    this.fitAspect = this.camera.aspect;
    this.homeDir = this._outside();
    this.camera.position.copy(this.center).add(this.homeDir.clone().multiplyScalar(this.fitDistance()));
    this.controls.update();
    if (this.targetPoint) {
      // A target set before its skin came: its normal now, and face it.
      this.targetNormal = this.normalAt(this.targetPoint);
      this.targetRing.lookAt(this.targetPoint.clone().add(this.targetNormal));
      this.lookAt(this.targetPoint, this.targetNormal);
    }
  }

  _label(text, at, radiusMm, priority = 1) {
    // A number beside a dot: an empty object at the dot that the label layer (view_labels.js)
    // projects and places on screen each frame, beside the dot and clear of the other labels.
    const o = new THREE.Object3D();
    o.position.copy(at);
    o.userData.label = { text, radiusMm, priority };
    this.labelsVersion += 1;
    return o;
  }

  _dots(name, points, color, size, opacity = 1, first = null) {
    // Dots; numbered from ``first`` (1-based, as in the touch list and on the printed sheet),
    // or by ``first[i]`` when it is a list (each touch's target number).
    this.clear(name);
    const geo = new THREE.SphereGeometry(size, 14, 10);
    for (let i = 0; i < points.length; i++) {
      const c = Array.isArray(color) ? color[i] : color;
      const m = new THREE.Mesh(geo, new THREE.MeshStandardMaterial({ color: c, transparent: opacity < 1, opacity }));
      const p = v3(points[i]);
      m.position.copy(p);
      m.userData.index = i;
      this.groups[name].add(m);
      const number = Array.isArray(first) ? first[i] ?? i + 1 : first != null ? first + i : null;
      if (number != null) this.groups[name].add(this._label(String(number), p, size));
    }
  }

  setPlanned(points, first = 0) { this._dots("planned", points, 0x9aa3b5, 1.6, 0.7, first + 1); }

  setDone(points, flags, numbers = null) {
    // ``numbers``: each touch's target number (a retake keeps its target's); else 1, 2, ...
    const colors = points.map((_, i) => ((flags[i] || []).length ? 0xe08a00 : 0x1e9e5a));
    this._dots("done", points, colors, 2.4, 1, numbers?.length ? numbers : 1);
  }

  setTarget(point, turn = true, number = null) {
    // The current target: a red dot and a ring with a pulse, its number always shown
    // (``number``, 1-based); ``turn`` flies the camera to face it.
    this.clear("target");
    this.pulse.classList.add("hidden");
    this.pulse.style.color = "";
    if (!point) {
      // The last target is done: back to the whole skin.
      if (this.targetRing && turn) this.overview();
      this.targetRing = null;
      this.targetPoint = this.targetNormal = null;
      return;
    }
    const p = v3(point);
    const sphere = new THREE.Mesh(new THREE.SphereGeometry(4, 24, 16),
      new THREE.MeshStandardMaterial({ color: 0xd13b3b, emissive: 0x550000 }));
    sphere.position.copy(p);
    const ring = new THREE.Mesh(new THREE.TorusGeometry(8, 0.8, 8, 40),
      new THREE.MeshBasicMaterial({ color: 0xd13b3b }));
    ring.position.copy(p);
    const n = this.normalAt(p);
    ring.lookAt(p.clone().add(n));
    this.groups.target.add(sphere, ring);
    // Placed clear of the ring (8.8 mm) with a margin.
    if (number != null) this.groups.target.add(this._label(String(number), p, 11, 0));
    this.targetRing = ring;
    this.targetPoint = p;
    this.targetNormal = n;
    this.targetState = null;
    if (turn) this.lookAt(p, n);
  }

  setTargetState(state) {
    // The ring shows the touch as it happens: red waiting, green touched, blue capturing.
    if (!this.targetRing || state === this.targetState) return;
    this.targetState = state;
    const colour = { touched: 0x1e9e5a, capturing: 0x2f6fde }[state] ?? 0xd13b3b;
    this.targetRing.material.color.setHex(colour);
    this.pulse.style.color = `#${colour.toString(16).padStart(6, "0")}`;
    this.dirty = true;
  }

  screenAt(p, radiusMm, w, h) {
    // Where ``p`` (world, mm) is on a ``w`` x ``h`` px view: its centre ``x``, ``y`` and the
    // radius ``r`` of ``radiusMm`` about it (px), its normalised device coordinates ``ndc``
    // (on the view within +-1, behind the camera at z > 1) and its distance ``depth`` (mm).
    const cam = this.camera;
    const ndc = p.clone().project(cam);
    const right = new THREE.Vector3().setFromMatrixColumn(cam.matrixWorld, 0);
    const edge = p.clone().addScaledVector(right, radiusMm).project(cam);
    const x = ((ndc.x + 1) / 2) * w, y = ((1 - ndc.y) / 2) * h;
    const r = Math.hypot(((edge.x + 1) / 2) * w - x, ((1 - edge.y) / 2) * h - y);
    return { x, y, r, ndc, depth: cam.position.distanceTo(p) };
  }

  _placePulse() {
    // The halo at the ring's place on screen and of its size; hidden with the target, off the
    // view or behind the skin.
    const p = this.targetRing?.parent ? this.targetPoint : null;
    const w = this.el.clientWidth, h = this.el.clientHeight;
    const at = p && w && h ? this.screenAt(p, 8.8, w, h) : null;
    const off = !at || at.ndc.z > 1 || Math.abs(at.ndc.x) > 1 || Math.abs(at.ndc.y) > 1;
    if (off || this.labels.hidden(p, at.depth)) {
      this.pulse.classList.add("hidden");
      return;
    }
    const r = Math.max(4, at.r);
    Object.assign(this.pulse.style, {
      left: `${at.x}px`, top: `${at.y}px`, width: `${2 * r}px`, height: `${2 * r}px`,
    });
    this.pulse.classList.remove("hidden");
  }

  normalAt(p) {
    const pos = this.skinGeometry?.attributes.position, nor = this.skinGeometry?.attributes.normal;
    if (!pos) return new THREE.Vector3(0, 0, 1);
    let best = 0, bestD = Infinity;
    const q = new THREE.Vector3();
    for (let i = 0; i < pos.count; i++) {
      q.fromBufferAttribute(pos, i);
      const d = q.distanceToSquared(p);
      if (d < bestD) { bestD = d; best = i; }
    }
    const n = new THREE.Vector3().fromBufferAttribute(nor, best).normalize();
    // Face the viewer from the outside of the skin (away from its centre).
    const out = p.clone().sub(this.center);
    if (n.dot(out) < 0) n.negate();
    return n;
  }

  _outside() {
    // The whole skin seen from its outside: along the normal of the skin point nearest its
    // centre, turned away from the centre, a little from above.
    const pos = this.skinGeometry.attributes.position, nor = this.skinGeometry.attributes.normal;
    const q = new THREE.Vector3();
    let best = 0, bestD = Infinity;
    for (let i = 0; i < pos.count; i++) {
      const d = q.fromBufferAttribute(pos, i).distanceToSquared(this.center);
      if (d < bestD) { bestD = d; best = i; }
    }
    const out = q.fromBufferAttribute(pos, best).clone().sub(this.center);
    const n = new THREE.Vector3().fromBufferAttribute(nor, best).normalize();
    if (out.lengthSq() > 1e-9 && n.dot(out) < 0) n.negate();
    if (!Number.isFinite(n.x) || n.lengthSq() < 0.5) return new THREE.Vector3(0.9, -1.6, 1.4).normalize();
    return n.add(new THREE.Vector3(0, 0, 0.4)).normalize();
  }

  overview() {
    this.flyTo(this.homeDir || new THREE.Vector3(0, -1, 1).normalize());
  }

  lookAt(p, n) {
    // Face-on: the camera looks along the surface normal at ``p`` (a target on the rim is seen
    // flat, not edge-on), still at the whole skin, so it can be clicked and its neighbours seen.
    this.flyTo(n);
  }

  flyTo(dir, ms = 700) {
    // Turn smoothly to look at the skin's centre from ``dir``, at the distance that fits it:
    // the direction turns on a great circle (never through the skin), the distance eases.
    if (this.lessMotion.matches) ms = 0;
    const from = this.camera.position.clone().sub(this.controls.target);
    const to = dir.clone().normalize();
    if (Math.abs(to.z) > 0.999) to.set(0, -0.02, Math.sign(to.z)).normalize(); // keep "up" defined
    const toDist = this.fitDistance();
    // No view yet (the camera at its centre, before the mesh came): start where it goes.
    const fresh = from.length() < 1e-6;
    this.fly = {
      fromDir: fresh ? to.clone() : from.clone().normalize(), fromDist: fresh ? toDist : from.length(), toDir: to,
      fromTarget: this.controls.target.clone(), t0: performance.now(), ms,
    };
    this.fly.turn = new THREE.Quaternion().setFromUnitVectors(this.fly.fromDir, to);
    this.dirty = true;
  }

  viewDirection() {
    // Unit vector from the orbit centre to the camera.
    return this.camera.position.clone().sub(this.controls.target).normalize();
  }

  // Live tracks: each contact's track has a mark (dot, uncertainty halo, trail) in its own
  // colour. The marks and their trail buffers are made once and reused: nothing is allocated
  // per point, and a lifted track keeps its faded trail until its mark is needed again.
  trackContact(key, colour, point, uncertaintyMm, ended) {
    let mark = this.marks.find((m) => m.key === key);
    if (!mark) {
      if (ended) return;
      mark = this._freeMark();
      mark.begin(key, TRACK_COLOURS[colour % TRACK_COLOURS.length]);
    } else if (!mark.live && !ended) {
      mark.resume(); // a track's end comes once: it was only late (a lagging tab or server)
    }
    if (point) mark.add(point[0] * MM, point[1] * MM, point[2] * MM, uncertaintyMm);
    if (ended) mark.end();
    this.dirty = true;
  }

  endTrack(key) {
    const mark = this.marks.find((m) => m.key === key && m.live);
    if (mark) {
      mark.end();
      this.dirty = true;
    }
  }

  _freeMark() {
    if (!this.marks.length) {
      const dot = new THREE.SphereGeometry(3.5, 20, 14), halo = new THREE.SphereGeometry(1, 20, 14);
      for (let i = 0; i < TRACK_MARKS; i++) this.marks.push(new TrackMark(this.groups.live, dot, halo));
    }
    // An unused mark, else the longest-lifted one, else (more fingers than marks) the oldest.
    const byAge = [...this.marks].sort((a, b) => a.startedAt - b.startedAt);
    return byAge.find((m) => m.key === null) || byAge.find((m) => !m.live) || byAge[0];
  }

  clearLive() {
    this.dirty = true;
    for (const m of this.marks) m.clear();
  }

  setCoverage(points, errorsMm, [lo, hi]) {
    // The expected error of a touch, as a colour on the skin's surface: each vertex takes the
    // inverse-distance mean of its 4 nearest evaluation points, coloured on [lo, hi] mm.
    this.clear("coverage");
    if (!this.skinGeometry) return;
    const geo = this.skinGeometry.clone();
    const pos = geo.attributes.position;
    const P = points.map(v3);
    const cols = new Float32Array(pos.count * 3);
    const at = new THREE.Vector3();
    for (let i = 0; i < pos.count; i++) {
      at.fromBufferAttribute(pos, i);
      const near = P.map((p, k) => [p.distanceToSquared(at), k]).sort((a, b) => a[0] - b[0]).slice(0, 4);
      let w = 0, e = 0;
      for (const [d2, k] of near) {
        const wk = 1 / Math.max(d2, 1e-6);
        w += wk;
        e += wk * errorsMm[k];
      }
      coverageColor((e / w - lo) / Math.max(hi - lo, 1e-9)).toArray(cols, 3 * i);
    }
    geo.setAttribute("color", new THREE.Float32BufferAttribute(cols, 3));
    const mesh = new THREE.Mesh(geo, new THREE.MeshStandardMaterial({
      vertexColors: true, roughness: 0.9, metalness: 0, side: THREE.DoubleSide,
    }));
    mesh.name = "coverage-surface";
    this.groups.coverage.add(mesh);
    this.dirty = true;
  }

  setErrors(targets, predicted, errors) {
    this.clear("errors");
    const geo = new THREE.SphereGeometry(2.6, 14, 10);
    const pts = [];
    for (let i = 0; i < predicted.length; i++) {
      const m = new THREE.Mesh(geo, new THREE.MeshStandardMaterial({ color: errorColor(errors[i]) }));
      m.position.copy(v3(targets[i]));
      this.groups.errors.add(m);
      this.groups.errors.add(this._label(String(i + 1), v3(targets[i]), 2.6));
      pts.push(v3(targets[i]), v3(predicted[i]));
      const x = new THREE.Mesh(new THREE.SphereGeometry(1.3, 10, 8), new THREE.MeshBasicMaterial({ color: 0x333333 }));
      x.position.copy(v3(predicted[i]));
      this.groups.errors.add(x);
    }
    if (pts.length) {
      this.groups.errors.add(new THREE.LineSegments(new THREE.BufferGeometry().setFromPoints(pts),
        new THREE.LineBasicMaterial({ color: 0x333333 })));
    }
  }

  show(names) {
    this.dirty = true;
    for (const [k, g] of Object.entries(this.groups)) g.visible = k === "skin" || names.includes(k);
  }

  hit(clientX, clientY) {
    // The skin's point under a point of the page (mm, world), or null.
    const r = this.renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((clientX - r.left) / r.width) * 2 - 1, -((clientY - r.top) / r.height) * 2 + 1);
    this.raycaster.setFromCamera(ndc, this.camera);
    const hits = this.skin ? this.raycaster.intersectObject(this.skin) : [];
    return hits.length ? hits[0].point.clone() : null;
  }

  _animate(t) {
    // Draw only when something moved (software WebGL is slow; the target's pulse is CSS).
    if (this.fly) {
      const f = this.fly;
      const k = f.ms > 0 ? Math.min(1, (t - f.t0) / f.ms) : 1;
      const e = k * k * (3 - 2 * k);
      const dir = f.fromDir.clone().applyQuaternion(new THREE.Quaternion().slerp(f.turn, e));
      const target = f.fromTarget.clone().lerp(this.center, e);
      this.controls.target.copy(target);
      // The distance that fits now: the view may be resized during the flight.
      const toDist = this.fitDistance();
      this.camera.position.copy(target).add(dir.multiplyScalar(f.fromDist + (toDist - f.fromDist) * e));
      this.dirty = true;
      if (k >= 1) this.fly = null;
    }
    this.controls.update();
    if (!this.dirty || t - this.lastDraw < this.minFrameMs) return; // still dirty: a later tick
    this.dirty = false;
    this.lastDraw = t;
    this.renderer.render(this.scene, this.camera);
    this.controlsUi.render();
    this.labels.render();
    this._placePulse();
  }
}
