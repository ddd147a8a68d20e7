// Viewer tools: reset the view, a scale bar in metres, a point-to-point measurement on the
// drawn surfaces (click two points; survey-frame metres), and the view saved as a PNG.

import * as THREE from "three";

/** A round length near ``x`` (1, 2 or 5 times a power of ten). */
export function roundLength(x) {
  const p = 10 ** Math.floor(Math.log10(x));
  return [1, 2, 5, 10].map((k) => k * p).filter((v) => v <= x).pop() || p;
}

export function fmtMetres(m) {
  if (m >= 1) return `${+m.toPrecision(3)} m`;
  if (m >= 0.01) return `${+(m * 100).toPrecision(3)} cm`;
  return `${+(m * 1000).toPrecision(3)} mm`;
}

export class ViewerTools {
  constructor(viewer, { scalebar, measureBtn, resetBtn, out, shotBtn, shotName = () => "view" }) {
    Object.assign(this, { viewer, scalebar, measureBtn, resetBtn, out, shotName });
    shotBtn?.addEventListener("click", () => this.screenshot());
    this.measuring = false;
    this.picks = [];
    this.marks = new THREE.Group();
    viewer.scene.add(this.marks);
    viewer.onRender = () => this.updateScale();
    viewer.onClear = () => {
      this.picks = [];
      this.marks.clear(); // a new result: the old measurement does not belong to it
      this.out.textContent = "";
    };
    resetBtn.addEventListener("click", () => viewer.reset());
    measureBtn.addEventListener("click", () => this.setMeasuring(!this.measuring));
    let down = null;
    viewer.canvas.addEventListener("pointerdown", (e) => (down = [e.clientX, e.clientY]));
    viewer.canvas.addEventListener("pointerup", (e) => {
      // a click, not the end of a drag (a drag turns the view)
      if (this.measuring && down && Math.hypot(e.clientX - down[0], e.clientY - down[1]) < 4) this.pick(e);
      down = null;
    });
  }

  setMeasuring(on) {
    this.measuring = on;
    this.measureBtn.setAttribute("aria-pressed", String(on));
    this.viewer.canvas.style.cursor = on ? "crosshair" : "";
    if (on) this.clear();
    this.out.textContent = on ? "click two points on a surface" : this.out.textContent;
  }

  clear() {
    this.picks = [];
    this.marks.clear();
    this.viewer.render();
  }

  /** The first drawn surface point under the pointer, in scene coordinates, or null. */
  hit(e) {
    const r = this.viewer.canvas.getBoundingClientRect();
    const ndc = new THREE.Vector2(((e.clientX - r.left) / r.width) * 2 - 1, -((e.clientY - r.top) / r.height) * 2 + 1);
    const ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, this.viewer.camera);
    const meshes = [];
    for (const obj of this.viewer.layers.values()) if (obj.visible && obj.userData.kind === "mesh") obj.traverse((o) => o.isMesh && meshes.push(o));
    const found = ray.intersectObjects(meshes, false)[0];
    return found ? found.point.clone() : null;
  }

  pick(e) {
    const p = this.hit(e);
    if (!p) {
      this.out.textContent = "no surface there: click on a mesh";
      return;
    }
    if (this.picks.length === 2) this.clear();
    this.picks.push(p);
    const size = this.viewer.camera.position.distanceTo(this.viewer.controls.target) / 150;
    const dot = new THREE.Mesh(new THREE.SphereGeometry(size, 12, 8), new THREE.MeshBasicMaterial({ color: 0xff3b30, depthTest: false }));
    dot.position.copy(p);
    this.marks.add(dot);
    if (this.picks.length === 2) {
      const line = new THREE.Line(new THREE.BufferGeometry().setFromPoints(this.picks),
        new THREE.LineBasicMaterial({ color: 0xff3b30, depthTest: false }));
      this.marks.add(line);
      const d = this.picks[0].distanceTo(this.picks[1]);
      this.out.textContent = `distance ${fmtMetres(d)}`;
      this.out.dataset.metres = String(d);
    } else this.out.textContent = "first point set; click the second";
    this.viewer.render();
  }

  /** The view as drawn, with its scale bar, saved as ``<survey>_view.png``. */
  async screenshot() {
    const v = this.viewer;
    v.render();
    const src = v.canvas;
    const img = Object.assign(document.createElement("canvas"), { width: src.width, height: src.height });
    const g = img.getContext("2d");
    g.drawImage(src, 0, 0);
    if (!this.scalebar.hidden) {
      // the bar as the page shows it, in the image's pixels
      const k = src.width / src.clientWidth;
      const px = Number(this.scalebar.dataset.px) * k;
      const x = 12 * k;
      const y = src.height - 14 * k;
      g.strokeStyle = g.fillStyle = "#ffffff";
      g.lineWidth = 2 * k;
      g.beginPath();
      g.moveTo(x, y - 5 * k);
      g.lineTo(x, y);
      g.lineTo(x + px, y);
      g.lineTo(x + px, y - 5 * k);
      g.stroke();
      g.font = `${12 * k}px sans-serif`;
      g.fillText(fmtMetres(Number(this.scalebar.dataset.metres)), x + 4 * k, y - 7 * k);
    }
    const blob = await new Promise((resolve) => img.toBlob(resolve, "image/png"));
    const url = URL.createObjectURL(blob);
    const a = Object.assign(document.createElement("a"), { href: url, download: `${this.shotName()}_view.png` });
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10000);
  }

  /** The bar shows a round length at the distance of the orbit's centre. */
  updateScale() {
    const v = this.viewer;
    const h = v.canvas.clientHeight;
    if (!h || !this.scalebar) return;
    const dist = v.camera.position.distanceTo(v.controls.target);
    const metresPerPx = (2 * dist * Math.tan(THREE.MathUtils.degToRad(v.camera.fov) / 2)) / h;
    const len = roundLength(metresPerPx * 120);
    const px = len / metresPerPx;
    this.scalebar.style.width = `${px.toFixed(1)}px`;
    this.scalebar.querySelector("span").textContent = fmtMetres(len);
    this.scalebar.dataset.metres = String(len);
    this.scalebar.dataset.px = String(px);
    this.scalebar.hidden = v.layers.size === 0;
  }
}
