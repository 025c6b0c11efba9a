// The stage's camera: three.js's perspective camera and OrbitControls around a target, Z up (drag
// to orbit, right-drag or shift-drag to pan, wheel to zoom), preset views eased to (front looks at
// the performer's face: the world's X is forward). `cur` reads the view back as azimuth,
// elevation, distance and target, and `viewProj` is where a world point lands on the page.

import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

export const PRESETS = {
  front: { az: 0, el: 0.12 },
  side: { az: Math.PI / 2, el: 0.12 },
  top: { az: 0, el: Math.PI / 2 - 0.001 },
  perspective: { az: 0.62, el: 0.36 },
};
const RAD_PER_PX = 0.006;   // orbit speed (OrbitControls' is per canvas height: rescaled each frame)

export class StageCamera {
  constructor(canvas) {
    this.canvas = canvas;
    this.camera = new THREE.PerspectiveCamera(45, 1, 0.05, 200);
    this.camera.up.set(0, 0, 1);
    this.home = { dist: 7.2, target: [-0.5, 0, 0.85] };
    const c = new OrbitControls(this.camera, canvas);
    c.minPolarAngle = 0.001;                      // el below the zenith
    c.maxPolarAngle = Math.PI / 2 + 0.2;          // and down to 0.2 rad under the horizon
    c.minDistance = 0.3; c.maxDistance = 80;
    c.zoomSpeed = 1.5;
    c.addEventListener("start", () => { this.goal = null; });   // the pointer wins over an easing preset
    this.controls = c;
    this.viewProj = new THREE.Matrix4();
    this._place({ ...PRESETS.perspective, dist: this.home.dist, target: this.home.target });
    this.goal = null;
  }

  _place(v) {
    const t = v.target;
    this.controls.target.set(t[0], t[1], t[2]);
    this.camera.position.set(t[0] + v.dist * Math.cos(v.el) * Math.cos(v.az), t[1] + v.dist * Math.cos(v.el) * Math.sin(v.az),
      t[2] + v.dist * Math.sin(v.el));
    this.controls.update();
  }

  // The current view: {az, el, dist, target}.
  get cur() {
    const t = this.controls.target, p = this.camera.position;
    const d = [p.x - t.x, p.y - t.y, p.z - t.z];
    const dist = Math.hypot(d[0], d[1], d[2]);
    return { az: Math.atan2(d[1], d[0]), el: Math.asin(Math.max(-1, Math.min(1, d[2] / dist))), dist, target: [t.x, t.y, t.z] };
  }

  preset(name) {
    const p = PRESETS[name], c = this.cur;
    this.goal = { ...c, az: p.az, el: p.el };
    if (name === "perspective") { this.goal.dist = this.home.dist; this.goal.target = [...this.home.target]; }
    while (this.goal.az - c.az > Math.PI) this.goal.az -= 2 * Math.PI;   // turn the short way round
    while (c.az - this.goal.az > Math.PI) this.goal.az += 2 * Math.PI;
  }

  fit(b) {
    const c = [(b[0] + b[3]) / 2, (b[1] + b[4]) / 2, (b[2] + b[5]) / 2];
    const r = Math.max(0.8, Math.hypot(b[3] - b[0], b[4] - b[1], b[5] - b[2]) / 2);
    this.goal = { ...(this.goal || this.cur), target: c, dist: Math.min(40, r / Math.sin(this.camera.fov * Math.PI / 360) * 1.1) };
  }

  // Ease toward a preset's goal, keep the controls' speed per pixel; returns the three.js camera.
  update(dt) {
    this.controls.rotateSpeed = RAD_PER_PX * Math.max(1, this.canvas.clientHeight) / (2 * Math.PI);
    if (this.goal) {
      const k = 1 - Math.exp(-dt * 10), c = this.cur, g = this.goal;
      const step = (a, b) => a + (b - a) * k;
      const next = { az: step(c.az, g.az), el: step(c.el, g.el), dist: step(c.dist, g.dist), target: c.target.map((v, i) => step(v, g.target[i])) };
      const done = Math.abs(g.az - next.az) < 1e-4 && Math.abs(g.el - next.el) < 1e-4 && Math.abs(g.dist - next.dist) < 1e-4;
      this._place(done ? g : next);
      if (done) this.goal = null;
    }
    this.camera.updateMatrixWorld();
    this.viewProj.multiplyMatrices(this.camera.projectionMatrix, this.camera.matrixWorldInverse);
    return this.camera;
  }
}
