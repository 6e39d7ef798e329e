// A @foxglove/ws-protocol client of a live `run --foxglove` (an outside reader): connects to
// ws://HOST:PORT, subscribes to TOPIC, decodes the first WANT messages with the channel's
// ros2msg schema (@foxglove/rosmsg + @foxglove/rosmsg2-serialization) and prints one JSON
// object: {"channels": [topics advertised], "schema": name, "encoding": e, "messages": [...]}.
// Retries the connection until TIMEOUT_S (the graph may still be starting); exit 1 with one
// line on stderr on timeout or a message that does not decode.
// Usage: node ws_client.mjs URL TOPIC [WANT] [TIMEOUT_S]
import WebSocket from "ws";
import wsProtocol from "@foxglove/ws-protocol";
import rosmsg from "@foxglove/rosmsg";
import serialization from "@foxglove/rosmsg2-serialization";

const { FoxgloveClient } = wsProtocol;
const { parse } = rosmsg;
const { MessageReader } = serialization;

const [url, topic, wantArg, timeoutArg] = process.argv.slice(2);
const want = Number(wantArg ?? 3);
const deadline = Date.now() + 1000 * Number(timeoutArg ?? 60);

function plain(value) {
  return JSON.parse(JSON.stringify(value, (_k, v) => {
    if (typeof v === "bigint") return Number(v);
    if (ArrayBuffer.isView(v)) return Array.from(v);
    if (typeof v === "number" && !Number.isFinite(v)) return String(v);
    return v;
  }));
}

function fail(text) {
  process.stderr.write(`ws_client: error: ${text}\n`);
  process.exit(1);
}

function attempt() {
  // the SDK's server speaks the protocol under its new name only (foxglove.sdk.v1, the same
  // messages as foxglove.websocket.v1, which this client library names)
  const ws = new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  const client = new FoxgloveClient({ ws });
  const advertised = [];
  const messages = [];
  let reader;
  let sub;
  let info;
  client.on("error", () => {});
  client.on("close", () => {
    if (messages.length < want) {
      if (Date.now() > deadline) fail(`no ${topic} message from ${url} in time`);
      setTimeout(attempt, 500);
    }
  });
  client.on("advertise", (channels) => {
    for (const ch of channels) {
      advertised.push(ch.topic);
      if (ch.topic === topic && sub === undefined) {
        if (ch.schemaEncoding !== "ros2msg" || ch.encoding !== "cdr") {
          fail(`${topic}: schema ${ch.schemaEncoding}, messages ${ch.encoding}`);
        }
        info = ch;
        reader = new MessageReader(parse(ch.schema, { ros2: true }));
        sub = client.subscribe(ch.id);
      }
    }
  });
  client.on("message", (event) => {
    if (event.subscriptionId !== sub || messages.length >= want) return;
    try {
      messages.push(plain(reader.readMessage(event.data)));
    } catch (err) {
      fail(`${topic}: ${err.message}`);
    }
    if (messages.length === want) {
      process.stdout.write(JSON.stringify({ channels: advertised, schema: info.schemaName,
        encoding: info.encoding, messages }) + "\n");
      process.exit(0);
    }
  });
}

setTimeout(() => fail(`no ${want} ${topic} messages from ${url} in time`),
  Math.max(0, deadline - Date.now()) + 1000);
attempt();
