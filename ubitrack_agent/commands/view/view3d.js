// ubitrack view: the frames in 3D. At display rate (once per animation frame, one request at
// a time) it fetches /frames.json?root=ROOT, every frame of the SRG placed relative to ROOT by
// the live relations taken at one display time (each interpolated there; the skew of one that
// could not be is shown), and draws each with its axes (x red, y green, z blue; a dot for a frame
// placed by a position only), its name, a trail of its recent positions and, where the
// placement has a covariance, the position's uncertainty as an ellipsoid. three.js is bundled
// (/vendor/three/, no CDN). Names come from the network: written as text, never as markup.
// The root: the select, or the page's address (/3d#root=FRAME); default the tracker's frame.
import * as THREE from "/vendor/three/three.module.min.js";
import { element } from "/dom.js";

const canvas = document.getElementById("canvas");
const labels = document.getElementById("labels");
const controls = Object.fromEntries(
  ["root", "sigma", "magnify", "trail"].map((id) => [id, document.getElementById(id)]),
);
const TRAIL_POINTS = 1200;

function problem(text) {
  const banner = document.getElementById("problem");
  banner.textContent = text || "";
  banner.hidden = !text;
}

let renderer;
try {
  renderer = new THREE.WebGLRenderer({ canvas, antialias: true });
} catch (error) {
  problem(`this browser draws no WebGL: ${error.message}`);
  throw error;
}
renderer.setPixelRatio(window.devicePixelRatio);
renderer.setClearColor(0xfbfbfd);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(45, 1, 0.001, 1000);
camera.up.set(0, 0, 1); // tracking frames: z up
const grid = new THREE.GridHelper(4, 8, 0xc8c8d0, 0xe2e2e8);
grid.rotation.x = Math.PI / 2; // in the root's x-y plane
scene.add(grid);

// The camera turns around a target: azimuth and elevation by dragging, distance by the wheel.
const orbit = { target: new THREE.Vector3(), distance: 4, azimuth: -2.2, elevation: 0.5, fitted: false };

function placeCamera() {
  const { target, distance, azimuth, elevation } = orbit;
  camera.position.set(
    target.x + distance * Math.cos(elevation) * Math.cos(azimuth),
    target.y + distance * Math.cos(elevation) * Math.sin(azimuth),
    target.z + distance * Math.sin(elevation),
  );
  camera.lookAt(target);
}

canvas.addEventListener("pointerdown", (down) => {
  canvas.setPointerCapture(down.pointerId);
  let [x, y] = [down.clientX, down.clientY];
  const move = (event) => {
    orbit.azimuth -= (event.clientX - x) * 0.01;
    orbit.elevation = Math.max(-1.5, Math.min(1.5, orbit.elevation + (event.clientY - y) * 0.01));
    [x, y] = [event.clientX, event.clientY];
  };
  canvas.addEventListener("pointermove", move);
  canvas.addEventListener("pointerup", () => canvas.removeEventListener("pointermove", move), { once: true });
});
canvas.addEventListener(
  "wheel",
  (event) => {
    event.preventDefault();
    orbit.distance *= Math.exp(event.deltaY * 0.001);
  },
  { passive: false },
);

