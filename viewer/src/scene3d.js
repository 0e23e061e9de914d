// The 3D scene: the part coloured per face, the selected cameras (a small glyph each; the
// selected one's depth-of-field box), the tour, number labels at each camera's aim point on
// the part (placed so that none hides another), picking.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { placeLabels } from './labels.js';
import { GHOST } from './palette.js';

const FRUSTUM = 0x1f6fb2;
const SELECTED = 0xe8590c;
const TOUR = 0x7048e8;
const PENDING = 200; // the part's grey while a plan loads (no colour claims anything)
const ARM = 0x868e96; // the robot arm posed at the selected viewpoint
const FLOOR = 0x8c939c; // the setup's floor: a translucent plane with a grid ...
const FLOOR_OPACITY = 0.18;
const FLOOR_GRID = 20; // ... of this many cells a side
const SOLID = 0x7b8088; // fixtures, and keep-out meshes and boxes (paler), translucent grey
const SOLID_OPACITY = 0.45;
const KEEP_OUT_OPACITY = 0.2;
const DIM = 255; // faces the selected camera does not see fade towards white, keeping a tint
const DIM_MIX = 0.72;
const GLYPH = 0.25; // a camera glyph is a pyramid this many part diagonals deep (≤ near_mm)
const FIT_MARGIN = 0.1; // share of the canvas left around what `fit` frames
const FIT_POINTS = 20000;
const MOVING_SCALE = 0.5; // while the eye moves, the canvas draws at this share of its pixels
const SETTLE_MS = 200; // ... and at all of them this long after it stops
const AIM_FACES = 2000; // faces per camera searched for its aim point (evenly spread)
const PIN_PX = 9; // camera pins, drawn and picked in screen pixels
const MARK_PX = 7; // under "problems only", a dot of this size marks each problem face ...
const MARK_LIFT = 0.002; // ... lifted off it by this share of the part's diagonal (no z-fight)
const PROBLEMS = [1, 2, 3]; // the states marked: unmet, uncovered (left out), uncoverable
const PICK_PX = 8;
const LINEAR = Float32Array.from({ length: 256 }, (_, i) => {
  const c = i / 255; // sRGB byte → linear, so that the sRGB output shows the byte again
  return c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4;
});
// OpenCV camera frame (x right, y down, z forward) → three.js (x right, y up, −z forward)
const CV_TO_GL = new THREE.Matrix4().makeScale(1, -1, -1);

