// The report's interactive 3-D view (straylight/view3d.py writes the data; three.js draws it).
// Reads the JSON in <script id="view3d-data">: parts (base64 float32 vertices in mm, uint32 faces,
// absorbed and incident power), the entrance disk, and ranked path groups with sample polylines.
// Mouse: left drag rotates, wheel zooms, right drag pans. The panel hides parts and selects paths.
// It opens showing the light: the instrument cut open along its axis (the half toward the camera clipped away;
// "cut open" in the panel), the main ranked paths drawn, each in its own colour (the swatches are the legend),
// and the detector marked (yellow, with a label).
// window.view3d is the page's small API (used by the browser test and by hand in the console).
(function () {
  "use strict";
  const data = JSON.parse(document.getElementById("view3d-data").textContent);

  function decode(b64, Type) {
    const bin = atob(b64);
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    return new Type(bytes.buffer);
  }

  // inferno colour map, 9 stops (matplotlib's), for log10 power
  const INFERNO = [[0, 0, 4], [40, 11, 84], [101, 21, 110], [159, 42, 99], [212, 72, 66],
                   [245, 125, 21], [250, 193, 39], [252, 255, 164], [252, 255, 164]];
  function inferno(t) {
    t = Math.min(1, Math.max(0, t)) * (INFERNO.length - 2);
    const i = Math.floor(t), f = t - i, a = INFERNO[i], b = INFERNO[i + 1];
    return new THREE.Color((a[0] + f * (b[0] - a[0])) / 255, (a[1] + f * (b[1] - a[1])) / 255,
                           (a[2] + f * (b[2] - a[2])) / 255);
  }
  const PART_COLORS = ["#4c72b0", "#dd8452", "#55a868", "#c44e52", "#8172b2", "#937860", "#da8bc3",
                       "#8c8c8c", "#ccb974", "#64b5cd"];

  const host = document.getElementById("view3d-canvas-host");
  const renderer = new THREE.WebGLRenderer({antialias: true, preserveDrawingBuffer: true});
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setClearColor(0xffffff, 1);
  host.appendChild(renderer.domElement);
  renderer.domElement.id = "view3d-canvas";
  const scene = new THREE.Scene();
  scene.add(new THREE.AmbientLight(0xffffff, 0.55));
  const sun = new THREE.DirectionalLight(0xffffff, 1.6);
  scene.add(sun);

  const lo = data.bounds_mm[0], hi = data.bounds_mm[1];
  const center = new THREE.Vector3((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2);
  const size = Math.max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) || 1;
  const camera = new THREE.PerspectiveCamera(30, 1, size / 1000, size * 100);
  camera.up.set(0, 0, 1);
  const view = new THREE.Vector3(0.35, 1.0, 0.3).normalize().multiplyScalar(2.6 * size);
  camera.position.copy(center).add(view);
  const controls = new THREE.OrbitControls(camera, renderer.domElement);
  controls.target.copy(center);
  controls.update();

  // parts
  const parts = {};
  const labels = [];  // HTML labels over the canvas (the detector's), placed on every render
  data.parts.forEach(function (p, k) {
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(decode(p.vertices_f32, Float32Array), 3));
    g.setIndex(new THREE.BufferAttribute(decode(p.faces_u32, Uint32Array), 1));
    g.computeVertexNormals();
    // the cut-open view: the triangles beyond the plane through the centre (py writes them: cut_faces_u32)
    const whole = new THREE.BufferAttribute(decode(p.faces_u32, Uint32Array), 1);
    const opened = p.cut_faces_u32 ? new THREE.BufferAttribute(decode(p.cut_faces_u32, Uint32Array), 1) : whole;
    g.setIndex(opened);
    const m = new THREE.MeshLambertMaterial({side: THREE.DoubleSide, transparent: false});
    const mesh = new THREE.Mesh(g, m);
    mesh.name = p.name;
    scene.add(mesh);
    parts[p.name] = {mesh: mesh, info: p, index: k, whole: whole, opened: opened};
    if (p.role === "detector") markDetector(g, p.name);
  });

  // the detector's mark: its bounding box outlined in magenta over everything, and a label beside it
  function markDetector(g, name) {
    g.computeBoundingBox();
    const b = g.boundingBox, pad = size * 0.01;
    const x = [b.min.x - pad, b.max.x + pad], y = [b.min.y - pad, b.max.y + pad], z = [b.min.z - pad, b.max.z + pad];
    const c = [];
    for (let i = 0; i < 8; i++) c.push([x[i & 1], y[(i >> 1) & 1], z[(i >> 2) & 1]]);
    const edges = [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]];
    const pts = [];
    edges.forEach(function (e) { pts.push(...c[e[0]], ...c[e[1]]); });
    const lg = new THREE.BufferGeometry();
    lg.setAttribute("position", new THREE.BufferAttribute(new Float32Array(pts), 3));
    const box = new THREE.LineSegments(lg, new THREE.LineBasicMaterial({color: 0xc000c0, depthTest: false}));
    box.renderOrder = 10;
    box.name = "detector mark: " + name;
    scene.add(box);
    const div = document.createElement("div");
    div.className = "view3d-label";
    div.textContent = "detector: " + name;
    host.appendChild(div);
    labels.push({div: div, at: new THREE.Vector3(b.max.x + pad, (b.min.y + b.max.y) / 2, b.max.z + pad)});
  }
  function placeLabels(w, h) {
    labels.forEach(function (l) {
      const q = l.at.clone().project(camera);
      l.div.style.left = Math.round((q.x + 1) / 2 * w + 6) + "px";
      l.div.style.top = Math.round((1 - q.y) / 2 * h - 10) + "px";
    });
  }

  // entrance disk (a translucent ring outline and fill)
  if (data.entrance) {
    const e = data.entrance;
    const ring = new THREE.Mesh(new THREE.RingGeometry(0, e.radius_mm, 64),
      new THREE.MeshBasicMaterial({color: 0x2a9d8f, side: THREE.DoubleSide, transparent: true, opacity: 0.25,
                                   depthWrite: false}));
    const n = new THREE.Vector3(e.normal[0], e.normal[1], e.normal[2]).normalize();
    ring.quaternion.setFromUnitVectors(new THREE.Vector3(0, 0, 1), n);
    ring.position.set(e.center_mm[0], e.center_mm[1], e.center_mm[2]);
    ring.name = "entrance";
    scene.add(ring);
    const edge = new THREE.LineSegments(new THREE.EdgesGeometry(new THREE.RingGeometry(e.radius_mm * 0.999,
      e.radius_mm, 64)), new THREE.LineBasicMaterial({color: 0x2a9d8f}));
    ring.add(edge);
    parts["entrance"] = {mesh: ring, info: {name: "entrance", role: "entrance"}, index: -1};
  }

  // path groups: one LineSegments object per ranked group, each in its own colour; the main ones (the first
  // SHOWN_PATHS ranks with sample rays) are drawn on opening
  const PATH_COLORS = ["#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#17becf", "#8c564b", "#e377c2",
                       "#bcbd22", "#7f7f7f"];
  const SHOWN_PATHS = 5;
  function pathColor(rank) { return PATH_COLORS[(rank - 1) % PATH_COLORS.length]; }
  const paths = {};
  let shown = 0;
  data.paths.forEach(function (grp) {
    const segs = [];
    grp.polylines.forEach(function (line) {
      for (let i = 0; i + 1 < line.length; i++) segs.push(...line[i], ...line[i + 1]);
    });
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(new Float32Array(segs), 3));
    const obj = new THREE.LineSegments(g, new THREE.LineBasicMaterial({color: pathColor(grp.rank)}));
    obj.visible = grp.polylines.length > 0 && shown < SHOWN_PATHS;
    if (obj.visible) shown += 1;
    obj.name = "path " + grp.rank;
    scene.add(obj);
    paths[grp.rank] = {obj: obj, info: grp};
  });

  // colouring
  function colorParts(mode) {
    const key = mode === "incident" ? "incident_w" : "absorbed_w";
    let vmin = Infinity, vmax = -Infinity;
    Object.values(parts).forEach(function (p) {
      const v = p.info[key];
      if (p.info.role !== "detector" && p.index >= 0 && v > 0) {
        vmin = Math.min(vmin, Math.log10(v)); vmax = Math.max(vmax, Math.log10(v));
      }
    });
    if (!(vmax > vmin)) { vmin = (isFinite(vmax) ? vmax : 0) - 1; vmax = vmin + 1; }
    Object.values(parts).forEach(function (p) {
      if (p.index < 0) return;
      const m = p.mesh.material;
      if (p.info.role === "detector") m.color.set("#ffd400");
      else if (mode === "part") m.color.set(PART_COLORS[p.index % PART_COLORS.length]);
      else {
        const v = p.info[key];
        m.color.copy(v > 0 ? inferno((Math.log10(v) - vmin) / (vmax - vmin)) : new THREE.Color(0.75, 0.75, 0.78));
      }
      const sw = document.querySelector('[data-swatch="' + CSS.escape(p.info.name) + '"]');
      if (sw) sw.style.background = "#" + m.color.getHexString();
    });
    const bar = document.getElementById("view3d-scale");
    bar.textContent = mode === "part" ? "" :
      "colour: log10 " + (mode === "incident" ? "incident" : "absorbed") + " power (W), black " +
      vmin.toFixed(1) + " .. light yellow " + vmax.toFixed(1) + "; grey: none";
    render();
  }

  function render() {
    const w = host.clientWidth || 800, h = host.clientHeight || 500;
    if (renderer.domElement.width !== Math.floor(w * renderer.getPixelRatio())) {
      renderer.setSize(w, h);
      camera.aspect = w / h;
      camera.updateProjectionMatrix();
    }
    sun.position.copy(camera.position);
    renderer.render(scene, camera);
    placeLabels(w, h);
  }
  controls.addEventListener("change", render);
  window.addEventListener("resize", render);

  // the panel
  function fmt(v) { return v > 0 ? v.toExponential(2) : "0"; }
  const list = document.getElementById("view3d-parts");
  Object.values(parts).forEach(function (p) {
    const row = document.createElement("label");
    row.className = "view3d-row";
    const box = document.createElement("input");
    box.type = "checkbox"; box.checked = true; box.dataset.part = p.info.name;
    box.addEventListener("change", function () { p.mesh.visible = box.checked; render(); });
    const sw = document.createElement("span");
    sw.className = "view3d-swatch"; sw.dataset.swatch = p.info.name;
    if (p.index < 0) sw.style.background = "#2a9d8f";
    const txt = document.createElement("span");
    txt.textContent = p.info.name + (p.info.role && p.info.role !== "surface" ? " (" + p.info.role + ")" : "") +
      (p.index >= 0 ? (p.info.role === "detector" ? "  det " : "  abs ") + fmt(p.info.absorbed_w) + " W" : "");
    txt.title = p.index >= 0 ? p.info.name + ": absorbed " + fmt(p.info.absorbed_w) + " W, incident " +
      fmt(p.info.incident_w) + " W, " + p.info.triangles + " triangles shown of " + p.info.triangles_traced : "entrance";
    row.append(box, sw, txt);
    list.appendChild(row);
  });
  const plist = document.getElementById("view3d-paths");
  data.paths.forEach(function (grp) {
    const row = document.createElement("label");
    row.className = "view3d-row";
    const box = document.createElement("input");
    box.type = "checkbox"; box.dataset.path = grp.rank;
    box.disabled = grp.polylines.length === 0;
    box.checked = paths[grp.rank].obj.visible;
    box.addEventListener("change", function () { paths[grp.rank].obj.visible = box.checked; render(); });
    const sw = document.createElement("span");
    sw.className = "view3d-swatch"; sw.dataset.pathSwatch = grp.rank;
    sw.style.background = pathColor(grp.rank);
    const txt = document.createElement("span");
    txt.textContent = "#" + grp.rank + " " + (100 * grp.fraction).toFixed(2) + "%  " +
      grp.label.replace(/^source -> /, "") + (grp.polylines.length ? "" : "  (no sample found)");
    txt.title = grp.label + ": " + (100 * grp.fraction).toFixed(3) + " % +- " + (100 * grp.fraction_stderr).toFixed(3) +
      " % of the detector power; " + grp.polylines.length + " sample rays drawn";
    row.append(box, sw, txt);
    plist.appendChild(row);
  });
  const cutBox = document.getElementById("view3d-cut");
  if (cutBox) {
    cutBox.addEventListener("change", function () {
      Object.values(parts).forEach(function (p) {
        if (p.index >= 0) p.mesh.geometry.setIndex(cutBox.checked ? p.opened : p.whole);
      });
      render();
    });
  }
  const select = document.getElementById("view3d-color");
  select.addEventListener("change", function () { colorParts(select.value); });

  function setBox(selector, on) {
    const box = document.querySelector(selector);
    if (!box) throw new Error("view3d: no control " + selector);
    if (box.checked !== on) box.click();
  }
  window.view3d = {
    ready: true,
    parts: Object.keys(parts),
    paths: data.paths.map(function (g) { return g.rank; }),
    hidePart: function (name) { setBox('input[data-part="' + CSS.escape(name) + '"]', false); },
    showPart: function (name) { setBox('input[data-part="' + CSS.escape(name) + '"]', true); },
    isVisible: function (name) { return parts[name].mesh.visible; },
    shownPaths: function () { return Object.keys(paths).filter(function (r) { return paths[r].obj.visible; })
      .map(Number); },
    pathColor: pathColor,
    cutOpen: function (on) { setBox("#view3d-cut", on !== false); },
    showPath: function (rank, on) { setBox('input[data-path="' + rank + '"]', on !== false); },
    colorBy: function (mode) { select.value = mode; colorParts(mode); },
    render: render,
  };
  colorParts(select.value);
})();
