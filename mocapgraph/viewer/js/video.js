// The video panel at the back of the stage: a local file chosen by the user plays on a plane,
// uploaded as the stage's (three.js) texture whenever the video has a new frame. Or the source
// video of a video skeleton reader (served by the viewer), played in step with its skeleton: the
// video shows, at each moment, the frame whose media time (frame_number / fps) the reader
// published at that moment (its publish stamp), followed by playback rate, seeking when off.

const PANEL_X = -3.4;   // m: the plane stands behind the performers as seen from the front
const PANEL_WIDTH = 4.4; // m
const PANEL_BOTTOM = 0.45; // m
const SEEK_S = 0.3;        // a source video farther than this from its reader's media time seeks
const SEEK_LEAD_S = 0.1;   // and lands this far ahead (a seek takes time), at the reader's rate
const GAIN = 4;            // playback rate added per second of media time the clip is behind

export class VideoPanel {
  constructor(renderer, els) {
    this.renderer = renderer;
    this.els = els;
    this.video = document.createElement("video");
    this.video.playsInline = true;
    this.video.preload = "auto";
    this.video.crossOrigin = "anonymous";
    this.url = null;
    this.fresh = false;
    this.framesUploaded = 0;
    this.aspect = 16 / 9;
    this.enabled = true;
    this.name = "";
    this._placeholder("no video: choose a file in the panel");
    const v = this.video;
    v.addEventListener("loadedmetadata", () => {
      this.aspect = v.videoWidth && v.videoHeight ? v.videoWidth / v.videoHeight : 16 / 9;
      if (v.duration === Infinity) {
        // Recorded WebM often has no duration: seeking past the end makes the browser find it.
        this.probing = true;
        v.currentTime = 1e101;
      }
      this.fresh = true;
      this.sync();
    });
    v.addEventListener("durationchange", () => {
      if (this.probing && Number.isFinite(v.duration)) {
        this.probing = false;
        v.currentTime = 0;
      }
      els.seek.max = String(Number.isFinite(v.duration) ? v.duration : 0);
      this.sync();
    });
    for (const ev of ["play", "pause", "ended", "volumechange", "seeked", "timeupdate"]) {
      v.addEventListener(ev, () => { this.fresh = true; this.sync(); });
    }
    els.file.addEventListener("change", () => els.file.files[0] && this.load(els.file.files[0]));
    els.follow.addEventListener("click", () => this.offered && this.followSource(this.offered));
    els.play.addEventListener("click", () => this.play());
    els.pause.addEventListener("click", () => v.pause());
    els.stop.addEventListener("click", () => this.stop());
    els.seek.addEventListener("input", () => { v.currentTime = Number(els.seek.value); });
    els.loop.addEventListener("change", () => { v.loop = els.loop.checked; });
    els.volume.addEventListener("input", () => { v.volume = Number(els.volume.value); if (v.volume > 0) v.muted = false; });
    els.mute.addEventListener("click", () => { v.muted = !v.muted; });
    this.sync();
  }

  load(file) {
    if (this.url) URL.revokeObjectURL(this.url);
    this.url = URL.createObjectURL(file);
    this.name = file.name;
    this.following = null;
    clearInterval(this.followTimer);
    this.video.playbackRate = 1;
    this.video.src = this.url;
    this.video.loop = this.els.loop.checked;
    this.video.load();
    this.sync();
  }

  // The clips the viewer offers (hello.source_videos: {node, name, fps}); the first is offered.
  offer(videos, token, store) {
    this.offered = videos.length ? { ...videos[0], token } : null;
    this.store = store;
    this.els.sourceRow.hidden = !this.offered;
    if (this.offered) this.els.follow.textContent = `▶ Source video · ${this.offered.name} (in step with ${this.offered.node})`;
  }

  followSource(src) {
    if (this.url) URL.revokeObjectURL(this.url);
    this.url = null;
    this.name = `${src.name} · source of ${src.node}`;
    this.following = { node: src.node, fps: src.fps, pass: null, seeks: 0 };
    this.video.loop = false;
    this.video.muted = true;    // the skeleton sets the pace; no sound jumping at each correction
    clearInterval(this.followTimer);
    this.followTimer = setInterval(() => this._follow(Date.now()), 40);   // finer than a slow page's frames
    this.video.src = `source_video?token=${encodeURIComponent(src.token)}&node=${encodeURIComponent(src.node)}`;
    this.video.load();
    this.sync();
  }

  // The reader's media time now: its newest pose's frame time, advanced by the wall time since its
  // publish stamp at the rate the poses come (null when there is no pose of that reader).
  sourceTime(nowMs) {
    const f = this.following;
    let pose = null;
    for (const s of this.store.streams.values()) {
      if (s.type === "SkeletonPose" && s.sender === f.node && (!pose || s.publish_ms > pose.publish_ms)) pose = s;
    }
    if (!pose) return null;
    const t = pose.fields.frame_number / f.fps;
    if (!f.pass || t < f.prevT || pose.publish_ms < f.pass.ms) f.pass = { t, ms: pose.publish_ms };  // a new pass (loop, restart)
    f.prevT = t;
    const span = (pose.publish_ms - f.pass.ms) / 1000;
    f.rate = span > 0.2 ? Math.max(0, (t - f.pass.t) / span) : (f.rate ?? 1);
    const fresh = nowMs - pose.publish_ms < 500;
    const ahead = fresh ? Math.min((nowMs - pose.publish_ms) / 1000 * f.rate, 0.5) : 0;
    return { t: Math.min(t + ahead, this.video.duration || Infinity), frame: pose.fields.frame_number, fresh, rate: f.rate };
  }

