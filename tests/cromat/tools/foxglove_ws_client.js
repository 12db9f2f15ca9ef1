// Foxglove's own npm client (@foxglove/ws-protocol, subprotocol foxglove.websocket.v1) against `cromat foxglove`.
// usage: node foxglove_ws_client.js URL SECONDS COUNT TOPIC...
// Prints one JSON line per event: {"event":"open","protocol":...}, {"event":"advertise","topic",...},
// {"event":"message","topic","data" (base64)}; exits 0 once every topic has COUNT messages, 1 at the deadline.
"use strict";
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");

const [url, seconds, count, ...topics] = process.argv.slice(2);
const wanted = new Set(topics);
const need = Number(count);
const got = new Map(topics.map((t) => [t, 0]));
const bySub = new Map();
const byChannel = new Map();
const say = (doc) => process.stdout.write(JSON.stringify(doc) + "\n");

const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const subscribe = (channel) => bySub.set(client.subscribe(channel.id), channel);

client.on("open", () => say({ event: "open", protocol: ws.protocol }));
client.on("serverInfo", (info) => say({ event: "serverInfo", name: info.name }));
client.on("error", (err) => say({ event: "error", message: String(err && err.message ? err.message : err) }));
client.on("close", (ev) => say({ event: "close", code: ev.code, reason: String(ev.reason || "") }));
client.on("advertise", (channels) => {
  for (const c of channels) {
    if (!wanted.has(c.topic) || byChannel.has(c.id)) continue;
    byChannel.set(c.id, c);
    say({ event: "advertise", topic: c.topic, encoding: c.encoding, schemaName: c.schemaName,
          schemaEncoding: c.schemaEncoding, schema: c.schema });
    subscribe(c);
  }
});
client.on("status", (st) => {
  say({ event: "status", level: st.level, message: st.message });
  // foxglove-sdk may refuse a subscription sent right after the advertisement (docs/tools.md): subscribe again
  const m = /Unknown channel ID: (\d+)/.exec(st.message || "");
  if (m && byChannel.has(Number(m[1]))) subscribe(byChannel.get(Number(m[1])));
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const c = bySub.get(subscriptionId);
  if (!c) return;
  got.set(c.topic, got.get(c.topic) + 1);
  const bytes = Buffer.from(data.buffer, data.byteOffset, data.byteLength);
  say({ event: "message", topic: c.topic, timestamp: timestamp.toString(), data: bytes.toString("base64") });
  if ([...got.values()].every((n) => n >= need)) {
    client.close();
    process.exit(0);
  }
});
setTimeout(() => {
  say({ event: "timeout", counts: Object.fromEntries(got) });
  process.exit(1);
}, Number(seconds) * 1000);
