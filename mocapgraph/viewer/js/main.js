// Entry of the viewer page: connects, draws the stage (three.js) every animation frame, refreshes the panel.
// window.mocapgraphStats exposes what was drawn (for tests and benchmarks).

import * as THREE from "three";
import { Stage } from "./stage.js";
import { StageCamera } from "./camera.js";
import { Avatars } from "./avatar.js";
import { Link, Store } from "./net.js";
import { SceneBuilder } from "./scene.js";
import { Panel } from "./panel.js";
import { VideoPanel } from "./video.js";

const $ = (id) => document.getElementById(id);

const stats = {
  ready: false, connected: false, connects: 0, session: null, bundles: 0, records: 0, bytes: 0,
  framesDrawn: 0, fps: 0, markersDrawn: 0, markersTotal: 0, jointsDrawn: 0, bonesDrawn: 0, skeletonJointsDrawn: 0,
  characterJointsDrawn: 0, bodiesDrawn: 0, actorsDrawn: 0, avatarsDrawn: 0, avatarErrors: [], streams: {}, topics: {},
  errors: [], webgl: "", three: THREE.REVISION, video: {}, calibration: null, player: null,
};
window.mocapgraphStats = stats;
window.addEventListener("error", (e) => stats.errors.push(String(e.message)));
window.addEventListener("unhandledrejection", (e) => stats.errors.push(String(e.reason)));

const canvas = $("canvas");
const stage = new Stage(canvas);
stats.webgl = stage.rendererName;
const camera = new StageCamera(canvas);
const store = new Store();
const scene = new SceneBuilder();
// The per-launch token of the printed URL goes with every connection (the server refuses any without it).
const token = new URLSearchParams(location.search).get("token") || "";
scene.avatars = new Avatars(stage.avatarRoot, token);
const wsUrl = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws?token=${encodeURIComponent(token)}`;
let panel = null;
const link = new Link(wsUrl, store, {
  onStatus: () => {
    if (link.hello) scene.referenceTopics = new Set(link.hello.reference_topics || []);
    if (link.hello) video.offer(link.hello.source_videos || [], token, store);
    if (panel) panel.connection();
  },
  onCommandResult: (msg, label) => panel && panel.commandResult(msg, label),
});
const video = new VideoPanel(stage, {
  file: $("video-file"), play: $("video-play"), pause: $("video-pause"), stop: $("video-stop"), seek: $("video-seek"),
  loop: $("video-loop"), volume: $("video-volume"), mute: $("video-mute"), status: $("video-status"),
  follow: $("video-follow"), sourceRow: $("video-source"),
});
panel = new Panel(link, store, scene, video);
const viewer = { camera, stage, store, scene, link, video, panel, avatars: scene.avatars, viewProj: null, frozen: false };
window.mocapgraphViewer = viewer;
$("freeze").addEventListener("change", (e) => { viewer.frozen = e.target.checked; });

let lastBounds = null;
for (const b of document.querySelectorAll("[data-view]")) {
  b.addEventListener("click", () => view(b.dataset.view));
}
function view(name) {
  if (name === "fit") { if (lastBounds) camera.fit(lastBounds); return; }
  camera.preset(name);
}
window.addEventListener("keydown", (e) => {
  if (e.target instanceof HTMLInputElement) return;
  const keys = { "1": "front", "2": "side", "3": "top", "0": "perspective", f: "fit" };
  if (keys[e.key]) view(keys[e.key]);
});

// Actor name labels over the stage (HTML, so that they stay crisp).
const labelPool = [];
const at = new THREE.Vector3();
function project(cam, p, w, h) {
  at.set(p[0], p[1], p[2]).applyMatrix4(cam.matrixWorldInverse);
  if (at.z >= -1e-6) return null;   // behind the camera
  at.applyMatrix4(cam.projectionMatrix);
  return [(at.x * 0.5 + 0.5) * w, (1 - (at.y * 0.5 + 0.5)) * h];
}
function drawLabels(labels, cam) {
  const box = $("labels");
  const w = canvas.clientWidth, h = canvas.clientHeight;
  let used = 0;
  if (scene.show.labels) {
    for (const l of labels) {
      const p = project(cam, l.pos, w, h);
      if (!p) continue;
      let div = labelPool[used];
      if (!div) { div = document.createElement("div"); div.className = "label"; box.append(div); labelPool.push(div); }
      div.textContent = l.text;
      div.classList.toggle("reference", !!l.reference);
      div.style.transform = `translate(${p[0].toFixed(1)}px, ${p[1].toFixed(1)}px) translate(-50%, -100%)`;
      div.hidden = false;
      used++;
    }
  }
  for (let i = used; i < labelPool.length; i++) labelPool[i].hidden = true;
}

let last = performance.now();
let lastPanel = 0;
let fpsCount = 0, fpsStart = last;
let built = null;
function frame(now) {
  const dt = Math.min(0.1, (now - last) / 1000);
  last = now;
  const wallMs = Date.now();
  const panelGeom = video.frame();
  // frozen: the last frame's stage stays (markers, bodies, avatars), the camera still moves
  if (!viewer.frozen || !built) built = scene.build(store, wallMs, { panel: panelGeom });
  if (built.bounds) lastBounds = built.bounds;
  stage.resize(camera.camera);
  const cam = camera.update(dt);
  viewer.viewProj = camera.viewProj.elements;   // for tests: where a world point lands on the page
  stage.draw(cam, scene.batches, panelGeom);
  drawLabels(built.labels, cam);
  link.ack();

  stats.framesDrawn++;
  Object.assign(stats, built.totals);
  stats.streams = built.streams;
  fpsCount++;
  if (now - fpsStart >= 1000) { stats.fps = fpsCount * 1000 / (now - fpsStart); fpsCount = 0; fpsStart = now; }
  if (now - lastPanel > 250) {
    lastPanel = now;
    panel.update(built, stats.fps, wallMs);
    stats.connected = link.connected;
    stats.connects = link.connects;
    stats.session = link.session;
    stats.client = link.hello ? link.hello.client : null;
    stats.bundles = link.bundles;
    stats.records = link.records;
    stats.bytes = link.bytes;
    stats.topics = Object.fromEntries([...store.topics].map(([t, v]) => [t, { type: v.type, records: v.records }]));
    stats.video = video.stats();
    stats.avatarsDrawn = scene.avatars.drawn;
    stats.avatarErrors = scene.avatars.errors;
    const st = (el) => (el.hidden ? null : el.querySelector(".badge").textContent);
    stats.calibration = st($("sec-calibration"));
    stats.player = st($("sec-player"));
  }
  stats.ready = true;
  requestAnimationFrame(frame);
}
requestAnimationFrame(frame);
