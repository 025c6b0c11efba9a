// Orbit camera around a target point, Z up: drag to orbit, right-drag or shift-drag to pan, wheel to
// zoom, preset views (front looks at the performer's face: the world's X is forward).

import { lookAt, multiply, perspective } from "./math.js";

export const PRESETS = {
  front: { az: 0, el: 0.12 },
  side: { az: Math.PI / 2, el: 0.12 },
  top: { az: 0, el: Math.PI / 2 - 0.001 },
  perspective: { az: 0.62, el: 0.36 },
};

export class OrbitCamera {
  constructor(canvas) {
    this.canvas = canvas;
    this.home = { dist: 7.2, target: [-0.5, 0, 0.85] };
    this.goal = { az: PRESETS.perspective.az, el: PRESETS.perspective.el, dist: this.home.dist, target: [...this.home.target] };
    this.cur = { ...this.goal, target: [...this.goal.target] };
    this.fovy = 45 * Math.PI / 180;
    this.drag = null;
    canvas.addEventListener("pointerdown", (e) => this.onDown(e));
    canvas.addEventListener("pointermove", (e) => this.onMove(e));
    canvas.addEventListener("pointerup", (e) => this.onUp(e));
    canvas.addEventListener("pointercancel", (e) => this.onUp(e));
    canvas.addEventListener("wheel", (e) => this.onWheel(e), { passive: false });
    canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  }

  onDown(e) {
    this.canvas.setPointerCapture(e.pointerId);
    this.drag = { x: e.clientX, y: e.clientY, pan: e.button !== 0 || e.shiftKey };
  }

  onMove(e) {
    if (!this.drag) return;
    const dx = e.clientX - this.drag.x, dy = e.clientY - this.drag.y;
    this.drag.x = e.clientX; this.drag.y = e.clientY;
    if (this.drag.pan) this.pan(dx, dy);
    else this.orbit(dx, dy);
  }

  onUp(e) {
    this.drag = null;
    if (this.canvas.hasPointerCapture(e.pointerId)) this.canvas.releasePointerCapture(e.pointerId);
  }

  onWheel(e) {
    e.preventDefault();
    this.zoom(Math.exp(e.deltaY * 0.0012));
  }

  orbit(dx, dy) {
    this.goal.az -= dx * 0.006;
    this.goal.el = Math.max(-0.2, Math.min(Math.PI / 2 - 0.001, this.goal.el + dy * 0.006));
    this.snap();
  }

  pan(dx, dy) {
    const g = this.goal;
    const k = g.dist * Math.tan(this.fovy / 2) * 2 / Math.max(1, this.canvas.clientHeight);
    const right = [-Math.sin(g.az), Math.cos(g.az), 0];
    const up = [-Math.sin(g.el) * Math.cos(g.az), -Math.sin(g.el) * Math.sin(g.az), Math.cos(g.el)];
    for (let i = 0; i < 3; i++) g.target[i] += (-dx * right[i] + dy * up[i]) * k;
    this.snap();
  }

  zoom(factor) {
    this.goal.dist = Math.max(0.3, Math.min(80, this.goal.dist * factor));
    this.snap();
  }

  // Direct manipulation follows the pointer without easing.
  snap() { this.cur = { ...this.goal, target: [...this.goal.target] }; }

  preset(name, bounds) {
    const p = PRESETS[name];
    this.goal.az = p.az;
    this.goal.el = p.el;
    if (bounds) this.fit(bounds);
    else if (name === "perspective") { this.goal.dist = this.home.dist; this.goal.target = [...this.home.target]; }
    // Turn the short way round.
    while (this.goal.az - this.cur.az > Math.PI) this.cur.az += 2 * Math.PI;
    while (this.cur.az - this.goal.az > Math.PI) this.cur.az -= 2 * Math.PI;
  }

  fit(b) {
    const c = [(b[0] + b[3]) / 2, (b[1] + b[4]) / 2, (b[2] + b[5]) / 2];
    const r = Math.max(0.8, Math.hypot(b[3] - b[0], b[4] - b[1], b[5] - b[2]) / 2);
    this.goal.target = c;
    this.goal.dist = Math.min(40, r / Math.sin(this.fovy / 2) * 1.1);
  }

  // Ease toward the goal; returns {viewProj, eye}.
  update(dt, aspect) {
    const k = 1 - Math.exp(-dt * 10);
    const c = this.cur, g = this.goal;
    c.az += (g.az - c.az) * k;
    c.el += (g.el - c.el) * k;
    c.dist += (g.dist - c.dist) * k;
    for (let i = 0; i < 3; i++) c.target[i] += (g.target[i] - c.target[i]) * k;
    const eye = [
      c.target[0] + c.dist * Math.cos(c.el) * Math.cos(c.az),
      c.target[1] + c.dist * Math.cos(c.el) * Math.sin(c.az),
      c.target[2] + c.dist * Math.sin(c.el),
    ];
    // Looking straight down, "up" on screen is the world's -X so that front stays at the bottom.
    const up = c.el > 1.5 ? [-Math.cos(c.az), -Math.sin(c.az), 0] : [0, 0, 1];
    const view = lookAt(eye, c.target, up);
    const proj = perspective(this.fovy, aspect, 0.05, 200);
    return { viewProj: multiply(proj, view), eye };
  }
}
