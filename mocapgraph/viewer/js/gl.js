// Plain WebGL2 renderer of the stage: background, floor grid, instanced meshes, a video quad.
// Every solid is an instance of a unit mesh (sphere, cylinder, box) with its own model matrix and
// colour, so one draw call per mesh kind draws every marker, joint, bone and body of a frame.

const FLOATS_PER_INSTANCE = 20; // mat4 + rgba

const MESH_VS = `#version 300 es
layout(location=0) in vec3 aPos;
layout(location=1) in vec3 aNormal;
layout(location=2) in vec4 aM0;
layout(location=3) in vec4 aM1;
layout(location=4) in vec4 aM2;
layout(location=5) in vec4 aM3;
layout(location=6) in vec4 aColor;
uniform mat4 uViewProj;
out vec3 vNormal;
out vec4 vColor;
out vec3 vWorld;
void main() {
  mat4 m = mat4(aM0, aM1, aM2, aM3);
  vec4 w = m * vec4(aPos, 1.0);
  mat3 nm = transpose(inverse(mat3(m)));
  vNormal = normalize(nm * aNormal);
  vColor = aColor;
  vWorld = w.xyz;
  gl_Position = uViewProj * w;
}`;

const MESH_FS = `#version 300 es
precision highp float;
in vec3 vNormal;
in vec4 vColor;
in vec3 vWorld;
uniform vec3 uEye;
out vec4 outColor;
void main() {
  vec3 n = normalize(vNormal);
  vec3 v = normalize(uEye - vWorld);
  if (dot(n, v) < 0.0) n = -n;
  vec3 key = normalize(vec3(0.4, 0.3, 0.85));
  float hemi = 0.5 + 0.5 * n.z;
  vec3 base = vColor.rgb;
  vec3 col = base * (0.38 + 0.22 * hemi) + base * 0.55 * max(dot(n, key), 0.0);
  float rim = pow(1.0 - max(dot(n, v), 0.0), 3.0);
  col += 0.25 * rim * base + 0.12 * pow(max(dot(reflect(-key, n), v), 0.0), 24.0);
  outColor = vec4(col, vColor.a);
}`;

const BG_VS = `#version 300 es
out vec2 vUv;
void main() {
  vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  vUv = p;
  gl_Position = vec4(p * 2.0 - 1.0, 0.999, 1.0);
}`;

const BG_FS = `#version 300 es
precision mediump float;
in vec2 vUv;
out vec4 outColor;
void main() {
  vec3 top = vec3(0.055, 0.07, 0.10), bottom = vec3(0.13, 0.15, 0.19);
  outColor = vec4(mix(bottom, top, clamp(vUv.y, 0.0, 1.0)), 1.0);
}`;

const FLOOR_VS = `#version 300 es
layout(location=0) in vec3 aPos;
uniform mat4 uViewProj;
out vec3 vWorld;
void main() { vWorld = aPos; gl_Position = uViewProj * vec4(aPos, 1.0); }`;

const FLOOR_FS = `#version 300 es
precision highp float;
in vec3 vWorld;
uniform vec3 uEye;
out vec4 outColor;
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
  vec3 col = floorCol + vec3(0.55, 0.62, 0.72) * max(minor, major);
  outColor = vec4(col, 0.96 * fade);
}`;

const QUAD_VS = `#version 300 es
layout(location=0) in vec3 aPos;
layout(location=1) in vec2 aUv;
uniform mat4 uViewProj;
out vec2 vUv;
void main() { vUv = aUv; gl_Position = uViewProj * vec4(aPos, 1.0); }`;

const QUAD_FS = `#version 300 es
precision mediump float;
in vec2 vUv;
uniform sampler2D uTex;
uniform float uDim;
out vec4 outColor;
void main() { outColor = vec4(texture(uTex, vUv).rgb * uDim, 1.0); }`;

