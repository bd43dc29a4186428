// The report's interactive 3-D view (straylight/view3d.py writes the data; three.js draws it).
// Reads the JSON in <script id="view3d-data">: parts (base64 float32 vertices in mm, uint32 faces,
// absorbed and incident power), the entrance disk, and ranked path groups with sample polylines.
// Mouse: left drag rotates, wheel zooms, right drag pans. The panel hides parts and selects paths.
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
  data.parts.forEach(function (p, k) {
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(decode(p.vertices_f32, Float32Array), 3));
    g.setIndex(new THREE.BufferAttribute(decode(p.faces_u32, Uint32Array), 1));
    g.computeVertexNormals();
    const m = new THREE.MeshLambertMaterial({side: THREE.DoubleSide, transparent: false});
    const mesh = new THREE.Mesh(g, m);
    mesh.name = p.name;
    scene.add(mesh);
    parts[p.name] = {mesh: mesh, info: p, index: k};
  });

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

  // path groups: one LineSegments object per ranked group
  const paths = {};
  data.paths.forEach(function (grp) {
    const segs = [];
    grp.polylines.forEach(function (line) {
      for (let i = 0; i + 1 < line.length; i++) segs.push(...line[i], ...line[i + 1]);
    });
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(new Float32Array(segs), 3));
    const obj = new THREE.LineSegments(g, new THREE.LineBasicMaterial({color: 0xd62728}));
    obj.visible = false;
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
    box.addEventListener("change", function () { paths[grp.rank].obj.visible = box.checked; render(); });
    const txt = document.createElement("span");
    txt.textContent = "#" + grp.rank + " " + (100 * grp.fraction).toFixed(2) + "%  " +
      grp.label.replace(/^source -> /, "") + (grp.polylines.length ? "" : "  (no sample found)");
    txt.title = grp.label + ": " + (100 * grp.fraction).toFixed(3) + " % +- " + (100 * grp.fraction_stderr).toFixed(3) +
      " % of the detector power; " + grp.polylines.length + " sample rays drawn";
    row.append(box, txt);
    plist.appendChild(row);
  });
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
    showPath: function (rank, on) { setBox('input[data-path="' + rank + '"]', on !== false); },
    colorBy: function (mode) { select.value = mode; colorParts(mode); },
    render: render,
  };
  colorParts(select.value);
})();
