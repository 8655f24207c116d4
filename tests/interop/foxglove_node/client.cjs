// A Foxglove client on Foxglove's own libraries, driven by the tests one JSON line at a
// time on stdin; it prints what it sees as JSON lines on stdout.
//
//   node client.cjs URL [SUBPROTOCOL,...] [ORIGIN]
//
// ORIGIN: the Origin header a browser would send (the web page that opened the
// connection); none by default, as a desktop app or a program.
// @foxglove/ws-protocol's FoxgloveClient speaks the protocol; Twists go out as the
// Foxglove app's Teleop panel sends them: JSON, or CDR written by
// @foxglove/rosmsg2-serialization from the ROS 1 definitions of geometry_msgs/Twist.
// Commands (stdin): advertise, publish, unadvertise, call, getParameters,
// setParameters, subscribe, sendText (raw protocol text, junk included), close.
// Events (stdout): open, refused (the HTTP status of a refused connection), serverInfo,
// advertise, advertiseServices, status, removeStatus, advertised, published, sent,
// response, failure, parameterValues, message, error, close.
"use strict";

const readline = require("node:readline");
const WebSocket = require("ws");
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const { MessageWriter } = require("@foxglove/rosmsg2-serialization");
const { ros1 } = require("@foxglove/rosmsg-msgs-common");

const [url, protocols = FoxgloveClient.SUPPORTED_SUBPROTOCOL, origin] = process.argv.slice(2);

function emit(event, fields = {}) {
  process.stdout.write(JSON.stringify({ event, ...fields }) + "\n");
}

const cdrTwist = new MessageWriter([ros1["geometry_msgs/Twist"], ros1["geometry_msgs/Vector3"]]);
const channels = new Map(); // our channel id -> encoding
const services = new Map(); // name -> service
const topics = new Map(); // topic -> server channel
const subscriptions = new Map(); // subscription id -> topic
const pending = new Map(); // call id -> service name
let nextCall = 1;

const ws = new WebSocket(url, protocols.split(","), origin ? { origin } : {});
ws.on("unexpected-response", (req, res) => {
  emit("refused", { status: res.statusCode });
  process.exit(0);
});
const client = new FoxgloveClient({ ws });

client.on("open", () => emit("open", { protocol: ws.protocol }));
client.on("error", (err) => emit("error", { message: String(err && err.message ? err.message : err) }));
client.on("close", (ev) => {
  emit("close", { code: ev && ev.code });
  process.exit(0);
});
client.on("serverInfo", (info) => emit("serverInfo", {
  capabilities: info.capabilities, supportedEncodings: info.supportedEncodings || [],
}));
client.on("status", (s) => emit("status", { level: s.level, message: s.message, id: s.id }));
client.on("removeStatus", (s) => emit("removeStatus", { ids: s.statusIds }));
client.on("advertise", (list) => {
  for (const ch of list) topics.set(ch.topic, ch);
  emit("advertise", { topics: list.map((c) => c.topic) });
});
client.on("advertiseServices", (list) => {
  for (const s of list) services.set(s.name, s);
  emit("advertiseServices", { services: list.map((s) => s.name) });
});
client.on("serviceCallResponse", (r) => {
  const name = pending.get(r.callId);
  pending.delete(r.callId);
  const text = Buffer.from(r.data.buffer, r.data.byteOffset, r.data.byteLength).toString();
  emit("response", { service: name, encoding: r.encoding, data: JSON.parse(text) });
});
client.on("serviceCallFailure", (f) => {
  const name = pending.get(f.callId);
  pending.delete(f.callId);
  emit("failure", { service: name, message: f.message });
});
client.on("parameterValues", (p) => emit("parameterValues", { id: p.id, parameters: p.parameters }));
client.on("message", (m) => {
  const topic = subscriptions.get(m.subscriptionId);
  const ch = topics.get(topic);
  const fields = { topic };
  if (ch && ch.encoding === "json") {
    fields.json = JSON.parse(Buffer.from(m.data.buffer, m.data.byteOffset, m.data.byteLength).toString());
  }
  emit("message", fields);
});

function number(v) {
  return v === "NaN" ? NaN : v === "Infinity" ? Infinity : v === "-Infinity" ? -Infinity : v;
}

function twistBytes(encoding, [vx, vy, wz]) {
  const msg = { linear: { x: number(vx), y: number(vy), z: 0 }, angular: { x: 0, y: 0, z: number(wz) } };
  if (encoding === "cdr") return cdrTwist.writeMessage(msg);
  return new Uint8Array(Buffer.from(JSON.stringify(msg)));
}

const commands = {
  advertise({ topic = "/cmd_vel", encoding = "json", schemaName = "geometry_msgs/Twist" }) {
    const id = client.advertise({ topic, encoding, schemaName });
    channels.set(id, encoding);
    emit("advertised", { channel: id, topic, encoding });
  },
  publish({ channel, twist, rate_hz = 10, seconds = 0, raw, fill, size = 0 }) {
    // fill, size: a message of size bytes, fill repeated (a bystander's 16 MB Twist)
    const encoding = channels.get(channel);
    const data = fill !== undefined ? new Uint8Array(Buffer.alloc(size, fill))
      : raw !== undefined ? new Uint8Array(Buffer.from(raw, "base64")) : twistBytes(encoding, twist);
    let count = 0;
    const send = () => { client.sendMessage(channel, data); count += 1; };
    send();
    if (seconds <= 0) {
      emit("published", { channel, count });
      return;
    }
    const timer = setInterval(send, 1000 / rate_hz);
    setTimeout(() => { clearInterval(timer); emit("published", { channel, count }); }, seconds * 1000);
  },
  unadvertise({ channel }) {
    client.unadvertise(channel);
    emit("unadvertised", { channel });
  },
  call({ service, request = {}, encoding = "json" }) {
    const s = services.get(service);
    if (!s) return emit("error", { message: `no service ${service}` });
    const callId = nextCall++;
    pending.set(callId, service);
    const bytes = new Uint8Array(Buffer.from(JSON.stringify(request)));
    client.sendServiceCallRequest({ serviceId: s.id, callId, encoding, data: new DataView(bytes.buffer) });
  },
  getParameters({ names = [], id = "get" }) {
    client.getParameters(names, id);
  },
  setParameters({ parameters, id = "set" }) {
    client.setParameters(parameters, id);
  },
  sendText({ text, repeat = 1 }) {
    for (let i = 0; i < repeat; i += 1) ws.send(text);
    emit("sent", { count: repeat });
  },
  subscribe({ topic }) {
    const ch = topics.get(topic);
    if (!ch) return emit("error", { message: `no topic ${topic}` });
    subscriptions.set(client.subscribe(ch.id), topic);
  },
  close() {
    client.close();
  },
};

function run(line) {
  if (!line.trim()) return;
  let cmd;
  try {
    cmd = JSON.parse(line);
    commands[cmd.op](cmd);
  } catch (err) {
    emit("error", { message: `${cmd ? cmd.op : line}: ${err.message}` });
  }
}

// Commands wait for the server's info (the connection is open and its capabilities known).
let ready = false;
const early = [];
client.on("serverInfo", () => {
  ready = true;
  early.splice(0).forEach(run);
});
readline.createInterface({ input: process.stdin }).on("line", (line) => {
  if (ready) run(line);
  else early.push(line);
});
