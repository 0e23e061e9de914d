// The 3D scene: the part coloured per face, the selected cameras' frusta, the tour, picking.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { CSS2DObject, CSS2DRenderer } from 'three/addons/renderers/CSS2DRenderer.js';

const FRUSTUM = 0x1f6fb2;
const SELECTED = 0xe8590c;
const TOUR = 0x7048e8;
const DIM = 222; // faces the selected camera does not see fade towards this grey (sRGB)
const DIM_MIX = 0.8;
const PIN_PX = 9; // camera pins, drawn and picked in screen pixels
const PICK_PX = 8;
const LINEAR = Float32Array.from({ length: 256 }, (_, i) => {
  const c = i / 255; // sRGB byte → linear, so that the sRGB output shows the byte again
  return c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4;
});
// OpenCV camera frame (x right, y down, z forward) → three.js (x right, y up, −z forward)
const CV_TO_GL = new THREE.Matrix4().makeScale(1, -1, -1);

export class PlanScene {
  constructor(canvas, labels) {
    this.canvas = canvas;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio);
    this.renderer.setClearColor(0xf3f4f6);
    this.labelRenderer = new CSS2DRenderer({ element: labels });
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(40, 1, 1, 1e5);
    this.scene.add(this.camera);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8d8d8d, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.6);
    sun.position.set(0.3, 0.6, 1);
    this.camera.add(sun);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.addEventListener('change', () => this.render());
    this.controls.addEventListener('start', () => this.onInteract?.());
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
    this.buildCameras();
    this.paint();
  }

  /** Faces of viewpoint k (visiting order) as a Uint32Array of face ids. */
  facesOf(k) { return this.seen.subarray(this.offsets[k], this.offsets[k + 1]); }

  /** Colour the faces: their own colour, faded where the selected camera does not see them. */
  paint() {
    const attr = this.part.geometry.getAttribute('color');
    const out = attr.array;
    const shown = new Uint8Array(this.colours);
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
    this.render();
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

  buildCameras() {
    for (const child of [...this.cameras.children]) {
      child.geometry?.dispose();
      this.cameras.remove(child);
    }
    const n = this.viewpoints.length;
    const all = [];
    for (let k = 0; k < n; k++) all.push(...this.frustumLines(k));
    this.frusta = new THREE.LineSegments(
      new THREE.BufferGeometry().setFromPoints(all),
      new THREE.LineBasicMaterial({ color: FRUSTUM, transparent: true, opacity: 0.35 }),
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
    this.labels = positions.map((p, k) => {
      const div = document.createElement('div');
      div.className = 'cam-label';
      div.textContent = String(k + 1);
      div.dataset.k = String(k);
      div.addEventListener('click', () => this.onPick?.(k));
      const label = new CSS2DObject(div);
      label.position.copy(p);
      return label;
    });
    this.cameras.add(this.frusta, this.highlight, this.tour, this.pins, ...this.labels);
    this.applyVisibility();
  }

  select(k) {
    this.selected = k;
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

  applyVisibility() {
    const v = { frusta: true, tour: true, labels: true, ...this.visible };
    this.frusta.visible = this.highlight.visible = this.pins.visible = v.frusta;
    this.tour.visible = v.tour;
    this.labels.forEach((l) => { l.visible = v.labels; });
  }

  /** Frame the box of the part (and of the cameras when `all`). */
  fit(all = true) {
    this.frame = null;
    const box = this.part.geometry.boundingBox.clone();
    if (all) for (const v of this.viewpoints) box.expandByPoint(new THREE.Vector3(...v.position));
    const centre = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3()).length() || 1;
    const dir = new THREE.Vector3(1, -1.4, 1).normalize();
    const dist = (0.9 * size) / 2 / Math.tan((this.camera.fov * Math.PI) / 360);
    this.camera.up.set(0, 0, 1);
    this.camera.position.copy(centre).addScaledVector(dir, dist);
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
    this.labelRenderer.setSize(width, height);
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
      this.labelRenderer.render(this.scene, this.camera);
      this.frames = (this.frames || 0) + 1;
      for (const resolve of this.waiting.splice(0)) resolve(this.frames);
    });
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
  rotate(angle) {
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
