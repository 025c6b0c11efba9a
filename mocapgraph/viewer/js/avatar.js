// Characters as skinned avatars: the viewer serves each character's mannequin as GLB (built from
// its CharacterInfo by our own glTF writer), three.js's GLTFLoader loads it, and every
// CharacterPose drives the skin's bones: rest orientation times the pose's local rotation per
// joint, the root at the pose's root position. glTF's axes (Y up, Z forward, X left) are turned
// into ours (Z up, X forward, Y left) by the avatar's parent group.

import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";

export const AVATAR_COLOUR = [0.92, 0.68, 0.52];   // the mannequin's clay (a hue nothing else on the stage has)
const RETRY_MS = 3000;
// ours = TO_OURS * glTF: x <- z, y <- x, z <- y
const TO_OURS = new THREE.Matrix4().set(0, 0, 1, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 1);

export class Avatars {
  constructor(root, token) {
    this.root = root;
    this.token = token;
    this.loader = new GLTFLoader();
    this.items = new Map();     // CharacterPose stream key -> avatar
    this.glbs = new Map();      // CharacterInfo id -> Promise of the GLB's bytes
    this.tmp = new THREE.Quaternion();
    this.drawn = 0;
    this.errors = [];
  }

  begin() {
    for (const a of this.items.values()) a.used = false;
  }

  end() {
    this.drawn = 0;
    for (const a of this.items.values()) {
      if (a.group) a.group.visible = a.used;
      this.drawn += a.used ? 1 : 0;
    }
  }

  // Pose the avatar of stream `s` (CharacterPose) whose skeleton is `info` (CharacterInfo); false
  // while its mesh loads or when it cannot show this pose (the caller draws bones instead).
  drive(s, info, dim) {
    const id = `${info.key}|${info.seq}|${info.publish_ms}`;
    let a = this.items.get(s.key);
    if (!a || a.id !== id || (a.state === "failed" && performance.now() > a.retryAt)) {
      if (a && a.group) this.root.remove(a.group);
      if (a && a.state === "failed") this.glbs.delete(id);
      a = { id, state: "loading", used: false, group: null };
      this.items.set(s.key, a);
      this._load(a, info);
    }
    const rot = s.arrays.local_rotations, root = s.arrays.root_position;
    if (a.state !== "ready" || !rot || rot.shape[0] !== a.bones.length) return false;
    const q = rot.data, r = root.data, tmp = this.tmp;
    for (let j = 0; j < a.bones.length; j++) {
      tmp.set(q[4 * j + 2], q[4 * j + 3], q[4 * j + 1], q[4 * j]).normalize();   // wxyz ours -> xyzw glTF
      a.bones[j].quaternion.multiplyQuaternions(a.rest[j], tmp);
    }
    if (Number.isFinite(r[0] + r[1] + r[2])) a.bones[a.rootIndex].position.set(r[1], r[2], r[0]);
    a.material.color.setRGB(AVATAR_COLOUR[0] * dim, AVATAR_COLOUR[1] * dim, AVATAR_COLOUR[2] * dim);
    a.used = true;
    return true;
  }

  _glb(id, infoKey) {
    if (!this.glbs.has(id)) {
      const url = `avatar.glb?token=${encodeURIComponent(this.token)}&key=${encodeURIComponent(infoKey)}`;
      this.glbs.set(id, fetch(url).then(async (r) => {
        if (!r.ok) throw new Error((await r.text()).trim() || `HTTP ${r.status}`);
        return r.arrayBuffer();
      }));
    }
    return this.glbs.get(id);
  }

  _load(a, info) {
    this._glb(a.id, info.key)
      .then((buf) => this.loader.parseAsync(buf, ""))
      .then((gltf) => {
        let mesh = null;
        gltf.scene.traverse((o) => { if (o.isSkinnedMesh && !mesh) mesh = o; });
        if (!mesh) throw new Error("the avatar has no skinned mesh");
        a.material = new THREE.MeshLambertMaterial({ color: new THREE.Color(...AVATAR_COLOUR) });
        mesh.material = a.material;
        mesh.frustumCulled = false;    // its bounds are the rest pose's; the pose moves it anywhere
        a.bones = mesh.skeleton.bones;
        a.rest = a.bones.map((b) => b.quaternion.clone());
        a.rootIndex = Math.max(0, a.bones.findIndex((b) => !b.parent || !b.parent.isBone));
        a.group = new THREE.Group();
        a.group.matrixAutoUpdate = false;
        a.group.matrix.copy(TO_OURS);
        a.group.visible = false;
        a.group.add(gltf.scene);
        this.root.add(a.group);
        a.state = "ready";
      })
      .catch((e) => {
        a.state = "failed";
        a.retryAt = performance.now() + RETRY_MS;
        const text = `avatar of ${info.fields.character || info.key}: ${e.message || e}`;
        if (!this.errors.includes(text)) this.errors = [...this.errors.slice(-4), text];
      });
  }
}
