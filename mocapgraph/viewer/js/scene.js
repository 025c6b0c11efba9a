// What the stage draws from the streams: each drawable type is drawn from its fields (positions,
// quality arrays, parents from its latched companion), never from per-type special geometry.

// A growable list of instances of one mesh kind: a model matrix (column-major) and a colour each.
export class Batch {
  constructor() { this.matrices = new Float32Array(16 * 256); this.colours = new Float32Array(3 * 256); this.count = 0; }
  clear() { this.count = 0; }
  // Stores the colour; returns the offset in `matrices` where the caller writes the matrix.
  add(r, g, b) {
    if (16 * (this.count + 1) > this.matrices.length) {
      for (const k of ["matrices", "colours"]) { const a = new Float32Array(this[k].length * 2); a.set(this[k]); this[k] = a; }
    }
    const c = 3 * this.count;
    this.colours[c] = r; this.colours[c + 1] = g; this.colours[c + 2] = b;
    return 16 * this.count++;
  }
}

// Rotation matrix columns of a unit quaternion (w, x, y, z).
function quatColumns(w, x, y, z) {
  const n = Math.hypot(w, x, y, z);
  if (!(n > 0)) return [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
  w /= n; x /= n; y /= n; z /= n;
  return [
    [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)],
    [2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)],
    [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)],
  ];
}

// Write a model matrix with the given columns (3-vectors, already scaled) and translation.
function writeMat(out, o, cx, cy, cz, t) {
  out.set([cx[0], cx[1], cx[2], 0, cy[0], cy[1], cy[2], 0, cz[0], cz[1], cz[2], 0, t[0], t[1], t[2], 1], o);
}

export const GOOD = [0.30, 0.86, 0.46];
export const ESTIMATED = [0.98, 0.70, 0.22];
export const MISSING = [1.0, 0.33, 0.33];
const MARKER_SEEN = [0.55, 1.0, 0.62];
const CHARACTER = [[0.64, 0.52, 1.0], [0.35, 0.72, 1.0], [1.0, 0.55, 0.85]];
const BODY_UNTRACKED = [0.58, 0.63, 0.72];
const REFERENCE = [0.86, 0.89, 0.96];

// Types drawn on the stage, and the types that feed the drawing or the panel without being drawn.
export const DRAWN_TYPES = new Set(["MarkerFrame", "ActorPose", "SkeletonPose", "CharacterPose", "PhysicsState"]);
export const SUPPORT_TYPES = new Set(["MarkerLayout", "SkeletonModel", "SkeletonInfo", "CharacterInfo", "PhysicsScene",
  "Diagnostics", "NodeStatus", "NodeCommand"]);
const STALE_MS = 3000;
const BESIDE = [0, -0.9, 0];   // m: where physics bodies go when shown beside (not over) the avatars

export function qualityColor(q) {
  return q >= 2 ? GOOD : q === 1 ? ESTIMATED : MISSING;
}

function finite3(a, i) {
  return Number.isFinite(a[3 * i]) && Number.isFinite(a[3 * i + 1]) && Number.isFinite(a[3 * i + 2]);
}

export class SceneBuilder {
  constructor() {
    this.batches = { sphere: new Batch(), cylinder: new Batch(), box: new Batch() };
    this.hidden = new Set(); // stream keys switched off in the panel
    this.show = { markers: true, bones: true, labels: true, axes: true, characters: true, avatars: true, bodiesBeside: false };
    this.avatars = null;     // avatar.js Avatars: characters drawn as skinned meshes (else as bones)
    this.poses = {};         // stream key -> the CharacterPose record drawn last (tests project its joints)
    this.referenceTopics = new Set(); // drawn as a thin neutral ghost (ground truth), not by quality
  }

  sphere(p, r, c, dim = 1) {
    const o = this.batches.sphere.add(c[0] * dim, c[1] * dim, c[2] * dim);
    writeMat(this.batches.sphere.matrices, o, [r, 0, 0], [0, r, 0], [0, 0, r], p);
  }

