// The side panel and the heads-up display: performers and layers, calibration, playback, topics.

import { DRAWN_TYPES, SUPPORT_TYPES, GOOD, ESTIMATED, MISSING } from "./scene.js";

const STALL_MS = 3000;  // launch/liveness.py STALL_S

const $ = (id) => document.getElementById(id);
const css = (c) => `rgb(${c.map((v) => Math.round(v * 255)).join(",")})`;
const fmt = (x, d = 1) => (Number.isFinite(x) ? x.toFixed(d) : "–");

function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v;
    else if (k === "text") e.textContent = v;
    else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c);
  return e;
}

function parseJson(text) {
  try { return JSON.parse(text || "{}") || {}; } catch { return {}; }
}

export class Panel {
  constructor(link, store, scene, video) {
    this.link = link;
    this.store = store;
    this.scene = scene;
    this.video = video;
    this.actorKeys = "";
    this.seekDragging = false;
    this.calibTarget = "";
    this.playerTarget = "";
    for (const b of document.querySelectorAll("[data-calib]")) {
      b.addEventListener("click", () => this.send("calibration", b.dataset.calib, {}, this.calibTarget, b.textContent));
    }
    for (const b of document.querySelectorAll("[data-player]")) {
      b.addEventListener("click", () => this.send("player", b.dataset.player, {}, this.playerTarget, b.textContent));
    }
    const seek = $("player-seek");
    seek.addEventListener("input", () => { this.seekDragging = true; $("player-time").textContent = `seek to ${fmt(Number(seek.value))} s`; });
    seek.addEventListener("change", () => {
      this.seekDragging = false;
      this.send("player", "seek", { position_s: Number(seek.value) }, this.playerTarget, "Seek");
    });
    for (const [id, key] of [["show-markers", "markers"], ["show-bones", "bones"], ["show-labels", "labels"], ["show-axes", "axes"],
                             ["show-characters", "characters"], ["show-avatars", "avatars"], ["show-bodies-beside", "bodiesBeside"]]) {
      $(id).addEventListener("change", (e) => { this.scene.show[key] = e.target.checked; });
    }
    $("show-video").addEventListener("change", (e) => { this.video.enabled = e.target.checked; });
    $("actor-list").addEventListener("change", (e) => {
      const key = e.target.dataset.key;
      if (!key) return;
      if (e.target.checked) this.scene.hidden.delete(key); else this.scene.hidden.add(key);
    });
  }

  send(channel, command, args, target, label) {
    if (this.link.command(channel, command, args, target, label)) {
      this.notice(`${label.trim()} → ${target || "all"}`);
    } else {
      this.notice("not connected", true);
    }
  }

  notice(text, error = false) {
    const n = $("notice");
    n.textContent = text;
    n.className = error ? "show error" : "show";
    clearTimeout(this.noticeTimer);
    this.noticeTimer = setTimeout(() => { n.className = ""; }, 2500);
  }

  commandResult(msg, label) {
    if (!msg.ok) this.notice(`${label || "command"} refused: ${msg.error}`, true);
  }

  topicOf(port) {
    const t = this.link.hello && this.link.hello.topics[port];
    return t ? t.topic : port;
  }

  // Refresh the DOM (a few times a second, not every frame).
  update(built, fps, nowMs) {
    this.connection();
    this.hud(built, fps);
    this.actors(built);
    this.calibration();
    this.player();
    this.topics(built, nowMs);
    this.video.sync();
    const errors = this.scene.avatars ? this.scene.avatars.errors : [];   // an avatar that failed: its character is drawn as bones
    $("avatar-note").hidden = !errors.length;
    $("avatar-note").textContent = errors.length ? `${errors[errors.length - 1]} (drawn as bones)` : "";
  }

  connection() {
    const ok = this.link.connected;
    $("conn-dot").className = "dot " + (ok ? "ok" : "bad");
    $("conn-text").textContent = ok ? `live · ${this.link.hello.node}` : "reconnecting…";
  }

  hud(built, fps) {
    const t = built.totals;
    $("hud-markers").textContent = t.markersTotal ? `${t.markersDrawn}/${t.markersTotal}` : "–";
    $("hud-actors").textContent = String(t.actorsDrawn);
    $("hud-fps").textContent = fmt(fps, 0);
    const missing = [];
    for (const s of this.store.ofType("MarkerFrame")) {
      const layout = this.store.ofType("MarkerLayout").find((l) => l.sender === s.sender && l.fields.labels.length === s.arrays.valid.shape[0]);
      const pos = s.arrays.positions.data;
      for (let i = 0; i < s.arrays.valid.shape[0]; i++) {
        if (!Number.isFinite(pos[3 * i])) missing.push(layout ? layout.fields.labels[i] : `#${i}`);
      }
    }
    $("hud-missing").textContent = missing.length ? `missing: ${missing.slice(0, 12).join(", ")}${missing.length > 12 ? ` +${missing.length - 12}` : ""}` : "";
  }