// One frame's drawing: axes, dot, ellipsoid, trail and label.
class FrameMark {
  constructor(name) {
    this.group = new THREE.Group();
    this.axes = new THREE.Group();
    [[1, 0, 0, 0xd03030], [0, 1, 0, 0x30a030], [0, 0, 1, 0x3050e0]].forEach(([x, y, z, colour]) =>
      this.axes.add(new THREE.ArrowHelper(new THREE.Vector3(x, y, z), new THREE.Vector3(), 1, colour, 0.25, 0.12)),
    );
    this.dot = new THREE.Mesh(
      new THREE.SphereGeometry(1, 12, 8),
      new THREE.MeshBasicMaterial({ color: 0x334466 }),
    );
    this.ellipsoid = new THREE.Mesh(
      new THREE.SphereGeometry(1, 32, 16),
      new THREE.MeshBasicMaterial({ color: 0xe07020, transparent: true, opacity: 0.35, depthWrite: false }),
    );
    this.group.add(this.axes, this.dot);
    this.trailPositions = new Float32Array(TRAIL_POINTS * 3);
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.BufferAttribute(this.trailPositions, 3));
    this.trail = new THREE.Line(geometry, new THREE.LineBasicMaterial({ color: 0x7a8ab0 }));
    this.history = [];
    this.label = element("span", name);
    labels.append(this.label);
    scene.add(this.group, this.ellipsoid, this.trail);
  }

  update(placed, now, size, scale, trailSeconds) {
    const [x, y, z] = placed.position;
    this.group.position.set(x, y, z);
    this.axes.visible = Array.isArray(placed.rotation);
    if (this.axes.visible) this.group.quaternion.fromArray(placed.rotation);
    this.axes.scale.setScalar(size);
    this.dot.scale.setScalar(size * (this.axes.visible ? 0.06 : 0.12));
    const ellipsoid = placed.ellipsoid;
    this.ellipsoid.visible = Boolean(ellipsoid);
    if (ellipsoid) {
      this.ellipsoid.position.set(x, y, z);
      const [u, v, w] = ellipsoid.axes.map((axis) => new THREE.Vector3(...axis));
      this.ellipsoid.quaternion.setFromRotationMatrix(new THREE.Matrix4().makeBasis(u, v, w));
      const [a, b, c] = ellipsoid.radii.map((r) => Math.max(r * scale, size * 0.01));
      this.ellipsoid.scale.set(a, b, c);
    }
    this.history.push([now, x, y, z]);
    while (this.history.length > TRAIL_POINTS || (this.history.length && this.history[0][0] < now - trailSeconds * 1000)) {
      this.history.shift();
    }
    this.history.forEach(([, px, py, pz], i) => this.trailPositions.set([px, py, pz], i * 3));
    this.trail.geometry.setDrawRange(0, this.history.length);
    this.trail.geometry.attributes.position.needsUpdate = true;
  }

  remove() {
    scene.remove(this.group, this.ellipsoid, this.trail);
    this.label.remove();
  }
}

const marks = new Map();
let latest = null;
let root = new URLSearchParams(location.hash.slice(1)).get("root");
let busy = false;
const counts = { answers: 0, drawn: 0, since: performance.now() };
// Since the page loaded: pictures drawn, and placements at a new display time (new samples);
// written on the footer (data-drawn, data-placements) for tests and bench/view_frames_bench.py.
const totals = { drawn: 0, placements: 0 };

function resetTrails() {
  for (const mark of marks.values()) mark.history = [];
}

controls.root.addEventListener("change", () => {
  root = controls.root.value;
  location.hash = `root=${encodeURIComponent(root)}`;
  resetTrails();
  orbit.fitted = false;
});
controls.trail.addEventListener("change", resetTrails);

function fillRoots(known, chosen) {
  const names = Array.isArray(known) ? known.map(String) : [];
  const current = [...controls.root.options].map((option) => option.value);
  if (names.join("\n") !== current.join("\n")) {
    controls.root.replaceChildren(...names.map((name) => element("option", name)));
  }
  controls.root.value = chosen;
}

let retryAt = 0; // after an answer that is no placement, ask again a second later

async function fetchFrames() {
  if (busy || performance.now() < retryAt) return;
  busy = true;
  try {
    const query = root ? `?root=${encodeURIComponent(root)}` : "";
    const response = await fetch(`/frames.json${query}`, { cache: "no-store" });
    const answer = await response.json();
    if (!response.ok) {
      retryAt = performance.now() + 1000;
      problem(answer.error || `the view answered ${response.status}`);
      if (root && Array.isArray(answer.known) && answer.known.length) root = null; // back to the default
      latest = null;
      return;
    }
    problem(null);
    if (!latest || answer.display_time_ns !== latest.display_time_ns) totals.placements += 1;
    latest = answer;
    root = answer.root;
    fillRoots(answer.known, answer.root);
    counts.answers += 1;
  } catch (error) {
    retryAt = performance.now() + 1000;
    problem(`the view does not answer: ${error}`);
  } finally {
    busy = false;
  }
}

// The size of the scene (the frames' farthest position from their centre) sets the axes' length
// and, the first time or after a change of root, the camera's distance.
function extent(frames) {
  const positions = Object.values(frames).map((f) => new THREE.Vector3(...f.position));
  const centre = positions.reduce((sum, p) => sum.add(p), new THREE.Vector3()).divideScalar(Math.max(positions.length, 1));
  const radius = Math.max(0.2, ...positions.map((p) => p.distanceTo(centre)));
  return { centre, radius };
}

