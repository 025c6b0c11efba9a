// The stage drawn by three.js: background, floor grid, lights, instanced solids, the video panel.
// Every marker, joint, bone and body of a frame is an instance of a unit mesh (sphere, cylinder,
// box) with its own matrix and colour: one draw call per mesh kind. The world keeps our axes (Z up,
// X forward); colours pass through unconverted (the legend's and the tests' references).

import * as THREE from "three";

THREE.ColorManagement.enabled = false;

const FLOOR_VS = `varying vec3 vWorld;
void main() { vec4 w = modelMatrix * vec4(position, 1.0); vWorld = w.xyz; gl_Position = projectionMatrix * viewMatrix * w; }`;

const FLOOR_FS = `varying vec3 vWorld;
float grid(vec2 p, float step, float width) {
  vec2 g = abs(fract(p / step - 0.5) - 0.5) / fwidth(p / step);
  return 1.0 - min(min(g.x, g.y) / width, 1.0);
}
void main() {
  vec2 p = vWorld.xy;
  float fade = 1.0 - smoothstep(6.0, 16.0, length(p));
  float minor = grid(p, 0.5, 1.0) * 0.22;
  float major = grid(p, 1.0, 1.2) * 0.45;
  float stage = 1.0 - smoothstep(3.8, 4.05, max(abs(p.x), abs(p.y)));
  vec3 floorCol = mix(vec3(0.10, 0.115, 0.14), vec3(0.15, 0.17, 0.205), stage);
  gl_FragColor = vec4(floorCol + vec3(0.55, 0.62, 0.72) * max(minor, major), 0.96 * fade);
}`;

function softwareRenderer() {
  const probe = document.createElement("canvas").getContext("webgl2");
  if (!probe) return false;
  const dbg = probe.getExtension("WEBGL_debug_renderer_info");
  const name = String(probe.getParameter(dbg ? dbg.UNMASKED_RENDERER_WEBGL : probe.RENDERER));
  const lose = probe.getExtension("WEBGL_lose_context");
  if (lose) lose.loseContext();
  return /swiftshader|llvmpipe|software/i.test(name);
}

// The sky: one triangle covering the screen, behind everything (cheaper than a background texture).
function background() {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.BufferAttribute(new Float32Array([-1, -1, 0, 3, -1, 0, -1, 3, 0]), 3));
  const material = new THREE.ShaderMaterial({
    vertexShader: "varying float vY; void main() { vY = position.y * 0.5 + 0.5; gl_Position = vec4(position.xy, 0.9999, 1.0); }",
    fragmentShader: `varying float vY;
      void main() { gl_FragColor = vec4(mix(vec3(0.13, 0.15, 0.19), vec3(0.055, 0.07, 0.10), clamp(vY, 0.0, 1.0)), 1.0); }`,
    depthWrite: false, depthTest: false });
  const sky = new THREE.Mesh(geometry, material);
  sky.frustumCulled = false;
  sky.renderOrder = -2;
  return sky;
}

// Unit solids: sphere of radius 1, cylinder of radius 1 from z = 0 to z = 1, box [-1, 1]^3.
function unitGeometries() {
  const cylinder = new THREE.CylinderGeometry(1, 1, 1, 16);
  cylinder.rotateX(Math.PI / 2).translate(0, 0, 0.5);
  return { sphere: new THREE.SphereGeometry(1, 18, 12), cylinder, box: new THREE.BoxGeometry(2, 2, 2) };
}

// One mesh kind's instances, grown by doubling; fed from a scene.js Batch each frame.
class Instanced {
  constructor(scene, geometry, material) {
    this.scene = scene; this.geometry = geometry; this.material = material; this.mesh = null; this.capacity = 0;
  }

  set(batch) {
    const n = batch.count;
    if (n > this.capacity) {
      if (this.mesh) { this.scene.remove(this.mesh); this.mesh.dispose(); }
      this.capacity = Math.max(256, 2 ** Math.ceil(Math.log2(n)));
      this.mesh = new THREE.InstancedMesh(this.geometry, this.material, this.capacity);
      this.mesh.instanceMatrix.setUsage(THREE.DynamicDrawUsage);
      this.mesh.instanceColor = new THREE.InstancedBufferAttribute(new Float32Array(3 * this.capacity), 3);
      this.mesh.instanceColor.setUsage(THREE.DynamicDrawUsage);
      this.mesh.frustumCulled = false;
      this.scene.add(this.mesh);
    }
    if (!this.mesh) return;
    this.mesh.count = n;
    for (const [attr, src, k] of [[this.mesh.instanceMatrix, batch.matrices, 16], [this.mesh.instanceColor, batch.colours, 3]]) {
      attr.array.set(src.subarray(0, n * k));
      attr.clearUpdateRanges();
      attr.addUpdateRange(0, n * k);
      attr.needsUpdate = true;
    }
  }
}