export class PlanScene {
  constructor(canvas, labels) {
    this.labelLayer = labels;
    this.canvas = canvas;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio);
    this.renderer.setClearColor(0xf3f4f6);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 1, 1e5);
    this.scene.add(this.camera);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8d8d8d, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(0.3, 0.6, 1);
    this.camera.add(sun);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.addEventListener('change', () => this.render());
    this.controls.addEventListener('start', () => { this.moving(); this.onInteract?.(); });
    this.controls.addEventListener('end', () => this.moving());
    this.cameras = new THREE.Group();
    this.scene.add(this.cameras);
    this.selected = null;
    this.waiting = [];
    new ResizeObserver(() => this.resize()).observe(canvas.parentElement);
    this.picking(canvas);
  }

  /** The part from packed geometry: vertices (V·3) float32 mm, faces (M·3) uint32. */
  setPart(vertices, faces) {
    if (this.part) { this.scene.remove(this.part); this.part.geometry.dispose(); }
    const m = faces.length / 3;
    const pos = new Float32Array(m * 9);
    for (let i = 0; i < m * 3; i++) pos.set(vertices.subarray(3 * faces[i], 3 * faces[i] + 3), 3 * i);
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(pos, 3));
    geometry.setAttribute('color', new THREE.BufferAttribute(new Float32Array(m * 9), 3));
    geometry.computeVertexNormals(); // non-indexed: the face normal at each corner
    geometry.computeBoundingBox();
    this.materials = {
      shaded: new THREE.MeshLambertMaterial({ vertexColors: true, side: THREE.DoubleSide }),
      flat: new THREE.MeshBasicMaterial({ vertexColors: true, side: THREE.DoubleSide }),
    };
    this.part = new THREE.Mesh(geometry, this.materials.shaded);
    this.scene.add(this.part);
    this.nFaces = m;
    this.centroids = new Float32Array(m * 3);
    for (let i = 0; i < m * 9; i++) this.centroids[3 * Math.floor(i / 9) + (i % 3)] += pos[i] / 3;
  }

  setShading(on) {
    this.part.material = on ? this.materials.shaded : this.materials.flat;
    this.render();
  }

  /** Face colours (M·3 sRGB bytes) and the selected viewpoints with their seen faces (CSR). */
  setPlan(colours, viewpoints, sensor, offsets, seen) {
    this.colours = colours;
    this.viewpoints = viewpoints;
    this.sensor = sensor;
    this.offsets = offsets;
    this.seen = seen;
    this.selected = null;
    this.frame = null;
    this.aims = viewpoints.map((_, k) => this.aimPoint(k));
    this.buildCameras();
    this.paint();
  }

  /** No plan drawn (while another one loads): the part in one neutral grey, no cameras, tour
   * or numbers, nothing selected. */
  clearPlan() {
    if (!this.part || !this.sensor) return;
    const grey = new Uint8Array(3 * this.nFaces).fill(PENDING);
    this.states = null;
    this.setPlan(grey, [], this.sensor, new Uint32Array(1), new Uint32Array(0));
    this.render();
  }

  /** Where viewpoint k looks on the part: the centre of the face it sees nearest its central
   * ray, among up to AIM_FACES of them (the point at the working distance along its gaze when
   * it sees none). */
  aimPoint(k) {
    const v = this.viewpoints[k];
    const p = new THREE.Vector3(...v.position);
    const g = new THREE.Vector3(...v.gaze).normalize();
    const wd = this.sensor.working_distance_mm ?? (this.sensor.near_mm + this.sensor.far_mm) / 2;
    let best = p.clone().addScaledVector(g, wd);
    let bestD = Infinity;
    const c = new THREE.Vector3();
    const faces = this.facesOf(k);
    const stride = Math.ceil(faces.length / AIM_FACES);
    for (let i = 0; i < faces.length; i += stride) {
      const f = faces[i];
      c.fromArray(this.centroids, 3 * f).sub(p);
      const along = c.dot(g);
      const d = c.addScaledVector(g, -along).lengthSq();
      if (d < bestD) { bestD = d; best = new THREE.Vector3().fromArray(this.centroids, 3 * f); }
    }
    return best;
  }

  /** Faces of viewpoint k (visiting order) as a Uint32Array of face ids. */
  facesOf(k) { return this.seen.subarray(this.offsets[k], this.offsets[k + 1]); }

  /** Show only the problems (`on`): met faces drawn pale, by their state array (M,) uint8. */
  setProblemsOnly(on, states) {
    this.problems = on;
    this.states = states;
    this.paint();
  }

  /** Colour the faces: their own colour (met ones pale under "problems only"), faded where the
   * selected camera does not see them. */
  paint() {
    const attr = this.part.geometry.getAttribute('color');
    const out = attr.array;
    const shown = new Uint8Array(this.colours);
    if (this.problems) {
      for (let i = 0; i < this.nFaces; i++) if (this.states[i] === 0) shown.set(GHOST, 3 * i);
    }
    if (this.selected !== null) {
      const keep = new Uint8Array(this.nFaces);
      for (const f of this.facesOf(this.selected)) keep[f] = 1;
      for (let i = 0; i < this.nFaces; i++) {
        if (keep[i]) continue;
        for (let c = 0; c < 3; c++) shown[3 * i + c] = Math.round(shown[3 * i + c] * (1 - DIM_MIX) + DIM * DIM_MIX);
      }
    }
    for (let i = 0; i < this.nFaces; i++) {
      for (let c = 0; c < 3; c++) {
        const v = LINEAR[shown[3 * i + c]];
        out[9 * i + c] = v;
        out[9 * i + 3 + c] = v;
        out[9 * i + 6 + c] = v;
      }
    }
    this.shown = shown;
    attr.needsUpdate = true;
    this.markProblems(shown);
    this.render();
  }

  /** Under "problems only", a dot in its colour on each problem face, so that faces smaller
   * than a pixel still show where they are; hidden where the part is in front of them. */
  markProblems(shown) {
    if (this.marks) { this.scene.remove(this.marks); this.marks.geometry.dispose(); this.marks = null; }
    this.markFaces = [];
    if (!this.problems || !this.states) return;
    const faces = [];
    for (let i = 0; i < this.nFaces; i++) if (PROBLEMS.includes(this.states[i])) faces.push(i);
    const normals = this.part.geometry.getAttribute('normal').array;
    const lift = MARK_LIFT * this.part.geometry.boundingBox.getSize(new THREE.Vector3()).length();
    const pos = new Float32Array(3 * faces.length);
    const col = new Float32Array(3 * faces.length);
    faces.forEach((f, j) => {
      for (let c = 0; c < 3; c++) {
        pos[3 * j + c] = this.centroids[3 * f + c] + lift * normals[9 * f + c];
        col[3 * j + c] = LINEAR[shown[3 * f + c]];
      }
    });
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(pos, 3));
    geometry.setAttribute('color', new THREE.BufferAttribute(col, 3));
    this.marks = new THREE.Points(geometry, new THREE.PointsMaterial(
      { size: MARK_PX, sizeAttenuation: false, vertexColors: true }));
    this.markFaces = faces;
    this.scene.add(this.marks);
  }

  /** The problem marks: face, canvas CSS px [x, y], sRGB colour, whether its face turns
   * towards the eye, the mark's and the eye's world positions (mm). */
  problemMarks() {
    if (!this.marks) return [];
    const { width, height } = this.size();
    const pos = this.marks.geometry.getAttribute('position');
    const normals = this.part.geometry.getAttribute('normal').array;
    const eye = this.camera.position;
    return this.markFaces.map((f, j) => {
      const w = new THREE.Vector3().fromBufferAttribute(pos, j);
      const n = new THREE.Vector3(normals[9 * f], normals[9 * f + 1], normals[9 * f + 2]);
      const facing = n.dot(eye.clone().sub(w)) > 0;
      const p = w.clone().project(this.camera);
      const xy = [((p.x + 1) / 2) * width, ((1 - p.y) / 2) * height];
      const rgb = Array.from(this.shown.subarray(3 * f, 3 * f + 3));
      return { face: f, xy, rgb, facing, world: w.toArray(), eye: eye.toArray() };
    });
  }

  /** Frustum corners (8 world points, near then far) of viewpoint k. */
  corners(k) {
    const s = this.sensor;
    const tx = Math.tan((s.fov_x_deg * Math.PI) / 360);
    const ty = Math.tan((s.fov_y_deg * Math.PI) / 360);
    const m = this.matrix(k);
    const out = [];
    for (const d of [s.near_mm, s.far_mm]) {
      for (const [a, b] of [[-1, -1], [1, -1], [1, 1], [-1, 1]]) {
        out.push(new THREE.Vector3(a * d * tx, b * d * ty, d).applyMatrix4(m));
      }
    }
    return out;
  }

  /** camera_to_world of viewpoint k as a Matrix4 (OpenCV frame, SPEC §8). */
  matrix(k) {
    return new THREE.Matrix4().fromArray(this.viewpoints[k].camera_to_world.flat()).transpose();
  }

  /** Segment end points of viewpoint k's depth of field box (12 edges), with `apex` also the
   * 4 lines from the camera to the near corners. */
  frustumLines(k, apex = false) {
    const c = this.corners(k);
    const p = new THREE.Vector3(...this.viewpoints[k].position);
    const pts = [];
    for (let i = 0; i < 4; i++) {
      const j = (i + 1) % 4;
      pts.push(c[i], c[j], c[4 + i], c[4 + j], c[i], c[4 + i]);
      if (apex) pts.push(p, c[i]);
    }
    return pts;
  }

  /** Segment end points of viewpoint k's glyph: a pyramid from the camera to a rectangle of
   * the sensor's aspect `depth` mm along its gaze (8 edges). */
  glyphLines(k, depth) {
    const s = this.sensor;
    const tx = Math.tan((s.fov_x_deg * Math.PI) / 360);
    const ty = Math.tan((s.fov_y_deg * Math.PI) / 360);
    const m = this.matrix(k);
    const p = new THREE.Vector3(...this.viewpoints[k].position);
    const c = [[-1, -1], [1, -1], [1, 1], [-1, 1]]
      .map(([a, b]) => new THREE.Vector3(a * depth * tx, b * depth * ty, depth).applyMatrix4(m));
    return c.flatMap((q, i) => [p, q, q, c[(i + 1) % 4]]);
  }

  buildCameras() {
    for (const child of [...this.cameras.children]) {
      child.geometry?.dispose();
      this.cameras.remove(child);
    }
    for (const el of [...this.labelLayer.children]) el.remove();
    const n = this.viewpoints.length;
    const diagonal = this.part.geometry.boundingBox.getSize(new THREE.Vector3()).length();
    const depth = Math.min(GLYPH * diagonal, this.sensor.near_mm);
    const all = [];
    for (let k = 0; k < n; k++) all.push(...this.glyphLines(k, depth));
    this.frusta = new THREE.LineSegments(
      new THREE.BufferGeometry().setFromPoints(all),
      new THREE.LineBasicMaterial({ color: FRUSTUM, transparent: true, opacity: 0.6 }),
    );
    this.highlight = new THREE.LineSegments(
      new THREE.BufferGeometry(), new THREE.LineBasicMaterial({ color: SELECTED }));
    const positions = this.viewpoints.map((v) => new THREE.Vector3(...v.position));
    this.tour = new THREE.Line(
      new THREE.BufferGeometry().setFromPoints(positions),
      new THREE.LineBasicMaterial({ color: TOUR }));
    const pins = new THREE.BufferGeometry().setFromPoints(positions);
    pins.setAttribute('color', new THREE.BufferAttribute(new Float32Array(3 * n), 3));
    this.pins = new THREE.Points(pins, new THREE.PointsMaterial(
      { size: PIN_PX, sizeAttenuation: false, vertexColors: true }));
    this.labels = this.aims.map((p, k) => {
      const div = document.createElement('div');
      div.className = 'cam-label';
      div.textContent = String(k + 1);
      div.dataset.k = String(k);
      div.title = `viewpoint ${k + 1}: click to select; the number sits where it looks`;
      div.addEventListener('click', () => this.onPick?.(k));
      this.labelLayer.append(div);
      return { element: div, anchor: p, visible: true };
    });
    for (const l of this.labels) l.size = [l.element.offsetWidth, l.element.offsetHeight];
    this.cameras.add(this.frusta, this.highlight, this.tour, this.pins);
    this.applyVisibility();
  }

  /** The arm of a robot setup from the plan scene's arrays (arm_vertices (V·3) mm in link
   * frames, arm_faces, arm_link (V), arm_frames (K·L·16, row-major, part frame)); none: no arm. */
  setArm(a) {
    if (this.armMesh) {
      this.scene.remove(this.armMesh);
      this.armMesh.geometry.dispose();
      this.armMesh = null;
    }
    this.arm = a && a.arm_vertices ? a : null;
    if (!this.arm) return;
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position',
      new THREE.BufferAttribute(new Float32Array(this.arm.arm_vertices.length), 3));
    geometry.setIndex(new THREE.BufferAttribute(new Uint32Array(this.arm.arm_faces), 1));
    this.armMesh = new THREE.Mesh(geometry, new THREE.MeshStandardMaterial(
      { color: ARM, transparent: true, opacity: 0.6, side: THREE.DoubleSide }));
    this.armMesh.visible = false;
    this.scene.add(this.armMesh);
  }

  /** The setup from the plan scene's triangle soups (T·9 float32 mm, part frame): the floor
   * (setup_floor, a square) as a translucent plane with a grid, fixtures (setup_fixtures) and
   * keep-out volumes (setup_keep_out) as translucent grey solids; none: nothing drawn. */
  setSetup(a) {
    if (this.setup) {
      this.scene.remove(this.setup);
      this.setup.traverse((o) => { o.geometry?.dispose(); o.material?.dispose(); });
    }
    this.setup = null;
    if (!a || !(a.setup_floor || a.setup_fixtures || a.setup_keep_out)) return;
    this.setup = new THREE.Group();
    this.setup.name = 'setup';
    const solid = (name, triangles, colour, opacity) => {
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(triangles), 3));
      geometry.computeVertexNormals();
      const mesh = new THREE.Mesh(geometry, new THREE.MeshLambertMaterial({
        color: colour, transparent: true, opacity, depthWrite: false, side: THREE.DoubleSide,
        // pushed back in depth: where it touches the part (the floor under it, a clamp on
        // it) the part's face is drawn, not streaks of both
        polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 4 }));
      mesh.name = name;
      mesh.renderOrder = 1; // after the part, so that it shows through
      this.setup.add(mesh);
    };
    if (a.setup_floor) {
      solid('floor', a.setup_floor, FLOOR, FLOOR_OPACITY);
      this.setup.add(this.floorGrid(a.setup_floor));
    }
    if (a.setup_fixtures) solid('fixtures', a.setup_fixtures, SOLID, SOLID_OPACITY);
    if (a.setup_keep_out) solid('keep_out', a.setup_keep_out, SOLID, KEEP_OUT_OPACITY);
    this.scene.add(this.setup);
    this.applyVisibility();
  }

  /** Grid lines over the floor square (its two triangles: corners 0, 1, 2 and 0, 2, 5). */
  floorGrid(t) {
    const c = [0, 1, 2, 5].map((i) => new THREE.Vector3(t[3 * i], t[3 * i + 1], t[3 * i + 2]));
    const points = [];
    for (let i = 0; i <= FLOOR_GRID; i++) {
      const s = i / FLOOR_GRID;
      points.push(c[0].clone().lerp(c[1], s), c[3].clone().lerp(c[2], s));
      points.push(c[0].clone().lerp(c[3], s), c[1].clone().lerp(c[2], s));
    }
    const grid = new THREE.LineSegments(new THREE.BufferGeometry().setFromPoints(points),
      new THREE.LineBasicMaterial({ color: FLOOR, transparent: true, opacity: 0.5, depthWrite: false }));
    grid.name = 'floor-grid';
    grid.renderOrder = 1;
    return grid;
  }

  /** The setup drawn: {shown, floor, fixtures, keep_out} each null or {visible, min, max}, the
   * world-space box of its vertices (mm); null without a setup. */
  setupState() {
    if (!this.setup) return null;
    const out = { shown: this.setup.visible };
    for (const name of ['floor', 'fixtures', 'keep_out']) {
      const o = this.setup.getObjectByName(name);
      if (!o) { out[name] = null; continue; }
      o.updateMatrixWorld(true);
      const box = new THREE.Box3().setFromObject(o);
      out[name] = { visible: o.visible && this.setup.visible, min: box.min.toArray(), max: box.max.toArray() };
    }
    return out;
  }

  /** Pose the arm at viewpoint k: each vertex by its link's frame at that view. */
  poseArm(k) {
    if (!this.armMesh) return;
    this.armMesh.visible = k !== null && !this.frame;
    if (k === null) return;
    const { arm_vertices: v, arm_link: link, arm_frames: f } = this.arm;
    const links = f.length / 16 / this.viewpoints.length;
    const pos = this.armMesh.geometry.getAttribute('position');
    for (let i = 0; i < link.length; i++) {
      const o = 16 * (k * links + link[i]);
      const [x, y, z] = [v[3 * i], v[3 * i + 1], v[3 * i + 2]];
      for (let r = 0; r < 3; r++) {
        pos.array[3 * i + r] = f[o + 4 * r] * x + f[o + 4 * r + 1] * y + f[o + 4 * r + 2] * z + f[o + 4 * r + 3];
      }
    }
    pos.needsUpdate = true;
    this.armMesh.geometry.computeVertexNormals();
    this.armMesh.geometry.computeBoundingSphere();
  }

  /** Whether the arm is drawn and the box of its posed vertices (null without an arm). */
  armState() {
    if (!this.armMesh) return null;
    const box = new THREE.Box3().setFromBufferAttribute(this.armMesh.geometry.getAttribute('position'));
    return { visible: this.armMesh.visible, min: box.min.toArray(), max: box.max.toArray() };
  }

  select(k) {
    this.selected = k;
    this.poseArm(k);
    this.highlight.geometry.dispose();
    this.highlight.geometry = new THREE.BufferGeometry().setFromPoints(
      k === null ? [] : this.frustumLines(k, true));
    this.labels.forEach((l, i) => l.element.classList.toggle('selected', i === k));
    const colour = this.pins.geometry.getAttribute('color');
    const [a, b] = [new THREE.Color(FRUSTUM), new THREE.Color(SELECTED)];
    for (let i = 0; i < this.viewpoints.length; i++) colour.setXYZ(i, ...(i === k ? b : a).toArray());
    colour.needsUpdate = true;
    this.paint();
  }

  /** Show or hide the frusta (with the camera pins), the tour or the number labels. */
  show(what, on) {
    this.visible = { ...this.visible, [what]: on };
    this.applyVisibility();
    this.render();
  }

  /** What is drawn: the toggles, and while looking through a camera none of the others. */
  applyVisibility() {
    const v = { frusta: true, tour: true, labels: true, setup: true, ...this.visible };
    const through = this.frame !== null && this.frame !== undefined;
    this.frusta.visible = this.pins.visible = v.frusta && !through;
    this.highlight.visible = v.frusta && !through;
    this.tour.visible = v.tour && !through;
    if (this.armMesh) this.armMesh.visible = this.selected !== null && !through;
    if (this.setup) this.setup.visible = v.setup;
    this.labels.forEach((l) => { l.visible = v.labels && !through; });
  }

  /** Frame the part (and the cameras when `all`) from the current direction (a default one
   * the first time): the eye just far enough that the part's vertices (up to FIT_POINTS of
   * them) and every camera fall inside the canvas less FIT_MARGIN on each side. */
  fit(all = true) {
    this.frame = null;
    this.applyVisibility();
    const pos = this.part.geometry.getAttribute('position');
    const points = [];
    const stride = Math.max(1, Math.floor(pos.count / FIT_POINTS));
    for (let i = 0; i < pos.count; i += stride) points.push(new THREE.Vector3().fromBufferAttribute(pos, i));
    if (all) for (const v of this.viewpoints) points.push(new THREE.Vector3(...v.position));
    const centre = new THREE.Box3().setFromPoints(points).getCenter(new THREE.Vector3());
    const offset = this.fitted ? this.camera.position.clone().sub(this.controls.target)
      : new THREE.Vector3(1, -1.4, 1);
    if (!this.fitted) this.camera.up.set(0, 0, 1);
    this.fitted = true;
    this.camera.fov = 40;
    const { width, height } = this.size();
    this.camera.aspect = width / height;
    this.camera.position.copy(centre).add(offset);
    this.camera.lookAt(centre);
    this.camera.updateMatrixWorld();
    const ty = Math.tan((this.camera.fov * Math.PI) / 360) * (1 - 2 * FIT_MARGIN);
    const tx = ty * this.camera.aspect;
    const inverse = this.camera.matrixWorld.clone().invert();
    const c = centre.clone().applyMatrix4(inverse);
    let dist = 0;
    for (const p of points) {
      const q = p.clone().applyMatrix4(inverse).sub(c); // eye frame, from the centre
      dist = Math.max(dist, q.z + Math.abs(q.x) / tx, q.z + Math.abs(q.y) / ty);
    }
    const dir = this.camera.getWorldDirection(new THREE.Vector3());
    this.camera.position.copy(centre).addScaledVector(dir, -dist);
    this.controls.target.copy(centre);
    this.resize();
  }

  /** See the part through viewpoint k: its pose, its fov fitted into the canvas. */
  lookThrough(k) {
    const v = this.viewpoints[k];
    const { width, height } = this.size();
    const s = this.sensor;
    const f = Math.min(width / 2 / Math.tan((s.fov_x_deg * Math.PI) / 360),
      height / 2 / Math.tan((s.fov_y_deg * Math.PI) / 360));
    const m = this.matrix(k).multiply(CV_TO_GL);
    this.camera.position.set(...v.position);
    this.camera.quaternion.setFromRotationMatrix(m);
    this.camera.up.set(0, 1, 0).applyQuaternion(this.camera.quaternion);
    const wd = s.working_distance_mm ?? (s.near_mm + s.far_mm) / 2;
    this.controls.target.set(...v.position).addScaledVector(new THREE.Vector3(...v.gaze), wd);
    this.frame = { k, f };
    this.applyVisibility();
    this.resize();
    this.camera.quaternion.setFromRotationMatrix(m); // OrbitControls' lookAt may round it
    this.render();
    const frameW = 2 * f * Math.tan((s.fov_x_deg * Math.PI) / 360);
    const frameH = 2 * f * Math.tan((s.fov_y_deg * Math.PI) / 360);
    return { f, width, height, frame: [(width - frameW) / 2, (height - frameH) / 2, frameW, frameH] };
  }

  size() {
    const r = this.canvas.parentElement.getBoundingClientRect();
    return { width: Math.max(1, Math.round(r.width)), height: Math.max(1, Math.round(r.height)) };
  }

  resize() {
    const { width, height } = this.size();
    this.renderer.setSize(width, height, false);
    this.camera.aspect = width / height;
    if (this.frame) {
      this.camera.fov = (2 * Math.atan(height / 2 / this.frame.f) * 180) / Math.PI;
    } else {
      this.camera.fov = 40;
    }
    this.camera.updateProjectionMatrix();
    this.controls.update();
    this.render();
  }

  render() {
    if (!this.part || this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
      const dist = this.camera.position.distanceTo(this.controls.target);
      const size = this.part.geometry.boundingBox.getSize(new THREE.Vector3()).length();
      this.camera.near = Math.max(dist / 1000, size / 1e5);
      this.camera.far = dist * 10 + size * 10;
      this.camera.updateProjectionMatrix();
      this.renderer.render(this.scene, this.camera);
      this.placeLabels();
      this.frames = (this.frames || 0) + 1;
      for (const resolve of this.waiting.splice(0)) resolve(this.frames);
    });
  }

  /** Put each shown number label next to its aim point, none over another, all inside the
   * canvas; a label with no free place nearby is hidden (zoom in to see it). Labels of cameras
   * that look at the far side of the part are drawn faint. */
  placeLabels() {
    if (!this.labels) return;
    const { width, height } = this.size();
    const eye = this.camera.getWorldDirection(new THREE.Vector3());
    const items = [];
    for (const [k, l] of this.labels.entries()) {
      const p = l.anchor.clone().project(this.camera);
      const shown = l.visible && p.z < 1;
      l.element.hidden = !shown;
      if (!shown) continue;
      const far = eye.dot(new THREE.Vector3(...this.viewpoints[k].gaze)) < 0;
      l.element.classList.toggle('far', far);
      items.push({ l, x: ((p.x + 1) / 2) * width, y: ((1 - p.y) / 2) * height, far, k });
    }
    // the selected one first, then the labels of the near side
    items.sort((a, b) => (b.k === this.selected) - (a.k === this.selected) || a.far - b.far);
    const placed = placeLabels(items.map((it) => ({ x: it.x, y: it.y, w: it.l.size[0], h: it.l.size[1] })),
      width, height);
    items.forEach((it, i) => {
      const r = placed[i];
      it.l.element.hidden = r === null;
      if (r) it.l.element.style.transform = `translate(${r[0]}px, ${r[1]}px)`;
    });
    const shown = placed.filter((r) => r !== null).length;
    if (shown !== this.labelsShown) this.onLabels?.(shown, items.length);
    this.labelsShown = shown;
  }

  /** The part's projected box [x0, y0, x1, y1] in canvas CSS px (up to 20 000 vertices). */
  partBox() {
    const pos = this.part.geometry.getAttribute('position');
    const { width, height } = this.size();
    const stride = Math.max(1, Math.floor(pos.count / 20000));
    const box = [Infinity, Infinity, -Infinity, -Infinity];
    const p = new THREE.Vector3();
    for (let i = 0; i < pos.count; i += stride) {
      p.fromBufferAttribute(pos, i).project(this.camera);
      const x = ((p.x + 1) / 2) * width;
      const y = ((1 - p.y) / 2) * height;
      box[0] = Math.min(box[0], x); box[1] = Math.min(box[1], y);
      box[2] = Math.max(box[2], x); box[3] = Math.max(box[3], y);
    }
    return box;
  }

  /** Canvas rectangles [x, y, w, h] (CSS px) of the number labels shown, by camera index. */
  labelBoxes() {
    const c = this.canvas.getBoundingClientRect();
    return Object.fromEntries(this.labels.filter((l) => !l.element.hidden).map((l) => {
      const r = l.element.getBoundingClientRect();
      return [l.element.dataset.k, [r.left - c.left, r.top - c.top, r.width, r.height]];
    }));
  }

  /** A promise of the number of frames drawn, resolved once the next frame is on screen. */
  drawn() {
    return new Promise((resolve) => { this.waiting.push(resolve); this.render(); });
  }

  /** The viewpoint whose gaze is closest to the eye's (it sees the side the eye sees). */
  facing() {
    const eye = this.camera.getWorldDirection(new THREE.Vector3());
    let best = 0;
    this.viewpoints.forEach((v, k) => {
      if (eye.dot(new THREE.Vector3(...v.gaze)) > eye.dot(new THREE.Vector3(...this.viewpoints[best].gaze))) best = k;
    });
    return best;
  }

  /** Turn the eye by `angle` (rad) around the orbit target, about the camera's up axis. */
  /** The eye moves: draw at MOVING_SCALE of the pixels (a CPU rasteriser keeps up) until
   * SETTLE_MS after the last call, then at full resolution again. */
  moving() {
    clearTimeout(this.settle);
    const full = window.devicePixelRatio;
    if (this.renderer.getPixelRatio() === full) this.setPixelRatio(full * MOVING_SCALE);
    this.settle = setTimeout(() => this.setPixelRatio(full), SETTLE_MS);
  }

  setPixelRatio(ratio) {
    const { width, height } = this.size();
    this.renderer.setPixelRatio(ratio);
    this.renderer.setSize(width, height, false);
    this.render();
  }

  rotate(angle) {
    this.moving();
    const offset = this.camera.position.clone().sub(this.controls.target);
    offset.applyAxisAngle(this.camera.up, angle);
    this.camera.position.copy(this.controls.target).add(offset);
    this.camera.lookAt(this.controls.target);
    this.render();
  }

  /** CSS pixel position of viewpoint k's pin in the canvas (null when behind the eye). */
  screenPosition(k) {
    const p = new THREE.Vector3(...this.viewpoints[k].position).project(this.camera);
    if (p.z > 1) return null;
    const { width, height } = this.size();
    return [((p.x + 1) / 2) * width, ((1 - p.y) / 2) * height];
  }

  /** A click (not a drag) on the canvas picks the camera whose pin is nearest, within PICK_PX. */
  picking(canvas) {
    let down = null;
    canvas.addEventListener('pointerdown', (e) => { down = [e.clientX, e.clientY]; });
    canvas.addEventListener('pointerup', (e) => {
      if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4 || !this.pins?.visible) return;
      const r = canvas.getBoundingClientRect();
      let best = null;
      let bestD = PICK_PX;
      for (let k = 0; k < this.viewpoints.length; k++) {
        const p = this.screenPosition(k);
        const d = p ? Math.hypot(p[0] - (e.clientX - r.left), p[1] - (e.clientY - r.top)) : Infinity;
        if (d < bestD) { best = k; bestD = d; }
      }
      if (best !== null) this.onPick?.(best);
    });
  }
}
