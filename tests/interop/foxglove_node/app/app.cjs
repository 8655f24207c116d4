// The Foxglove app's own code, taken from its web build (@foxglove/studio-base's assets,
// the open-source Foxglove Studio that Lichtblick forked), run against omnican's channels:
//
//   node app.cjs channels  < [{topic, encoding, schemaName, schema, schemaEncoding,
//                              message (base64)}, ...]
//       -> {topic: {decoded} | {error}}: what the app's parseChannel (its JSON schema
//          parser, parseJsonSchema, and its ROS 2 CDR reader) makes of each channel and
//          message, as the app does when a server advertises a channel ("Failed to parse
//          channel schema" in its Problems tab is this throwing).
//   node app.cjs threeDee
//       -> {drawn: [schema names the 3D panel subscribes to]}
//
// The functions are cut out of the bundle by name and run as they are; what they call
// in the branches used here (base64, the ROS message parser and CDR reader) is given
// from the same npm packages the app bundles.
"use strict";

const fs = require("node:fs");
const path = require("node:path");

const ASSETS = path.join(path.dirname(require.resolve("@foxglove/studio-base/package.json")),
  "assets");

function fail(message) {
  process.stderr.write(message + "\n");
  process.exit(3);
}

// The source text of `function NAME(...) {...}` in `text` (braces matched; strings,
// template literals and comments skipped).
function cutFunction(text, name) {
  const start = text.indexOf(`function ${name}(`);
  if (start < 0) fail(`function ${name} not found in the app's web build`);
  let i = text.indexOf("{", text.indexOf(")", start));
  let depth = 0;
  const stack = []; // template literal nesting
  for (; i < text.length; i++) {
    const c = text[i];
    if (c === '"' || c === "'") {
      for (i++; text[i] !== c; i++) if (text[i] === "\\") i++;
    } else if (c === "`") {
      stack.push(depth);
      for (i++; i < text.length; i++) {
        if (text[i] === "\\") { i++; continue; }
        if (text[i] === "`") { stack.pop(); break; }
        if (text[i] === "$" && text[i + 1] === "{") { i++; depth++; break; }
      }
    } else if (c === "/" && text[i + 1] === "/") {
      i = text.indexOf("\n", i);
    } else if (c === "/" && text[i + 1] === "*") {
      i = text.indexOf("*/", i) + 1;
    } else if (c === "{") {
      depth++;
    } else if (c === "}") {
      depth--;
      if (stack.length > 0 && depth === stack[stack.length - 1]) {
        // back inside a template literal
        for (i++; i < text.length; i++) {
          if (text[i] === "\\") { i++; continue; }
          if (text[i] === "`") { stack.pop(); break; }
          if (text[i] === "$" && text[i + 1] === "{") { i++; depth++; break; }
        }
        continue;
      }
      if (depth === 0) return text.slice(start, i + 1);
    }
  }
  return fail(`function ${name}: no end found`);
}

function bundle(predicate) {
  for (const name of fs.readdirSync(ASSETS)) {
    if (!name.endsWith(".js")) continue;
    const text = fs.readFileSync(path.join(ASSETS, name), "utf8");
    if (predicate(text)) return text;
  }
  return fail("no such chunk in the app's web build");
}

// ---------------------------------------------------------------- parseChannel

function appParseChannel() {
  const text = fs.readFileSync(path.join(ASSETS, "index.js"), "utf8");
  const source = ["parseJsonSchema", "parsedDefinitionsToDatatypes", "parseChannel"]
    .map((name) => cutFunction(text, name)).join("\n");
  const base64 = {
    length: (s) => Buffer.from(s, "base64").length,
    decode: (s, out, offset) => Buffer.from(s, "base64").copy(out, offset),
  };
  const rosmsg_dist = require("@foxglove/rosmsg");
  const rosmsg2_serialization_dist = require("@foxglove/rosmsg2-serialization");
  // eslint-disable-next-line no-new-func
  return new Function("base64", "rosmsg_dist", "rosmsg2_serialization_dist",
    `${source}\nreturn parseChannel;`)(base64, rosmsg_dist, rosmsg2_serialization_dist);
}

function plain(value) {
  if (typeof value === "bigint") return Number(value);
  if (ArrayBuffer.isView(value)) return Array.from(value, plain);
  if (Array.isArray(value)) return value.map(plain);
  if (value !== null && typeof value === "object") {
    const out = {};
    for (const [k, v] of Object.entries(value)) out[k] = plain(v);
    return out;
  }
  if (typeof value === "number" && !Number.isFinite(value)) return String(value);
  return value;
}

function channels(list) {
  const parseChannel = appParseChannel();
  const out = {};
  const textEncoder = new TextEncoder();
  for (const ch of list) {
    try {
      // As the app's Foxglove WebSocket player builds a channel from an advertisement.
      const parsed = parseChannel({
        messageEncoding: ch.encoding,
        schema: { name: ch.schemaName, encoding: ch.schemaEncoding,
          data: textEncoder.encode(ch.schema) },
      });
      const decoded = parsed.deserialize(Buffer.from(ch.message, "base64"));
      out[ch.topic] = { decoded: plain(decoded), datatypes: [...parsed.datatypes.keys()] };
    } catch (err) {
      out[ch.topic] = { error: String(err && err.message ? err.message : err) };
    }
  }
  return out;
}

// ---------------------------------------------------------------- the 3D panel

function threeDee() {
  const text = bundle((t) => t.includes("function addRosDataType("));
  const defs = [...text.matchAll(/const (\w+_DATATYPES) = new Set\(\);/g)].map((m) => m[1]);
  const adds = [...text.matchAll(/(addRosDataType|addFoxgloveSchema)\((\w+_DATATYPES), "([^"]+)"\);/g)];
  const subscribed = new Set([...text.matchAll(/addSchemaSubscriptions\((\w+_DATATYPES)/g)]
    .map((m) => m[1]));
  const source = [cutFunction(text, "addRosDataType"), cutFunction(text, "addFoxgloveSchema"),
    ...defs.map((d) => `const ${d} = new Set();`),
    ...adds.map((m) => `${m[1]}(${m[2]}, ${JSON.stringify(m[3])});`),
    `return {${defs.join(", ")}};`].join("\n");
  // eslint-disable-next-line no-new-func
  const sets = new Function(source)();
  const drawn = new Set();
  for (const name of subscribed) {
    if (sets[name] === undefined) fail(`${name} is subscribed but not defined`);
    for (const schema of sets[name]) drawn.add(schema);
  }
  return { drawn: [...drawn].sort() };
}

const mode = process.argv[2];
if (mode === "channels") {
  const input = fs.readFileSync(0, "utf8");
  process.stdout.write(JSON.stringify(channels(JSON.parse(input))) + "\n");
} else if (mode === "threeDee") {
  process.stdout.write(JSON.stringify(threeDee()) + "\n");
} else {
  fail("usage: node app.cjs channels|threeDee");
}