  actors(built) {
    const keys = Object.keys(built.streams).sort();
    const list = $("actor-list");
    if (keys.join("\n") !== this.actorKeys) {
      this.actorKeys = keys.join("\n");
      list.replaceChildren();
      for (const key of keys) {
        const r = built.streams[key];
        const box = el("input", { type: "checkbox", "data-key": key });
        box.checked = !this.scene.hidden.has(key);
        const row = el("label", { class: "actor", "data-key": key }, box,
          el("span", { class: "name", text: r.name }), el("span", { class: "type", text: r.reference ? `${r.type} · reference` : r.type }),
          el("span", { class: "summary" }));
        list.append(row);
      }
      if (!keys.length) list.append(el("div", { class: "empty", text: "nothing to draw yet" }));
    }
    for (const row of list.querySelectorAll(".actor")) {
      const r = built.streams[row.dataset.key];
      if (!r) continue;
      const s = row.querySelector(".summary");
      s.replaceChildren();
      if (r.quality) {
        for (const [n, c, what] of [[r.quality.good, GOOD, "good"], [r.quality.estimated, ESTIMATED, "estimated"], [r.quality.missing, MISSING, "missing"]]) {
          const chip = el("span", { class: "chip", title: `${n} ${what}`, text: String(n) });
          chip.style.background = css(c);
          s.append(chip);
        }
      } else if (r.total !== undefined) {
        s.append(el("span", { class: "count", text: `${r.visible ? r.points : 0}/${r.total}` }));
      }
      row.classList.toggle("stale", !!r.stale);
    }
  }

  calibration() {
    const topic = this.topicOf("calibration_status");
    const status = [...this.store.streams.values()].find((s) => s.topic === topic && s.type === "NodeStatus");
    const models = this.store.ofType("SkeletonModel");
    $("sec-calibration").hidden = !status && !models.length;
    const data = status ? parseJson(status.fields.data_json) : {};
    if (status) {
      this.calibTarget = status.fields.node || status.sender;
      $("calib-state").textContent = status.fields.state;
      $("calib-state").dataset.state = status.fields.state;
      $("calib-detail").textContent = status.fields.detail || "";
      const p = status.fields.progress;
      $("calib-progress").style.width = `${Number.isFinite(p) ? Math.round(100 * p) : 0}%`;
    } else {
      $("calib-state").textContent = "no calibration node";
    }
    for (const b of document.querySelectorAll("[data-calib]")) b.disabled = !status || !this.link.connected;
    const model = models.find((m) => m.sender === this.calibTarget) || models[0];
    const table = $("joint-table");
    if (!model) { table.replaceChildren(); return; }
    const names = model.fields.joint_names;
    const res = model.arrays.joint_residual_rms ? model.arrays.joint_residual_rms.data : null;
    const rom = model.arrays.joint_rom ? model.arrays.joint_rom.data : null;
    // The calibration node's report (data_json.joints: reliable, residual_mm, rom_deg, warnings)
    // and the model's own verdict (extra_json quality: method, reliable): a joint either calls
    // unreliable is shown so, whatever its residual (a centre from the prior is never good).
    const report = new Map((Array.isArray(data.joints) ? data.joints : []).map((j) => [j.joint, j]));
    const mq = (parseJson(model.fields.extra_json || "{}") || {}).quality || {};
    const rows = [el("tr", {}, el("th", { text: "joint" }), el("th", { text: "method" }), el("th", { text: "residual mm" }), el("th", { text: "ROM °" }), el("th", { text: "" }))];
    names.forEach((name, i) => {
      const r = report.get(name);
      const mm = r && r.residual_mm != null ? Number(r.residual_mm) : res ? res[i] * 1000 : NaN;
      const deg = r && r.rom_deg != null ? Number(r.rom_deg) : rom ? rom[i] * 180 / Math.PI : NaN;
      const reliable = !(r && r.reliable === false) && !(Array.isArray(mq.reliable) && mq.reliable[i] === false);
      const q = !reliable || !Number.isFinite(mm) ? 0 : mm < 5 ? 2 : mm < 12 ? 1 : 0;
      const dot = el("span", { class: "qdot", title: reliable ? ["poor", "fair", "good"][q] : "unreliable" });
      dot.dataset.reliable = String(reliable);
      dot.style.background = css(q >= 2 ? GOOD : q === 1 ? ESTIMATED : MISSING);
      const method = r && r.method ? String(r.method) : Array.isArray(mq.method) ? String(mq.method[i] ?? "") : "";
      const row = el("tr", { "data-reliable": reliable ? "yes" : "no" }, el("td", { text: name }), el("td", { text: method }), el("td", { text: fmt(mm) }), el("td", { text: fmt(deg, 0) }), el("td", {}, dot));
      if (r && r.warnings && r.warnings.length) row.title = r.warnings.join("; ");
      rows.push(row);
    });
    table.replaceChildren(...rows);
  }