function draw(now) {
  const frames = latest ? latest.frames : {};
  const { centre, radius } = extent(frames);
  if (latest && !orbit.fitted) {
    orbit.target.copy(centre);
    orbit.distance = radius * 2.4;
    orbit.fitted = true;
  }
  grid.scale.setScalar(radius / 2);
  const size = radius * 0.2;
  const scale = Number(controls.sigma.value) * Number(controls.magnify.value);
  for (const [name, mark] of marks) {
    if (!(name in frames)) {
      mark.remove();
      marks.delete(name);
    }
  }
  for (const [name, placed] of Object.entries(frames)) {
    if (!marks.has(name)) marks.set(name, new FrameMark(name));
    marks.get(name).update(placed, now, size, scale, Number(controls.trail.value));
  }
  const width = canvas.clientWidth;
  const height = canvas.clientHeight;
  if (canvas.width !== Math.floor(width * renderer.getPixelRatio())) {
    renderer.setSize(width, height, false);
    camera.aspect = width / Math.max(height, 1);
    camera.updateProjectionMatrix();
  }
  placeCamera();
  renderer.render(scene, camera);
  for (const [name, mark] of marks) {
    const point = mark.group.position.clone().project(camera);
    mark.label.hidden = point.z > 1;
    mark.label.style.left = `${((point.x + 1) / 2) * width}px`;
    mark.label.style.top = `${((1 - point.y) / 2) * height}px`;
    mark.label.className = latest && name === latest.root ? "root" : "";
  }
  counts.drawn += 1;
  totals.drawn += 1;
}

function fillTable() {
  const frames = latest ? latest.frames : {};
  const rows = Object.keys(frames)
    .sort()
    .map((name) => {
      const placed = frames[name];
      const radii = placed.ellipsoid ? placed.ellipsoid.radii.map((r) => (r * 1000).toFixed(2)).join(", ") : "–";
      const row = element("tr");
      row.dataset.frame = name;
      row.append(
        element("td", name),
        element("td", placed.position.map((v) => v.toFixed(3)).join(", ")),
        element("td", radii),
        element("td", placed.skew_ms ? placed.skew_ms.toFixed(1) : "0"),
        element("td", placed.via.length ? placed.via.join(" · ") : "the root"),
      );
      return row;
    });
  const unplaced = latest ? latest.unplaced || {} : {};
  for (const name of Object.keys(unplaced).sort()) {
    const row = element("tr", null, "none");
    row.dataset.frame = name;
    row.append(element("td", name), element("td", "not placed"), element("td", "–"), element("td", "–"), element("td", unplaced[name]));
    rows.push(row);
  }
  document.querySelector("#frames tbody").replaceChildren(...rows);
  document.getElementById("agent").textContent = latest
    ? `${Object.keys(frames).length} of ${(latest.known || []).length} frames placed relative to ${latest.root}` +
      (latest.root === latest.default_root ? " (the tracker's frame)" : "") +
      (typeof latest.behind_ms !== "number" ? "" : `, at one instant ${latest.behind_ms.toFixed(0)} ms before the newest sample`)
    : "no frames yet";
  const seconds = (performance.now() - counts.since) / 1000;
  const footer = document.getElementById("rate");
  footer.dataset.drawn = totals.drawn;
  footer.dataset.placements = totals.placements;
  footer.textContent =
    `${(counts.answers / seconds).toFixed(0)} placements/s fetched, ${(counts.drawn / seconds).toFixed(0)} pictures/s drawn`;
  [counts.answers, counts.drawn, counts.since] = [0, 0, performance.now()];
}

// At display rate: once per animation frame. A browser that gives no animation frames (a
// headless one, not compositing) still gets a picture ten times a second.
let drawnAt = 0;

function step(now) {
  fetchFrames();
  draw(now);
  drawnAt = performance.now();
}

function animate(now) {
  step(now);
  requestAnimationFrame(animate);
}

requestAnimationFrame(animate);
setInterval(() => {
  if (performance.now() - drawnAt > 200) step(performance.now());
}, 100);
setInterval(fillTable, 500);
