// WebSocket link to the visualizer node: bundle decoding, the stream store, acks and reconnects.
// Bundle layout (see mocapgraph/viewer/wire.py): "MGV1", u32 json length, JSON, padding to 8,
// then array blocks at 8-byte aligned offsets from the start of the binary section.

const ARRAY_TYPES = { f4: Float32Array, f8: Float64Array, u1: Uint8Array, i1: Int8Array, i2: Int16Array, i4: Int32Array };
const decoder = new TextDecoder();

export function decodeBundle(buffer) {
  const view = new DataView(buffer);
  if (buffer.byteLength < 8 || view.getUint32(0, false) !== 0x4d475631) throw new Error("not a viewer bundle");
  const n = view.getUint32(4, true);
  const doc = JSON.parse(decoder.decode(new Uint8Array(buffer, 8, n)));
  const base = 8 + n + ((8 - ((8 + n) % 8)) % 8);
  for (const rec of doc.records) {
    const arrays = {};
    for (const [name, [code, shape, offset]] of Object.entries(rec.arrays)) {
      const Ctor = ARRAY_TYPES[code];
      const count = shape.reduce((a, b) => a * b, 1);
      arrays[name] = { data: new Ctor(buffer, base + offset, count), shape };
    }
    rec.arrays = arrays;
  }
  return doc;
}

// Streams by key ("topic|sender|name") with their newest record; topics with counts.
export class Store {
  constructor() { this.clear(); }
  clear() {
    this.streams = new Map();
    this.topics = new Map();
    this.version = 0;
  }
  apply(doc, nowMs) {
    for (const rec of doc.records) {
      const prev = this.streams.get(rec.key);
      // the same message sent again (a reconnect sends every stream's newest) is no news: a node
      // that stopped must not look alive because its last diagnostics came round once more
      const again = prev && prev.seq === rec.seq && prev.publish_ms === rec.publish_ms;
      rec.receivedMs = again ? prev.receivedMs : nowMs;
      rec.count = (prev ? prev.count : 0) + (again ? 0 : 1);
      rec.latencyMs = nowMs - rec.publish_ms;
      this.streams.set(rec.key, rec);
      let t = this.topics.get(rec.topic);
      if (!t) { t = { type: rec.type, records: 0, keys: new Set(), firstMs: nowMs }; this.topics.set(rec.topic, t); }
      t.type = rec.type;
      t.records++;
      t.lastMs = nowMs;
      t.keys.add(rec.key);
    }
    this.version++;
  }
  ofType(type) {
    const out = [];
    for (const s of this.streams.values()) if (s.type === type) out.push(s);
    return out;
  }
}

// Keeps a WebSocket open to the node, reconnecting with back-off; acknowledges drawn bundles.
export class Link {
  constructor(url, store, handlers) {
    this.url = url;
    this.store = store;
    this.handlers = handlers;
    this.ws = null;
    this.connected = false;
    this.connects = 0;
    this.session = null;
    this.hello = null;
    this.bundles = 0;
    this.records = 0;
    this.bytes = 0;
    this.unacked = 0;
    this.delay = 300;
    this.nextId = 1;
    this.pending = new Map();
    this.open();
  }

  open() {
    let ws;
    try {
      ws = new WebSocket(this.url);
    } catch (e) {
      this.retry();
      return;
    }
    ws.binaryType = "arraybuffer";
    this.ws = ws;
    ws.onopen = () => { this.delay = 300; };
    ws.onmessage = (ev) => this.onMessage(ev.data);
    ws.onclose = () => {
      if (this.ws !== ws) return;
      this.connected = false;
      this.unacked = 0;
      this.handlers.onStatus && this.handlers.onStatus();
      this.retry();
    };
    ws.onerror = () => {}; // onclose follows; a refused connection is normal while the graph restarts
  }

  retry() {
    clearTimeout(this.timer);
    this.timer = setTimeout(() => this.open(), this.delay);
    this.delay = Math.min(3000, this.delay * 1.6);
  }

  onMessage(data) {
    if (typeof data === "string") {
      const msg = JSON.parse(data);
      if (msg.type === "hello") {
        if (this.session !== null && this.session !== msg.session) this.store.clear(); // graph restarted
        this.session = msg.session;
        this.hello = msg;
        this.connected = true;
        this.connects++;
        this.handlers.onStatus && this.handlers.onStatus();
      } else if (msg.type === "command_result") {
        const cb = this.pending.get(msg.id);
        this.pending.delete(msg.id);
        this.handlers.onCommandResult && this.handlers.onCommandResult(msg, cb);
      }
      return;
    }
    const doc = decodeBundle(data);
    this.store.apply(doc, Date.now());
    this.bundles++;
    this.records += doc.records.length;
    this.bytes += data.byteLength;
    this.unacked++;
  }

  // Called after a frame is drawn: hands the server back the credit of every bundle received.
  ack() {
    if (!this.unacked || !this.ws || this.ws.readyState !== WebSocket.OPEN) return;
    for (let i = 0; i < this.unacked; i++) this.ws.send("a");
    this.unacked = 0;
  }

  command(channel, command, args = {}, target = "", label = "") {
    if (!this.ws || this.ws.readyState !== WebSocket.OPEN) return false;
    const id = this.nextId++;
    this.pending.set(id, label || command);
    this.ws.send(JSON.stringify({ type: "command", id, channel, command, args, target }));
    return true;
  }
}
