// Decode Sparkplug B payloads with Eclipse Tahu's JavaScript codec (npm sparkplug-payload,
// pinned in package.json), not ropemon's: the proof that what the station publishes is read
// by the reference implementation.
//
// stdin: a JSON list of base64 payloads; stdout: a JSON list of the decoded payloads, each
// 64-bit integer (a Long) written as a decimal string, bytes as base64.
"use strict";
const Long = require("long");
const sparkplug = require("sparkplug-payload").get("spBv1.0");

function plain(v) {
  if (Long.isLong(v)) return v.toString();
  if (v instanceof Uint8Array) return Buffer.from(v).toString("base64");
  if (Array.isArray(v)) return v.map(plain);
  if (v !== null && typeof v === "object") {
    const out = {};
    for (const [k, x] of Object.entries(v)) out[k] = plain(x);
    return out;
  }
  return v;
}

let input = "";
process.stdin.setEncoding("utf8");
process.stdin.on("data", (chunk) => { input += chunk; });
process.stdin.on("end", () => {
  const payloads = JSON.parse(input);
  const out = payloads.map((b64) => plain(sparkplug.decodePayload(Buffer.from(b64, "base64"))));
  process.stdout.write(JSON.stringify(out));
});
