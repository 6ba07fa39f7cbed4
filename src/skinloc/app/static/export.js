// Export: the open session's recordings and model, its validation errors (CSV), the error view
// (PNG, SVG, drawn by the server) and the 3D view as it is on screen (PNG, and SVG drawn from the
// same camera). Downloads are plain GETs of /api/export/...; nothing here changes the session.
import * as THREE from "/static/vendor/three.bundle.min.js";

const KB = 1024;
export const fmtBytes = (n) => (n < KB ? `${n} B` : n < KB * KB ? `${(n / KB).toFixed(1)} kB` : `${(n / KB / KB).toFixed(1)} MB`);

function save(blob, name) {
  const a = document.createElement("a");
  a.href = URL.createObjectURL(blob);
  a.download = name;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 10_000);
}

// The 3D view as PNG: drawn once more now, then read (the renderer keeps its drawing buffer).
export function viewPng(viewer) {
  viewer.renderer.render(viewer.scene, viewer.camera);
  return new Promise((resolve) => viewer.renderer.domElement.toBlob(resolve, "image/png"));
}

// The 3D view as SVG, from the same camera: the skin's triangles (far ones first, shaded by how
// much they face the camera), each dot as a circle, each line as a line. Labels are left out.
export function viewSvg(viewer) {
  const size = viewer.renderer.getSize(new THREE.Vector2());
  const W = Math.round(size.x) || 800, H = Math.round(size.y) || 600;
  const cam = viewer.camera;
  cam.updateMatrixWorld();
  viewer.scene.updateMatrixWorld();
  // [x, y] px, the distance in front of the camera (mm: what the painter's order sorts on)
  // and whether the point is between the near and far planes.
  const toScreen = (v) => {
    const p = v.clone().project(cam);
    const depth = -v.clone().applyMatrix4(cam.matrixWorldInverse).z;
    return [((p.x + 1) / 2) * W, ((1 - p.y) / 2) * H, depth, p.z > -1 && p.z < 1];
  };
  const inView = (s) => s[3];
  const hex = (c) => `#${c.getHexString()}`;
  const tris = [], dots = [], lines = [];
  const a = new THREE.Vector3(), b = new THREE.Vector3(), c = new THREE.Vector3();
  const toCam = new THREE.Vector3();
  viewer.scene.traverseVisible((obj) => {
    const geo = obj.geometry;
    if (!geo || obj.isSprite) return;
    const pos = geo.attributes.position;
    const colour = obj.material?.color ?? new THREE.Color(0x333333);
    if (obj.isMesh && geo.type === "SphereGeometry") {
      const s = toScreen(obj.getWorldPosition(a));
      // The radius on screen: the projected distance to a point one radius aside.
      const r = geo.parameters.radius * obj.scale.x;
      const edge = toScreen(obj.getWorldPosition(b).add(new THREE.Vector3().setFromMatrixColumn(cam.matrixWorld, 0).multiplyScalar(r)));
      if (inView(s)) dots.push([s, Math.max(1, Math.hypot(edge[0] - s[0], edge[1] - s[1])), hex(colour), obj.material.opacity ?? 1, obj.getWorldPosition(new THREE.Vector3())]);
      return;
    }
    if (obj.isMesh) {
      const idx = geo.index ? geo.index.array : null;
      const n = idx ? idx.length : pos.count;
      const cols = geo.attributes.color;
      for (let k = 0; k < n; k += 3) {
        const [i, j, m] = idx ? [idx[k], idx[k + 1], idx[k + 2]] : [k, k + 1, k + 2];
        a.fromBufferAttribute(pos, i).applyMatrix4(obj.matrixWorld);
        b.fromBufferAttribute(pos, j).applyMatrix4(obj.matrixWorld);
        c.fromBufferAttribute(pos, m).applyMatrix4(obj.matrixWorld);
        const sa = toScreen(a), sb = toScreen(b), sc = toScreen(c);
        if (!inView(sa) || !inView(sb) || !inView(sc)) continue;
        const normal = new THREE.Vector3().subVectors(b, a).cross(new THREE.Vector3().subVectors(c, a)).normalize();
        toCam.copy(cam.position).sub(a).normalize();
        const base = cols ? new THREE.Color().fromBufferAttribute(cols, i) : colour.clone();
        const shade = 0.55 + 0.45 * Math.abs(normal.dot(toCam));
        tris.push([(sa[2] + sb[2] + sc[2]) / 3, [sa, sb, sc], hex(base.multiplyScalar(shade))]);
      }
      return;
    }
    if (obj.isLine || obj.isLineSegments) {
      const step = obj.isLineSegments ? 2 : 1;
      const n = obj.isLine && !obj.isLineSegments ? Math.min(pos.count, geo.drawRange.count) : pos.count;
      if (obj.parent === viewer.groups.skin) return; // the mesh's edges: the triangles show it
      for (let k = 0; k + 1 < n; k += step) {
        a.fromBufferAttribute(pos, k).applyMatrix4(obj.matrixWorld);
        b.fromBufferAttribute(pos, k + 1).applyMatrix4(obj.matrixWorld);
        const s0 = toScreen(a), s1 = toScreen(b);
        const mid = a.clone().add(b).multiplyScalar(0.5);
        const vc = geo.attributes.color; // an axis drawn in its vertices' colours
        const col = vc && obj.material.vertexColors ? new THREE.Color().fromBufferAttribute(vc, k) : colour;
        if (inView(s0) && inView(s1)) lines.push([s0, s1, hex(col), mid]);
      }
    }
  });
  // The skin's triangles in painter's order (far first); then the lines and dots the skin does
  // not hide: a ray from the camera to them meets no skin before them (3 mm of slack, as dots
  // sit on the surface). Per-triangle order alone fails for the long triangles of a cone.
  tris.sort((p, q) => q[0] - p[0]);
  const ray = new THREE.Raycaster();
  const seen = (v) => {
    if (!viewer.skin) return true;
    const dir = v.clone().sub(cam.position);
    const dist = dir.length();
    ray.set(cam.position, dir.normalize());
    const hit = ray.intersectObject(viewer.skin)[0];
    return !hit || hit.distance > dist - 3;
  };
  const f = (x) => x.toFixed(1);
  const out = [
    `<svg xmlns="http://www.w3.org/2000/svg" width="${W}" height="${H}" viewBox="0 0 ${W} ${H}">`,
    `<title>skinloc 3D view</title>`,
    `<rect width="${W}" height="${H}" fill="#f7f8fb"/>`,
    `<g stroke-width="0.3" stroke-linejoin="round">`,
  ];
  for (const [, [p, q, r], col] of tris) out.push(`<path d="M${f(p[0])} ${f(p[1])}L${f(q[0])} ${f(q[1])}L${f(r[0])} ${f(r[1])}Z" fill="${col}" stroke="${col}"/>`);
  out.push(`</g><g stroke-width="1.2">`);
  for (const [p, q, col, mid] of lines) if (seen(mid)) out.push(`<line x1="${f(p[0])}" y1="${f(p[1])}" x2="${f(q[0])}" y2="${f(q[1])}" stroke="${col}"/>`);
  out.push(`</g><g stroke="#1d2330" stroke-width="0.5">`);
  dots.sort((p, q) => q[0][2] - p[0][2]);
  for (const [p, r, col, op, at] of dots) if (seen(at)) out.push(`<circle cx="${f(p[0])}" cy="${f(p[1])}" r="${f(r)}" fill="${col}"${op < 1 ? ` fill-opacity="${op}"` : ""}/>`);
  out.push(`</g></svg>`);
  return out.join("\n");
}

