// A viewer that subscribes to every channel of a live `run --foxglove` (or to the TOPICs
// given) and counts what it receives, until the server goes away: the load a viewer puts on
// the graph, to measure the live view's cost to the lockstep. Prints {"messages": n,
// "bytes": b}. Usage: node ws_all.mjs URL [TIMEOUT_S [TOPIC...]]
import WebSocket from "ws";
import wsProtocol from "@foxglove/ws-protocol";

const { FoxgloveClient } = wsProtocol;
const [url, timeoutArg, ...only] = process.argv.slice(2);
const deadline = Date.now() + 1000 * Number(timeoutArg ?? 60);
let messages = 0;
let bytes = 0;
let opened = false;

function attempt() {
  const ws = new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  const client = new FoxgloveClient({ ws });
  client.on("error", () => {});
  client.on("open", () => { opened = true; });
  client.on("advertise", (channels) => {
    for (const ch of channels) {
      if (only.length === 0 || only.includes(ch.topic)) client.subscribe(ch.id);
    }
  });
  client.on("message", (event) => { messages += 1; bytes += event.data.byteLength; });
  client.on("close", () => {
    if (!opened && Date.now() < deadline) { setTimeout(attempt, 200); return; }
    process.stdout.write(JSON.stringify({ messages, bytes }) + "\n");
    process.exit(opened ? 0 : 1);
  });
}
attempt();
