// Decode EVERY message of a metro_atc bag with Foxglove's readers (an outside reader of
// `run --record`): @mcap/core reads the MCAP file (zstd chunks through fzstd), each
// channel's ros2msg schema is parsed by @foxglove/rosmsg and each message's CDR bytes are
// decoded by @foxglove/rosmsg2-serialization. Prints one JSON object on stdout:
//   {"topics": {topic: {"schema": name, "count": n}}, "total": n, "first": {topic: msg}}
// ("first": the first decoded message of a few topics, numbers as JSON numbers).
// Exit 1 with one line on stderr when a message does not decode or reads past its bytes.
// Usage: node decode_bag.mjs BAG_DIR_OR_MCAP_FILE
import { readFileSync, readdirSync, statSync } from "node:fs";
import { join } from "node:path";
import { McapStreamReader } from "@mcap/core";
import rosmsg from "@foxglove/rosmsg";
import serialization from "@foxglove/rosmsg2-serialization";
import { decompress } from "fzstd";

const { parse } = rosmsg;
const { MessageReader } = serialization;

const FIRST = new Set(["/line/layout", "/line/trains", "/line/status", "/train_01/state"]);

function mcapFile(path) {
  if (!statSync(path).isDirectory()) return path;
  const files = readdirSync(path).filter((f) => f.endsWith(".mcap"));
  if (files.length !== 1) throw new Error(`${path}: ${files.length} .mcap files (want 1)`);
  return join(path, files[0]);
}

function plain(value) {
  return JSON.parse(JSON.stringify(value, (_k, v) => {
    if (typeof v === "bigint") return Number(v);
    if (ArrayBuffer.isView(v)) return Array.from(v);
    if (typeof v === "number" && !Number.isFinite(v)) return String(v);
    return v;
  }));
}

function main(path) {
  const reader = new McapStreamReader({
    decompressHandlers: { zstd: (data, size) => decompress(data, new Uint8Array(Number(size))) },
  });
  reader.append(readFileSync(mcapFile(path)));
  const schemas = new Map();
  const channels = new Map();
  const topics = {};
  const first = {};
  let total = 0;
  for (let rec; (rec = reader.nextRecord()) !== undefined;) {
    if (rec.type === "Schema") {
      schemas.set(rec.id, rec);
    } else if (rec.type === "Channel") {
      const schema = schemas.get(rec.schemaId);
      if (schema === undefined || schema.encoding !== "ros2msg" ||
          rec.messageEncoding !== "cdr") {
        throw new Error(`${rec.topic}: schema ${schema?.encoding}, messages ${rec.messageEncoding}`);
      }
      const text = new TextDecoder().decode(schema.data);
      if (channels.has(rec.id)) continue; // repeated in the summary section
      channels.set(rec.id, { topic: rec.topic, schema: schema.name,
        reader: new MessageReader(parse(text, { ros2: true })) });
      if (rec.topic in topics) throw new Error(`${rec.topic}: two channels`);
      topics[rec.topic] = { schema: schema.name, count: 0 };
    } else if (rec.type === "Message") {
      const ch = channels.get(rec.channelId);
      if (ch === undefined) throw new Error(`message on unknown channel ${rec.channelId}`);
      let msg;
      try {
        msg = ch.reader.readMessage(rec.data);
      } catch (err) {
        throw new Error(`${ch.topic} message ${topics[ch.topic].count}: ${err.message}`);
      }
      if (msg === undefined || msg === null) throw new Error(`${ch.topic}: nothing decoded`);
      topics[ch.topic].count += 1;
      total += 1;
      if (FIRST.has(ch.topic) && !(ch.topic in first)) first[ch.topic] = plain(msg);
    }
  }
  if (!reader.done()) throw new Error("the MCAP file ends before its footer");
  process.stdout.write(JSON.stringify({ topics, total, first }) + "\n");
}

try {
  main(process.argv[2]);
} catch (err) {
  process.stderr.write(`decode_bag: error: ${err.message}\n`);
  process.exit(1);
}