  // Keep the clip on the reader's media time: playback rate for small offsets, a seek for large.
  _follow(nowMs) {
    const v = this.video, f = this.following;
    if (!f || v.readyState < 1 || v.seeking) return;
    const at = this.sourceTime(nowMs);
    if (!at) return;
    const off = at.t - v.currentTime;
    f.last = { mediaTime: at.t, videoTime: v.currentTime, frame: at.frame, offFrames: off * f.fps, rate: at.rate };
    if (!at.fresh || !(at.rate > 0.05)) {                         // the reader paused or stopped: hold its frame
      if (!v.paused) v.pause();
      if (Math.abs(off) > 0.5 / f.fps) { v.currentTime = at.t; f.seeks++; }
      return;
    }
    if (Math.abs(off) > SEEK_S) {
      v.currentTime = Math.min(at.t + at.rate * SEEK_LEAD_S, (v.duration || Infinity) - 1e-3);
      f.seeks++;
    }
    v.playbackRate = Math.max(0.0625, Math.min(4, at.rate + GAIN * off));   // catches up 1 / GAIN s of a lag a second
    if (v.paused && !v.ended) this.play();
  }

  play() {
    if (!this.video.src) return;
    const p = this.video.play();
    if (p && p.catch) p.catch((e) => { this.els.status.textContent = "cannot play: " + e.message; });
  }

  stop() {
    this.video.pause();
    if (this.video.src) this.video.currentTime = 0;
  }

  _placeholder(text) {
    const c = document.createElement("canvas");
    c.width = 768; c.height = 432;
    const g = c.getContext("2d");
    const grad = g.createLinearGradient(0, 0, 0, c.height);
    grad.addColorStop(0, "#1c2230"); grad.addColorStop(1, "#12161f");
    g.fillStyle = grad; g.fillRect(0, 0, c.width, c.height);
    g.strokeStyle = "#3a4458"; g.lineWidth = 6; g.strokeRect(12, 12, c.width - 24, c.height - 24);
    g.fillStyle = "#7d8aa3"; g.font = "600 34px system-ui, sans-serif"; g.textAlign = "center";
    g.fillText("VIDEO PANEL", c.width / 2, c.height / 2 - 12);
    g.font = "24px system-ui, sans-serif"; g.fillStyle = "#5d6980";
    g.fillText(text, c.width / 2, c.height / 2 + 30);
    this.renderer.uploadTexture(c);
  }

  // Called once per drawn frame: upload a new video frame, return the panel geometry.
  frame() {
    const v = this.video;
    if (v.src && v.readyState >= 2 && (this.fresh || !v.paused)) {
      this.renderer.uploadTexture(v);
      this.framesUploaded++;
      this.fresh = false;
    }
    if (!this.enabled) return null;
    const w = PANEL_WIDTH, h = w / this.aspect, y = w / 2;
    return {
      // Seen from the front (+X) the screen's right is the world's +Y.
      corners: [[PANEL_X, -y, PANEL_BOTTOM], [PANEL_X, y, PANEL_BOTTOM], [PANEL_X, y, PANEL_BOTTOM + h], [PANEL_X, -y, PANEL_BOTTOM + h]],
      dim: v.src ? 1 : 0.9,
    };
  }

  sync() {
    const v = this.video, els = this.els;
    const has = !!v.src;
    for (const b of [els.play, els.pause, els.stop, els.seek, els.mute]) b.disabled = !has;
    if (document.activeElement !== els.seek) els.seek.value = String(v.currentTime || 0);
    els.mute.textContent = v.muted ? "Unmute" : "Mute";
    els.mute.setAttribute("aria-pressed", String(v.muted));
    els.volume.value = String(v.muted ? 0 : v.volume);
    const t = (x) => Number.isFinite(x) ? x.toFixed(1) + " s" : "–";
    els.status.textContent = has ? `${this.name} · ${v.paused ? (v.ended ? "ended" : "paused") : "playing"} · ${t(v.currentTime)} / ${t(v.duration)}` : "no file chosen";
  }

  stats() {
    const v = this.video;
    return { loaded: !!v.src, ready: !!v.src && !this.probing && Number.isFinite(v.duration) && v.readyState >= 2, playing: !v.paused && !v.ended, currentTime: v.currentTime, duration: v.duration || 0,
      loop: v.loop, muted: v.muted, volume: v.volume, framesUploaded: this.framesUploaded, width: v.videoWidth,
      height: v.videoHeight, following: this.following ? this.following.node : null,
      sync: this.following ? this.following.last || null : null, seeks: this.following ? this.following.seeks : 0 };
  }
}