  bone(a, b, r, c, dim = 1) {
    const d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    const len = Math.hypot(d[0], d[1], d[2]);
    if (!(len > 1e-6)) return;
    const z = [d[0] / len, d[1] / len, d[2] / len];
    const up = Math.abs(z[2]) < 0.95 ? [0, 0, 1] : [1, 0, 0];
    let x = [up[1] * z[2] - up[2] * z[1], up[2] * z[0] - up[0] * z[2], up[0] * z[1] - up[1] * z[0]];
    const lx = Math.hypot(x[0], x[1], x[2]);
    x = [x[0] / lx, x[1] / lx, x[2] / lx];
    const y = [z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0]];
    const o = this.batches.cylinder.add(c[0] * dim, c[1] * dim, c[2] * dim);
    writeMat(this.batches.cylinder.matrices, o, [x[0] * r, x[1] * r, x[2] * r], [y[0] * r, y[1] * r, y[2] * r], d, a);
  }

  // Build every batch for one frame. Returns per-stream draw records, labels and totals.
  build(store, nowMs, stage) {
    for (const b of Object.values(this.batches)) b.clear();
    if (this.avatars) this.avatars.begin();
    const out = { streams: {}, labels: [], totals: { markersDrawn: 0, markersTotal: 0, jointsDrawn: 0, bonesDrawn: 0,
      skeletonJointsDrawn: 0, characterJointsDrawn: 0, referenceJointsDrawn: 0, bodiesDrawn: 0, actorsDrawn: 0 },
      bounds: null };
    this.bounds = [Infinity, Infinity, Infinity, -Infinity, -Infinity, -Infinity];
    this._stage(stage);
    for (const s of store.streams.values()) {
      if (!DRAWN_TYPES.has(s.type)) continue;
      const visible = !this.hidden.has(s.key);
      const dim = nowMs - s.receivedMs > STALE_MS ? 0.4 : 1;
      const rec = { topic: s.topic, type: s.type, name: streamName(s), visible, points: 0, bones: 0,
        frame: s.fields.frame_number ?? null, seq: s.seq, stale: dim < 1, reference: this.referenceTopics.has(s.topic) };
      out.streams[s.key] = rec;
      if (!visible) continue;
      if (s.type === "MarkerFrame") this._markers(s, rec, dim, out);
      else if (rec.reference && s.arrays.joint_positions) this._skeleton(s, rec, dim, out,
        companion(store, s, s.type === "ActorPose" ? "SkeletonModel" : s.type === "SkeletonPose" ? "SkeletonInfo" : "CharacterInfo"),
        null, 0.02, "referenceJointsDrawn", REFERENCE);
      else if (s.type === "ActorPose") this._skeleton(s, rec, dim, out, companion(store, s, "SkeletonModel"),
        s.arrays.joint_quality.data, 0.032, "jointsDrawn");
      else if (s.type === "SkeletonPose") this._skeleton(s, rec, dim, out, companion(store, s, "SkeletonInfo"),
        s.arrays.tracking_state.data, 0.028, "skeletonJointsDrawn");
      else if (s.type === "CharacterPose") { if (this.show.characters) this._character(s, rec, dim, out, companion(store, s, "CharacterInfo")); }
      else if (s.type === "PhysicsState") this._bodies(s, rec, dim, out, companion(store, s, "PhysicsScene"));
      out.totals.bonesDrawn += rec.bones;
    }
    if (this.avatars) this.avatars.end();
    if (this.bounds[0] <= this.bounds[3]) out.bounds = this.bounds;
    return out;
  }

  _grow(p) {
    const b = this.bounds;
    for (let k = 0; k < 3; k++) { b[k] = Math.min(b[k], p[k]); b[k + 3] = Math.max(b[k + 3], p[k]); }
  }

  _stage(stage) {
    if (this.show.axes) {
      const r = 0.009;
      this.bone([0, 0, 0], [0.6, 0, 0], r, [0.95, 0.3, 0.3]);
      this.bone([0, 0, 0], [0, 0.6, 0], r, [0.35, 0.9, 0.4]);
      this.bone([0, 0, 0], [0, 0, 0.6], r, [0.35, 0.55, 1.0]);
      this.sphere([0, 0, 0], 0.022, [0.9, 0.9, 0.9]);
    }
    if (stage.panel) {
      const [bl, br, tr, tl] = stage.panel.corners;
      const c = [0.22, 0.24, 0.28], r = 0.025;
      this.bone(bl, br, r, c); this.bone(br, tr, r, c); this.bone(tr, tl, r, c); this.bone(tl, bl, r, c);
      for (const p of [bl, br]) this.bone([p[0], p[1], 0], p, 0.03, c);
    }
  }

  _markers(s, rec, dim, out) {
    const pos = s.arrays.positions.data, valid = s.arrays.valid.data;
    const n = s.arrays.positions.shape[0];
    out.totals.markersTotal += n;
    rec.total = n;
    if (!this.show.markers) return;
    for (let i = 0; i < n; i++) {
      if (!finite3(pos, i)) continue;
      const p = [pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]];
      this.sphere(p, valid[i] ? 0.0135 : 0.017, valid[i] ? MARKER_SEEN : MISSING, dim);
      this._grow(p);
      rec.points++;
    }
    out.totals.markersDrawn += rec.points;
  }

  _skeleton(s, rec, dim, out, info, quality, radius, total, colour = null) {
    const pos = s.arrays.joint_positions.data;
    const n = s.arrays.joint_positions.shape[0];
    rec.total = n;
    const parent = info && info.arrays.joint_parent && info.arrays.joint_parent.shape[0] === n
      ? info.arrays.joint_parent.data : null;
    const tint = colour || (quality ? null : CHARACTER[hash(s.key) % CHARACTER.length]);
    let top = null;
    const counts = [0, 0, 0];
    for (let i = 0; i < n; i++) {
      if (!finite3(pos, i)) { counts[0]++; continue; }
      const p = [pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]];
      const q = quality ? quality[i] : 2;
      counts[Math.max(0, Math.min(2, q))]++;
      this.sphere(p, radius, tint || qualityColor(q), dim);
      this._grow(p);
      rec.points++;
      if (!top || p[2] > top[2]) top = p;
      if (parent && this.show.bones) {
        const j = parent[i];
        if (j >= 0 && j < n && finite3(pos, j)) {
          const a = [pos[3 * j], pos[3 * j + 1], pos[3 * j + 2]];
          const qb = quality ? Math.min(q, quality[j]) : 2;
          const c = tint || qualityColor(qb);
          this.bone(a, p, radius * (colour ? 0.3 : 0.42), [c[0] * 0.8, c[1] * 0.8, c[2] * 0.8], dim);
          rec.bones++;
        }
      }
    }
    if (quality) rec.quality = { good: counts[2], estimated: counts[1], missing: counts[0] };
    out.totals[total] += rec.points;
    out.totals.actorsDrawn++;
    // A reference's label sits higher, so that it never covers the label of the actor it shadows.
    const lift = rec.reference ? 0.5 : 0.28;
    const text = rec.name + (rec.reference ? " · reference" : "") + (rec.stale ? " (stale)" : "");
    if (top) out.labels.push({ key: s.key, text, pos: [top[0], top[1], top[2] + lift], reference: rec.reference });
  }

  // A retargeted character: solid bones in the character's own colour (one per character name),
  // joints the retargeter flags estimated or missing drawn in the quality colours.
  _character(s, rec, dim, out, info) {
    const pos = s.arrays.joint_positions.data;
    const n = s.arrays.joint_positions.shape[0];
    const quality = s.arrays.joint_quality ? s.arrays.joint_quality.data : null;
    rec.total = n;
    const parent = info && info.arrays.joint_parent && info.arrays.joint_parent.shape[0] === n
      ? info.arrays.joint_parent.data : null;
    const tint = CHARACTER[hash(s.fields.character || s.key) % CHARACTER.length];
    // the skinned avatar when its mesh is loaded (the avatar toggle off: bones); same counts either way
    rec.avatar = !!(this.show.avatars && this.avatars && info && this.avatars.drive(s, info, dim));
    this.poses[s.key] = s;
    const counts = [0, 0, 0];
    let top = null;
    for (let i = 0; i < n; i++) {
      if (!finite3(pos, i)) { counts[0]++; continue; }
      const p = [pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]];
      const q = quality ? quality[i] : 2;
      counts[Math.max(0, Math.min(2, q))]++;
      if (!rec.avatar) this.sphere(p, 0.026, q >= 2 ? tint : qualityColor(q), dim);
      this._grow(p);
      rec.points++;
      if (!top || p[2] > top[2]) top = p;
      const j = parent ? parent[i] : -1;
      if (j >= 0 && j < n && finite3(pos, j)) {
        const a = [pos[3 * j], pos[3 * j + 1], pos[3 * j + 2]];
        const qb = quality ? Math.min(q, quality[j]) : 2;
        if (!rec.avatar) this.bone(a, p, 0.021, qb >= 2 ? tint : qualityColor(qb), dim);   // solid: as thick as a limb
        rec.bones++;
      }
    }
    rec.quality = { good: counts[2], estimated: counts[1], missing: counts[0] };
    out.totals.characterJointsDrawn += rec.points;
    out.totals.actorsDrawn++;
    const text = rec.name + (rec.stale ? " (stale)" : "");
    if (top) out.labels.push({ key: s.key, text, pos: [top[0], top[1], top[2] + 0.28], reference: false });
  }

  _bodies(s, rec, dim, out, scene) {
    const pos = s.arrays.positions.data, quat = s.arrays.orientations.data, err = s.arrays.tracking_error.data;
    const n = s.arrays.positions.shape[0];
    rec.total = n;
    const shapes = scene && scene.fields.shapes.length === n ? scene.fields.shapes : null;
    const sizes = shapes ? scene.arrays.sizes.data : null;
    rec.shapes = {};       // drawn bodies per shape, and how many are coloured by a tracking error
    rec.tracked = 0;
    const side = this.show.bodiesBeside ? BESIDE : [0, 0, 0];   // over the avatar, or beside it
    for (let i = 0; i < n; i++) {
      if (!finite3(pos, i)) continue;
      const p = [pos[3 * i] + side[0], pos[3 * i + 1] + side[1], pos[3 * i + 2] + side[2]];
      const R = quatColumns(quat[4 * i], quat[4 * i + 1], quat[4 * i + 2], quat[4 * i + 3]);
      const shape = shapes ? shapes[i] : "box";
      const sz = sizes ? [sizes[3 * i], sizes[3 * i + 1], sizes[3 * i + 2]] : [0.05, 0.05, 0.05];
      const c = errorColor(err[i]);
      const sc = (v, k) => [v[0] * k, v[1] * k, v[2] * k];
      if (shape === "sphere") {
        const o = this.batches.sphere.add(c[0] * dim, c[1] * dim, c[2] * dim);
        writeMat(this.batches.sphere.matrices, o, sc(R[0], sz[0]), sc(R[1], sz[0]), sc(R[2], sz[0]), p);
      } else if (shape === "capsule" || shape === "cylinder") {
        const r = sz[0], h = sz[1];
        const base = [p[0] - R[2][0] * h, p[1] - R[2][1] * h, p[2] - R[2][2] * h];
        const o = this.batches.cylinder.add(c[0] * dim, c[1] * dim, c[2] * dim);
        writeMat(this.batches.cylinder.matrices, o, sc(R[0], r), sc(R[1], r), sc(R[2], 2 * h), base);
        if (shape === "capsule") {
          this.sphere(base, r, c, dim);
          this.sphere([p[0] + R[2][0] * h, p[1] + R[2][1] * h, p[2] + R[2][2] * h], r, c, dim);
        }
      } else {
        const o = this.batches.box.add(c[0] * dim, c[1] * dim, c[2] * dim);
        writeMat(this.batches.box.matrices, o, sc(R[0], sz[0]), sc(R[1], sz[1] || sz[0]), sc(R[2], sz[2] || sz[0]), p);
      }
      this._grow(p);
      rec.points++;
      rec.shapes[shape] = (rec.shapes[shape] || 0) + 1;
      if (Number.isFinite(err[i])) rec.tracked++;
    }
    out.totals.bodiesDrawn += rec.points;
  }
}