export class Stage {
  constructor(canvas) {
    // Multisampling costs a software renderer (SwiftShader, llvmpipe) half its frame rate: off there.
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: !softwareRenderer(), alpha: false });
    this.renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    const gl = this.renderer.getContext();
    const dbg = gl.getExtension("WEBGL_debug_renderer_info");
    this.rendererName = String(gl.getParameter(dbg ? dbg.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
    this.canvas = canvas;
    const scene = this.scene = new THREE.Scene();
    scene.add(background());
    // white lights only: shading scales a colour, never changes its hue
    scene.add(new THREE.AmbientLight(0xffffff, 1.25));
    const key = new THREE.DirectionalLight(0xffffff, 1.6);
    key.position.set(0.4, 0.3, 0.85);
    scene.add(key);
    const floor = new THREE.Mesh(new THREE.PlaneGeometry(40, 40), new THREE.ShaderMaterial({
      vertexShader: FLOOR_VS, fragmentShader: FLOOR_FS, transparent: true, depthWrite: false, side: THREE.DoubleSide }));
    floor.renderOrder = -1;
    scene.add(floor);
    const solid = new THREE.MeshLambertMaterial({ color: 0xffffff });
    const geoms = unitGeometries();
    this.kinds = Object.fromEntries(Object.entries(geoms).map(([k, g]) => [k, new Instanced(scene, g, solid)]));
    this.avatarRoot = new THREE.Group();
    scene.add(this.avatarRoot);
    this._panel();
  }

  _panel() {
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.BufferAttribute(new Float32Array(12), 3));
    geometry.setAttribute("uv", new THREE.BufferAttribute(new Float32Array([0, 0, 1, 0, 1, 1, 0, 1]), 2));
    geometry.setIndex([0, 1, 2, 0, 2, 3]);
    this.panelMaterial = new THREE.MeshBasicMaterial({ side: THREE.DoubleSide });
    this.panel = new THREE.Mesh(geometry, this.panelMaterial);
    this.panel.frustumCulled = false;
    this.scene.add(this.panel);
    this.texture = null;
  }

  // An image, canvas or video as the video panel's picture (a new texture when its source or size changes).
  uploadTexture(source) {
    const w = source.videoWidth || source.width, h = source.videoHeight || source.height;
    // three sizes a texture by the element's width/height: a video's are 0 unless set
    if (source.videoWidth && (source.width !== w || source.height !== h)) { source.width = w; source.height = h; }
    const t = this.texture;
    if (!t || t.image !== source || t.userData.w !== w || t.userData.h !== h) {
      if (t) t.dispose();
      this.texture = new THREE.Texture(source);
      this.texture.minFilter = THREE.LinearFilter;
      this.texture.generateMipmaps = false;
      this.texture.userData = { w, h };
      this.panelMaterial.map = this.texture;
      this.panelMaterial.needsUpdate = true;
    }
    this.texture.needsUpdate = true;
  }

  resize(camera) {
    const w = Math.max(1, this.canvas.clientWidth), h = Math.max(1, this.canvas.clientHeight);
    const size = this.renderer.getSize(new THREE.Vector2());
    if (size.x !== w || size.y !== h) this.renderer.setSize(w, h, false);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
  }

  // Draw one frame: batches {sphere, cylinder, box} of instances; panel {corners: [bl, br, tr, tl], dim} or null.
  draw(camera, batches, panel) {
    for (const [kind, inst] of Object.entries(this.kinds)) inst.set(batches[kind]);
    this.panel.visible = !!panel;
    if (panel) {
      const pos = this.panel.geometry.attributes.position;
      panel.corners.forEach((c, i) => pos.setXYZ(i, c[0], c[1], c[2]));
      pos.needsUpdate = true;
      this.panelMaterial.color.setScalar(panel.dim);
    }
    this.renderer.render(this.scene, camera);
  }
}