  player() {
    const topic = this.topicOf("player_status");
    const status = [...this.store.streams.values()].find((s) => s.topic === topic && s.type === "NodeStatus");
    $("sec-player").hidden = !status;
    if (!status) return;
    this.playerTarget = status.fields.node || status.sender;
    const data = parseJson(status.fields.data_json);
    const t = Number(data.t ?? data.time_s ?? data.position_s ?? NaN);
    const dur = Number(data.duration ?? data.duration_s ?? NaN);
    $("player-state").textContent = status.fields.state;
    $("player-state").dataset.state = status.fields.state;
    const seek = $("player-seek");
    if (Number.isFinite(dur)) seek.max = String(dur);
    if (!this.seekDragging && document.activeElement !== seek && Number.isFinite(t)) seek.value = String(t);
    if (!this.seekDragging) $("player-time").textContent = `${fmt(t, 2)} s / ${fmt(dur, 1)} s`;
    for (const b of document.querySelectorAll("[data-player]")) b.disabled = !this.link.connected;
  }

  topics(built, nowMs) {
    // Rate, latency and drops per topic from every node's diagnostics (over all receiving edges).
    const rows = new Map();
    const row = (topic) => {
      let r = rows.get(topic);
      if (!r) { r = { topic, type: "", rate: NaN, latency: NaN, drops: 0, edges: 0 }; rows.set(topic, r); }
      return r;
    };
    // A node whose diagnostics (1 Hz) stopped for 3 s is stalled: stopped, or stuck in a handler.
    const stalled = [];
    for (const d of this.store.ofType("Diagnostics")) {
      if (nowMs - d.receivedMs > STALL_MS) stalled.push(d.fields.node || d.sender);
    }
    stalled.sort();
    const note = $("stalled-nodes");
    if (note) {
      note.hidden = stalled.length === 0;
      note.textContent = stalled.length ? `stalled (no diagnostics for 3 s): ${stalled.join(", ")}` : "";
    }
    if (window.mocapgraphStats) window.mocapgraphStats.stalled = stalled;
    for (const d of this.store.ofType("Diagnostics")) {
      const f = d.fields, a = d.arrays;
      f.edge_topics.forEach((topic, i) => {
        const r = row(topic);
        r.edges++;
        r.rate = Number.isFinite(r.rate) ? Math.max(r.rate, a.edge_rate_hz.data[i]) : a.edge_rate_hz.data[i];
        const lat = a.edge_latency_ms.data[i];
        if (Number.isFinite(lat)) r.latency = Number.isFinite(r.latency) ? Math.max(r.latency, lat) : lat;
        r.drops += a.edge_gaps.data[i] + a.edge_rejected.data[i];
      });
    }
    for (const [topic, t] of this.store.topics) row(topic).type = t.type;
    if (this.link.hello) {
      for (const t of Object.values(this.link.hello.topics)) if (rows.has(t.topic) && !rows.get(t.topic).type && t.type !== "*") rows.get(t.topic).type = t.type;
    }
    const body = $("topic-table").querySelector("tbody");
    const out = [];
    for (const r of [...rows.values()].sort((a, b) => a.topic.localeCompare(b.topic))) {
      const known = DRAWN_TYPES.has(r.type) ? "drawn" : SUPPORT_TYPES.has(r.type) ? "used" : r.type ? "not drawn" : "";
      const tr = el("tr", { "data-topic": r.topic, "data-drawn": known },
        el("td", { text: r.topic }), el("td", { text: r.type || "?" }), el("td", { class: "num", text: fmt(r.rate, 0) }),
        el("td", { class: "num", text: fmt(r.latency, 1) }), el("td", { class: "num" + (r.drops ? " warn" : ""), text: String(r.drops) }),
        el("td", { class: "tag " + known.replace(" ", "-"), text: known === "not drawn" ? "not drawn (unknown type)" : known }));
      out.push(tr);
    }
    body.replaceChildren(...out);
  }
}
