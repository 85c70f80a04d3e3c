// A Foxglove WebSocket client (the official @foxglove/ws-protocol FoxgloveClient over `ws`):
// connects to a running flyd, subscribes to the given topics and writes, as one JSON line,
// each topic's advertised schema and the first messages it received (base64).
//
//   node client.js ws://127.0.0.1:PORT SECONDS TOPIC...
//
// Exits 0 once every topic delivered 3 messages, 1 on timeout or error.
"use strict";
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const { WebSocket } = require("ws");

const [url, seconds, ...topics] = process.argv.slice(2);
const ws = new WebSocket(url, ["foxglove.sdk.v1"]);
const client = new FoxgloveClient({ ws });
const wanted = new Map(); // subscription id -> topic
const got = {}; // topic -> { schemaName, schemaEncoding, encoding, schema, messages: [] }
let serverName = null;

let finished = false;
function done(code, why) {
  if (finished) return;
  finished = true;
  process.stdout.write(JSON.stringify({ server: serverName, why, topics: got }) + "\n");
  // Exit once stdout is flushed (it is a pipe under the tests).
  process.stdout.write("", () => process.exit(code));
}

client.on("serverInfo", (info) => {
  serverName = info.name;
});
client.on("error", (e) => done(1, `error: ${e && e.message}`));
client.on("close", () => done(1, "closed by the server"));
client.on("advertise", (channels) => {
  for (const c of channels) {
    if (topics.includes(c.topic) && !got[c.topic]) {
      got[c.topic] = {
        schemaName: c.schemaName,
        schemaEncoding: c.schemaEncoding,
        encoding: c.encoding,
        schema: c.schema,
        messages: [],
      };
      wanted.set(client.subscribe(c.id), c.topic);
    }
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const topic = wanted.get(subscriptionId);
  if (!topic) return;
  const t = got[topic];
  if (t.messages.length < 3) {
    const bytes = Buffer.from(data.buffer, data.byteOffset, data.byteLength);
    t.messages.push({ timestamp: timestamp.toString(), data: bytes.toString("base64") });
  }
  if (topics.every((name) => got[name] && got[name].messages.length >= 3)) done(0, "ok");
});
setTimeout(() => done(1, "timeout"), Number(seconds) * 1000);