// Tracking error (m) to colour: teal when close to its target, through amber to red at 10 cm; grey untracked.
export function errorColor(e) {
  if (!Number.isFinite(e)) return BODY_UNTRACKED;
  const t = Math.max(0, Math.min(1, (e - 0.01) / 0.09));
  const a = [0.25, 0.8, 0.78], b = [1.0, 0.7, 0.22], c = [1.0, 0.33, 0.33];
  return t < 0.5 ? mix(a, b, t * 2) : mix(b, c, t * 2 - 1);
}

function mix(a, b, t) { return [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t]; }

function hash(text) {
  let h = 0;
  for (let i = 0; i < text.length; i++) h = (h * 31 + text.charCodeAt(i)) >>> 0;
  return h;
}

export function streamName(s) {
  const f = s.fields;
  const name = f.actor || f.source_id || f.character || s.sender || s.topic;
  return name;
}

// The latched message describing a per-frame stream: same sender first, then same name, then the
// one whose joint/body count matches.
export function companion(store, s, type) {
  const count = (s.arrays.joint_positions || s.arrays.positions).shape[0];
  const size = (c) => {
    if (c.arrays.joint_parent) return c.arrays.joint_parent.shape[0];
    if (c.arrays.sizes) return c.arrays.sizes.shape[0];
    return -1;
  };
  const name = s.fields.character;
  let best = null, bestScore = -1;
  for (const c of store.streams.values()) {
    if (c.type !== type || size(c) !== count) continue;
    const score = (c.sender === s.sender ? 2 : 0) + (name && c.fields.character === name ? 4 : 0);
    if (score > bestScore) { best = c; bestScore = score; }
  }
  return best;
}