function compile(gl, vsText, fsText) {
  const prog = gl.createProgram();
  for (const [type, text] of [[gl.VERTEX_SHADER, vsText], [gl.FRAGMENT_SHADER, fsText]]) {
    const sh = gl.createShader(type);
    gl.shaderSource(sh, text);
    gl.compileShader(sh);
    if (!gl.getShaderParameter(sh, gl.COMPILE_STATUS)) throw new Error("shader: " + gl.getShaderInfoLog(sh));
    gl.attachShader(prog, sh);
  }
  gl.linkProgram(prog);
  if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error("program: " + gl.getProgramInfoLog(prog));
  const uniforms = {};
  const n = gl.getProgramParameter(prog, gl.ACTIVE_UNIFORMS);
  for (let i = 0; i < n; i++) {
    const u = gl.getActiveUniform(prog, i);
    uniforms[u.name] = gl.getUniformLocation(prog, u.name);
  }
  return { prog, uniforms };
}

function sphereMesh(seg = 18, rings = 12) {
  const pos = [], idx = [];
  for (let r = 0; r <= rings; r++) {
    const th = Math.PI * r / rings;
    for (let s = 0; s <= seg; s++) {
      const ph = 2 * Math.PI * s / seg;
      pos.push(Math.sin(th) * Math.cos(ph), Math.sin(th) * Math.sin(ph), Math.cos(th));
    }
  }
  for (let r = 0; r < rings; r++) {
    for (let s = 0; s < seg; s++) {
      const a = r * (seg + 1) + s, b = a + seg + 1;
      idx.push(a, b, a + 1, a + 1, b, b + 1);
    }
  }
  return { pos, normal: pos.slice(), idx };
}

// Unit cylinder: radius 1, from z = 0 to z = 1, with caps.
function cylinderMesh(seg = 16) {
  const pos = [], normal = [], idx = [];
  for (let s = 0; s <= seg; s++) {
    const a = 2 * Math.PI * s / seg, c = Math.cos(a), si = Math.sin(a);
    pos.push(c, si, 0, c, si, 1);
    normal.push(c, si, 0, c, si, 0);
  }
  for (let s = 0; s < seg; s++) {
    const a = 2 * s;
    idx.push(a, a + 2, a + 1, a + 1, a + 2, a + 3);
  }
  for (const z of [0, 1]) {
    const centre = pos.length / 3;
    pos.push(0, 0, z); normal.push(0, 0, z ? 1 : -1);
    for (let s = 0; s <= seg; s++) {
      const a = 2 * Math.PI * s / seg;
      pos.push(Math.cos(a), Math.sin(a), z); normal.push(0, 0, z ? 1 : -1);
    }
    for (let s = 0; s < seg; s++) idx.push(centre, centre + 1 + s, centre + 2 + s);
  }
  return { pos, normal, idx };
}

// Unit box: [-1, 1]^3 (so that MuJoCo half-sizes are the scale).
function boxMesh() {
  const pos = [], normal = [], idx = [];
  const faces = [[0, 1], [0, -1], [1, 1], [1, -1], [2, 1], [2, -1]];
  for (const [axis, sign] of faces) {
    const u = (axis + 1) % 3, v = (axis + 2) % 3, base = pos.length / 3;
    for (const [a, b] of [[-1, -1], [1, -1], [1, 1], [-1, 1]]) {
      const p = [0, 0, 0]; p[axis] = sign; p[u] = a; p[v] = b;
      const n = [0, 0, 0]; n[axis] = sign;
      pos.push(...p); normal.push(...n);
    }
    idx.push(base, base + 1, base + 2, base, base + 2, base + 3);
  }
  return { pos, normal, idx };
}

function softwareRenderer() {
  const probe = document.createElement("canvas").getContext("webgl2");
  if (!probe) return false;
  const dbg = probe.getExtension("WEBGL_debug_renderer_info");
  const name = String(probe.getParameter(dbg ? dbg.UNMASKED_RENDERER_WEBGL : probe.RENDERER));
  const lose = probe.getExtension("WEBGL_lose_context");
  if (lose) lose.loseContext();
  return /swiftshader|llvmpipe|software/i.test(name);
}