export async function saveView(viewer, fmt, name = "skinloc-3d-view") {
  if (fmt === "png") save(await viewPng(viewer), `${name}.png`);
  else save(new Blob([viewSvg(viewer)], { type: "image/svg+xml" }), `${name}.svg`);
}

export class ExportPage {
  // el: the Export page's card; viewer: the 3D view; sessionId(): the open session's id.
  constructor(el, { viewer, esc, sessionId }) {
    this.el = el;
    this.viewer = viewer;
    this.esc = esc;
    this.sessionId = sessionId;
    el.querySelector(".view-png").addEventListener("click", () => saveView(viewer, "png", this.viewName()));
    el.querySelector(".view-svg").addEventListener("click", () => saveView(viewer, "svg", this.viewName()));
    // The same two buttons on the 3D view itself, so the view can be saved where it is seen.
    const bar = document.createElement("div");
    bar.className = "viewer-export";
    bar.innerHTML = `<button type="button" class="small" data-fmt="png" title="Save the 3D view as PNG">PNG</button><button type="button" class="small" data-fmt="svg" title="Save the 3D view as SVG">SVG</button>`;
    for (const btn of bar.querySelectorAll("button")) btn.addEventListener("click", () => saveView(viewer, btn.dataset.fmt, this.viewName()));
    viewer.el.appendChild(bar);
  }

  viewName() {
    const id = this.sessionId();
    return id ? `${id}-3d-view` : "skinloc-3d-view";
  }

  async refresh() {
    const esc = this.esc;
    const body = this.el.querySelector(".export-files tbody");
    const r = await fetch("/api/export");
    const data = await r.json().catch(() => ({}));
    if (!r.ok) {
      body.innerHTML = `<tr><td colspan="4" class="hint">${esc(data.detail || "nothing to export")}</td></tr>`;
      this.el.querySelector(".export-derived").classList.add("hidden");
      return;
    }
    body.innerHTML = data.files.length
      ? data.files.map((f) => `<tr><td><a href="/api/export/files/${encodeURIComponent(f.name)}" download="${esc(f.download)}">${esc(f.name)}</a></td><td>${esc(f.kind)}</td><td class="num">${fmtBytes(f.bytes)}</td><td><code class="open-with">${esc(f.command)}</code></td></tr>`).join("")
      : `<tr><td colspan="4" class="hint">No files yet: calibrate first.</td></tr>`;
    const derived = this.el.querySelector(".export-derived");
    derived.classList.remove("hidden");
    for (const a of derived.querySelectorAll("a")) a.classList.toggle("disabled", !data.validation);
    derived.querySelector(".hint").textContent = data.validation ? "" : "Validate first: these come from the validation touches.";
  }
}
