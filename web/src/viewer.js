// The 3-D viewer: each method's mesh (GLB) and point cloud (PLY coloured by its scalar), the
// ground truth when the survey has one; orbit, zoom and pan (mouse, touch and arrow keys); the
// survey frame's axes in a corner.
// Files are fetched through the API (with the session key) and parsed here.

import * as THREE from "three";
import { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
import { GLTFLoader } from "three/examples/jsm/loaders/GLTFLoader.js";
import { PLYLoader } from "three/examples/jsm/loaders/PLYLoader.js";
import { api } from "./api.js";

const GROUND_TRUTH = 0xd0d0d0;
// each method's colour is the method catalogue's (GET /methods), fetched once
let methodColours = null;
let known = {}; // the catalogue's colours once fetched (legends read them synchronously)
function coloursOf() {
  methodColours ??= api("/methods")
    .then((ms) => (known = Object.fromEntries(ms.map((m) => [m.name, parseInt(m.colour.slice(1), 16)]))))
    .catch(() => ({}));
  return methodColours;
}

// viridis at 5 stops: scalars in [τ, 1] read as a familiar dark-to-bright scale
const VIRIDIS = [[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551], [0.369, 0.789, 0.383], [0.993, 0.906, 0.144]];

/** The CSS colour a layer of ``key`` (a method, or "ground_truth") is drawn in: for legends
 * (a method's colour is known once its mesh was added, which fetched the catalogue). */
export function layerColour(key) {
  const colour = key === "ground_truth" ? GROUND_TRUTH : known[key] ?? 0xcccccc;
  return `#${colour.toString(16).padStart(6, "0")}`;
}

/** The point clouds' colour scale as a CSS gradient (low to high intensity). */
export function viridisGradient() {
  const stops = VIRIDIS.map((c, i) => `rgb(${c.map((v) => Math.round(v * 255)).join(",")}) ${(i / (VIRIDIS.length - 1)) * 100}%`);
  return `linear-gradient(to right, ${stops.join(", ")})`;
}
function viridis(t) {
  const x = Math.min(Math.max(t, 0), 1) * (VIRIDIS.length - 1);
  const i = Math.min(Math.floor(x), VIRIDIS.length - 2);
  const f = x - i;
  return VIRIDIS[i].map((a, k) => a + (VIRIDIS[i + 1][k] - a) * f);
}

/** Side (CSS px) of the orientation gizmo drawn in the lower-right corner of each view. */
export const GIZMO_PX = 84;

/** A text label ("x") as a sprite, for the gizmo's axes. */
function axisLabel(text, position, colour) {
  const c = Object.assign(document.createElement("canvas"), { width: 64, height: 64 });
  const g = c.getContext("2d");
  g.fillStyle = colour;
  g.font = "bold 44px sans-serif";
  g.textAlign = "center";
  g.textBaseline = "middle";
  g.fillText(text, 32, 34);
  const sprite = new THREE.Sprite(new THREE.SpriteMaterial({ map: new THREE.CanvasTexture(c), depthTest: false }));
  sprite.position.set(...position);
  sprite.scale.set(0.7, 0.7, 1);
  return sprite;
}

/** The survey frame's axes (x red, y green, z blue and up), turned as the camera turns. */
function makeGizmo() {
  const scene = new THREE.Scene();
  const axes = new THREE.AxesHelper(1);
  axes.setColors(new THREE.Color(0xff5555), new THREE.Color(0x55dd55), new THREE.Color(0x5599ff));
  scene.add(axes);
  scene.add(axisLabel("x", [1.3, 0, 0], "#ff5555"), axisLabel("y", [0, 1.3, 0], "#55dd55"), axisLabel("z", [0, 0, 1.3], "#5599ff"));
  const camera = new THREE.OrthographicCamera(-1.7, 1.7, 1.7, -1.7, 0.1, 10);
  return { scene, camera };
}

export class Viewer {
  constructor(canvas, { main = true } = {}) {
    this.canvas = canvas;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0x10151c);
    this.camera = new THREE.PerspectiveCamera(45, 1, 0.001, 1000);
    this.camera.up.set(0, 0, 1); // survey frame: z up
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.listenToKeyEvents(canvas);
    this.controls.addEventListener("change", () => this.render());
    // keyboard zoom beside OrbitControls' arrow keys: + / = closer, - farther
    canvas.addEventListener("keydown", (e) => {
      const f = { "+": 0.8, "=": 0.8, "-": 1.25, _: 1.25 }[e.key];
      if (!f) return;
      e.preventDefault();
      this.zoom(f);
    });
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x303040, 2.2));
    const sun = new THREE.DirectionalLight(0xffffff, 1.5);
    sun.position.set(1, -1, 2);
    this.scene.add(sun);
    this.gizmo = makeGizmo();
    this.layers = new Map(); // name -> Object3D
    this.origin = null; // survey-frame point placed at the scene origin (float32 precision)
    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
    if (main) window.__shsasViewer = this; // for the browser tests: what the scene holds
  }

  resize() {
    const w = this.canvas.clientWidth || 300;
    const h = this.canvas.clientHeight || 300;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() {
    const r = this.renderer;
    r.render(this.scene, this.camera);
    // the axes in the lower-right corner, seen from the camera's direction
    const { scene, camera } = this.gizmo;
    camera.position.copy(this.camera.position).sub(this.controls.target).setLength(4);
    camera.up.copy(this.camera.up);
    camera.lookAt(0, 0, 0);
    const size = r.getSize(new THREE.Vector2());
    r.autoClear = false;
    r.clearDepth();
    r.setViewport(size.x - GIZMO_PX, 0, GIZMO_PX, GIZMO_PX);
    r.render(scene, camera);
    r.setViewport(0, 0, size.x, size.y);
    r.autoClear = true;
    this.onRender?.();
  }

  /** Move the camera ``factor`` times its distance from the orbit centre (< 1: closer). */
  zoom(factor) {
    const offset = this.camera.position.clone().sub(this.controls.target).multiplyScalar(factor);
    this.camera.position.copy(this.controls.target).add(offset);
    this.controls.update(); // fires "change": linked panes follow
  }

  /** Back to the view the result opened with. */
  reset() {
    if (!this.home) return;
    this.camera.position.copy(this.home.position);
    this.controls.target.copy(this.home.target);
    this.camera.updateProjectionMatrix();
    this.controls.update();
    this.render();
  }

  clear() {
    this.onClear?.();
    for (const name of [...this.layers.keys()]) this.remove(name);
    this.origin = null;
  }

  remove(name) {
    const obj = this.layers.get(name);
    if (!obj) return;
    this.scene.remove(obj);
    obj.traverse((o) => {
      o.geometry?.dispose();
      o.material?.dispose?.();
    });
    this.layers.delete(name);
  }

  place(offset) {
    // GLB coordinates + offset = survey frame; everything is shown relative to the first offset
    if (!this.origin) this.origin = new THREE.Vector3(...(offset || [0, 0, 0]));
    return new THREE.Vector3(...(offset || [0, 0, 0])).sub(this.origin);
  }

  async addMesh(name, buffer, offset, colourKey) {
    const gltf = await new GLTFLoader().parseAsync(buffer, "");
    const group = new THREE.Group();
    const gt = colourKey === "ground_truth";
    const colour = gt ? GROUND_TRUTH : (await coloursOf())[colourKey] ?? 0xcccccc;
    gltf.scene.traverse((o) => {
      if (o.isMesh) {
        o.material = new THREE.MeshStandardMaterial({
          color: colour, roughness: 0.6, metalness: 0.05, side: THREE.DoubleSide,
          transparent: gt, opacity: gt ? 0.35 : 1, wireframe: false, depthWrite: !gt,
        });
      }
    });
    group.add(gltf.scene);
    group.position.copy(this.place(offset));
    group.userData = { kind: "mesh", triangles: countTriangles(gltf.scene) };
    this.set(name, group);
    return group.userData.triangles;
  }

  addPoints(name, buffer) {
    const loader = new PLYLoader();
    loader.setCustomPropertyNameMapping({ scalar: ["scalar_magnitude"] });
    const geom = loader.parse(buffer);
    for (const [attr, a] of Object.entries(geom.attributes)) {
      // PLY doubles arrive as Float64 attributes, which WebGL cannot draw
      if (a.array instanceof Float64Array) geom.setAttribute(attr, new THREE.Float32BufferAttribute(a.array, a.itemSize));
    }
    const n = geom.getAttribute("position")?.count ?? 0;
    const scalar = geom.getAttribute("scalar");
    const colours = new Float32Array(n * 3);
    for (let i = 0; i < n; i++) colours.set(viridis(scalar ? scalar.getX(i) : 1), i * 3);
    geom.setAttribute("color", new THREE.BufferAttribute(colours, 3));
    const shift = this.place([0, 0, 0]); // PLY points are in the survey frame already
    geom.translate(shift.x, shift.y, shift.z);
    const pts = new THREE.Points(geom, new THREE.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: true }));
    pts.userData = { kind: "points", points: n };
    this.set(name, pts);
    return n;
  }

  set(name, obj) {
    const visible = this.layers.get(name)?.visible ?? true;
    this.remove(name);
    obj.visible = visible;
    obj.name = name;
    this.layers.set(name, obj);
    this.scene.add(obj);
    this.render();
  }

  show(name, on) {
    const obj = this.layers.get(name);
    if (obj) obj.visible = on;
    this.render();
  }

  frame() {
    this.frameBox(this.box());
  }

  /** Place every layer relative to this survey-frame point (panes that share a camera share it). */
  setOrigin(offset) {
    this.origin = new THREE.Vector3(...(offset || [0, 0, 0]));
  }

  /** The box of the visible layers (empty when none). */
  box() {
    const box = new THREE.Box3();
    for (const obj of this.layers.values()) if (obj.visible) box.expandByObject(obj);
    return box;
  }

  /** Look at ``box`` from the default direction. */
  frameBox(box) {
    if (box.isEmpty()) return;
    const centre = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3()).length() || 1;
    this.controls.target.copy(centre);
    this.camera.position.copy(centre).add(new THREE.Vector3(0.9, -1.1, 0.7).multiplyScalar(size));
    this.camera.near = size / 1000;
    this.camera.far = size * 100;
    this.camera.updateProjectionMatrix();
    this.controls.update();
    this.home = { position: this.camera.position.clone(), target: this.controls.target.clone() };
    this.render();
  }

  /** Copy another viewer's camera (position, target, clipping) and draw. */
  follow(other) {
    this.camera.position.copy(other.camera.position);
    this.camera.quaternion.copy(other.camera.quaternion);
    this.camera.near = other.camera.near;
    this.camera.far = other.camera.far;
    this.camera.updateProjectionMatrix();
    this.controls.target.copy(other.controls.target);
    this.controls.update();
    this.render();
  }

  /** Link the cameras of ``viewers``: moving one moves all of them the same way. */
  static link(viewers) {
    let busy = false; // follow() fires the followers' own change events
    for (const v of viewers) {
      v.controls.addEventListener("change", () => {
        if (busy) return;
        busy = true;
        for (const o of viewers) if (o !== v) o.follow(v);
        busy = false;
      });
    }
  }

  dispose() {
    this.clear();
    this.controls.dispose();
    this.renderer.dispose();
    this.renderer.forceContextLoss(); // a browser keeps only a few WebGL contexts
  }

  /** What the scene holds, for tests and the status line. */
  summary() {
    const out = {};
    for (const [name, obj] of this.layers) out[name] = { ...obj.userData, visible: obj.visible };
    return out;
  }
}

function countTriangles(root) {
  let n = 0;
  root.traverse((o) => {
    if (o.isMesh) n += (o.geometry.index ? o.geometry.index.count : o.geometry.getAttribute("position").count) / 3;
  });
  return n;
}