export class Renderer {
  constructor(canvas) {
    // Multisampling costs a software renderer (SwiftShader, llvmpipe) half its frame rate: off there.
    const gl = canvas.getContext("webgl2", { antialias: !softwareRenderer(), alpha: false });
    if (!gl) throw new Error("WebGL2 is not available in this browser");
    this.gl = gl;
    this.canvas = canvas;
    this.meshProg = compile(gl, MESH_VS, MESH_FS);
    this.bgProg = compile(gl, BG_VS, BG_FS);
    this.floorProg = compile(gl, FLOOR_VS, FLOOR_FS);
    this.quadProg = compile(gl, QUAD_VS, QUAD_FS);
    this.meshes = { sphere: this._mesh(sphereMesh()), cylinder: this._mesh(cylinderMesh()), box: this._mesh(boxMesh()) };
    this.bgVao = gl.createVertexArray();
    this.floor = this._floor(20);
    this.quad = this._quad();
    this.texture = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, this.texture);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, true);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, 1, 1, 0, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array([20, 24, 30, 255]));
    const dbg = gl.getExtension("WEBGL_debug_renderer_info");
    this.rendererName = gl.getParameter(dbg ? dbg.UNMASKED_RENDERER_WEBGL : gl.RENDERER);
  }

  _mesh({ pos, normal, idx }) {
    const gl = this.gl;
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const vb = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, vb);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(pos), gl.STATIC_DRAW);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 0, 0);
    const nb = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, nb);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(normal), gl.STATIC_DRAW);
    gl.enableVertexAttribArray(1);
    gl.vertexAttribPointer(1, 3, gl.FLOAT, false, 0, 0);
    const ib = gl.createBuffer();
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ib);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, new Uint16Array(idx), gl.STATIC_DRAW);
    const inst = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, inst);
    const stride = FLOATS_PER_INSTANCE * 4;
    for (let i = 0; i < 5; i++) {
      gl.enableVertexAttribArray(2 + i);
      gl.vertexAttribPointer(2 + i, 4, gl.FLOAT, false, stride, i * 16);
      gl.vertexAttribDivisor(2 + i, 1);
    }
    gl.bindVertexArray(null);
    return { vao, inst, count: idx.length, capacity: 0 };
  }

  _floor(half) {
    const gl = this.gl;
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const b = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, b);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-half, -half, 0, half, -half, 0, half, half, 0,
      -half, -half, 0, half, half, 0, -half, half, 0]), gl.STATIC_DRAW);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 0, 0);
    gl.bindVertexArray(null);
    return vao;
  }

  _quad() {
    const gl = this.gl;
    const vao = gl.createVertexArray();
    gl.bindVertexArray(vao);
    const buf = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, buf);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(30), gl.DYNAMIC_DRAW);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 3, gl.FLOAT, false, 20, 0);
    gl.enableVertexAttribArray(1);
    gl.vertexAttribPointer(1, 2, gl.FLOAT, false, 20, 12);
    gl.bindVertexArray(null);
    return { vao, buf };
  }

  // Upload an image/video/canvas as the video panel's texture.
  uploadTexture(source) {
    const gl = this.gl;
    gl.bindTexture(gl.TEXTURE_2D, this.texture);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, gl.RGBA, gl.UNSIGNED_BYTE, source);
  }

  resize() {
    const dpr = Math.min(window.devicePixelRatio || 1, 2);
    const w = Math.max(1, Math.round(this.canvas.clientWidth * dpr));
    const h = Math.max(1, Math.round(this.canvas.clientHeight * dpr));
    if (this.canvas.width !== w || this.canvas.height !== h) {
      this.canvas.width = w;
      this.canvas.height = h;
    }
    return [w, h];
  }

  // Draw one frame. batches: {sphere: Float32Array, cylinder: ..., box: ...} of instances;
  // panel: {corners: [bl, br, tr, tl] world points, dim} or null.
  draw(viewProj, eye, batches, panel) {
    const gl = this.gl;
    const [w, h] = this.resize();
    gl.viewport(0, 0, w, h);
    gl.clearColor(0.08, 0.09, 0.12, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.disable(gl.DEPTH_TEST);
    gl.useProgram(this.bgProg.prog);
    gl.bindVertexArray(this.bgVao);
    gl.drawArrays(gl.TRIANGLES, 0, 3);

    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.LEQUAL);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
    gl.useProgram(this.floorProg.prog);
    gl.uniformMatrix4fv(this.floorProg.uniforms.uViewProj, false, viewProj);
    gl.uniform3fv(this.floorProg.uniforms.uEye, eye);
    gl.bindVertexArray(this.floor);
    gl.depthMask(false);
    gl.drawArrays(gl.TRIANGLES, 0, 6);
    gl.depthMask(true);
    gl.disable(gl.BLEND);

    if (panel) {
      const [bl, br, tr, tl] = panel.corners;
      const data = new Float32Array([...bl, 0, 0, ...br, 1, 0, ...tr, 1, 1, ...bl, 0, 0, ...tr, 1, 1, ...tl, 0, 1]);
      gl.useProgram(this.quadProg.prog);
      gl.uniformMatrix4fv(this.quadProg.uniforms.uViewProj, false, viewProj);
      gl.uniform1f(this.quadProg.uniforms.uDim, panel.dim);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, this.texture);
      gl.uniform1i(this.quadProg.uniforms.uTex, 0);
      gl.bindVertexArray(this.quad.vao);
      gl.bindBuffer(gl.ARRAY_BUFFER, this.quad.buf);
      gl.bufferSubData(gl.ARRAY_BUFFER, 0, data);
      gl.drawArrays(gl.TRIANGLES, 0, 6);
    }

    gl.useProgram(this.meshProg.prog);
    gl.uniformMatrix4fv(this.meshProg.uniforms.uViewProj, false, viewProj);
    gl.uniform3fv(this.meshProg.uniforms.uEye, eye);
    for (const [kind, batch] of Object.entries(batches)) {
      const n = batch.count;
      if (!n) continue;
      const mesh = this.meshes[kind];
      gl.bindVertexArray(mesh.vao);
      gl.bindBuffer(gl.ARRAY_BUFFER, mesh.inst);
      const bytes = n * FLOATS_PER_INSTANCE * 4;
      if (mesh.capacity < bytes) {
        mesh.capacity = Math.max(bytes, 2 * mesh.capacity);
        gl.bufferData(gl.ARRAY_BUFFER, mesh.capacity, gl.DYNAMIC_DRAW);
      }
      gl.bufferSubData(gl.ARRAY_BUFFER, 0, batch.data, 0, n * FLOATS_PER_INSTANCE);
      gl.drawElementsInstanced(gl.TRIANGLES, mesh.count, gl.UNSIGNED_SHORT, 0, n);
    }
    gl.bindVertexArray(null);
  }
}

// A growable list of instances (model matrix + colour) for one mesh kind.
export class Batch {
  constructor() { this.data = new Float32Array(FLOATS_PER_INSTANCE * 256); this.count = 0; }
  clear() { this.count = 0; }
  // Returns the float offset where the caller writes a mat4, and stores the colour.
  add(r, g, b, a = 1) {
    if ((this.count + 1) * FLOATS_PER_INSTANCE > this.data.length) {
      const bigger = new Float32Array(this.data.length * 2);
      bigger.set(this.data);
      this.data = bigger;
    }
    const o = this.count * FLOATS_PER_INSTANCE;
    this.data[o + 16] = r; this.data[o + 17] = g; this.data[o + 18] = b; this.data[o + 19] = a;
    this.count++;
    return o;
  }
}
