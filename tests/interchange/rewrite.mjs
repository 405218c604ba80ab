// Rewrites a railswitch recording with the TypeScript MCAP library, as another team's tool would: zstd chunks
// of 4 KiB, every JSON payload's keys in reverse order with a field railswitch does not know, and a /rosout
// channel of another schema encoding. tests/integration/test_interchange.py runs it.
// Usage: node rewrite.mjs IN.mcap OUT.mcap
import { readFile, writeFile } from "node:fs/promises";
import { McapStreamReader, McapWriter, TempBuffer } from "@mcap/core";
import zstd from "@foxglove/wasm-zstd";

const CHUNK_BYTES = 4096;
const EXTRA = { unit_serial: "PM-4711" };
const ROSOUT_EVERY = 50; // a foreign log message after every 50 of the recording's
const ROSOUT_SCHEMA = "byte FATAL=50\nbuiltin_interfaces/Time stamp\nuint8 level\nstring name\nstring msg\n";

// Integers past 2^53 would come back rounded from JSON.parse: refuse rather than change a time.
function checkSafe(value, path) {
  if (typeof value === "number" && Number.isInteger(value) && !Number.isSafeInteger(value)) {
    throw new Error(`${path} = ${value} is past 2^53 and would be rounded; rewrite simulated recordings only`);
  }
  if (value !== null && typeof value === "object") {
    for (const [key, item] of Object.entries(value)) checkSafe(item, `${path}.${key}`);
  }
}

function foreignPayload(data, topic) {
  const payload = JSON.parse(new TextDecoder().decode(data));
  checkSafe(payload, topic);
  const reversed = Object.fromEntries(Object.entries(payload).reverse());
  return new TextEncoder().encode(JSON.stringify({ ...reversed, ...EXTRA }));
}

async function main([input, output]) {
  if (!input || !output) throw new Error("usage: node rewrite.mjs IN.mcap OUT.mcap");
  await zstd.isLoaded;
  const reader = new McapStreamReader({
    decompressHandlers: { zstd: (data, size) => zstd.decompress(data, Number(size)) },
  });
  reader.append(await readFile(input));
  const buffer = new TempBuffer();
  const writer = new McapWriter({
    writable: buffer,
    chunkSize: CHUNK_BYTES,
    compressChunk: (data) => ({ compression: "zstd", compressedData: zstd.compress(data) }),
  });
  await writer.start({ profile: "", library: "railswitch interchange test (@mcap/core)" });
  const rosoutSchema = await writer.registerSchema({
    name: "rcl_interfaces/msg/Log", encoding: "ros2msg", data: new TextEncoder().encode(ROSOUT_SCHEMA),
  });
  const rosout = await writer.registerChannel({
    topic: "/rosout", messageEncoding: "cdr", schemaId: rosoutSchema, metadata: new Map(),
  });
  const schemas = new Map(); // source id -> our id (0: a channel without schema)
  const channels = new Map(); // source id -> { id, topic }
  let count = 0;
  for (let record; (record = reader.nextRecord()); ) {
    if (record.type === "Schema" && !schemas.has(record.id)) {
      schemas.set(record.id, await writer.registerSchema({ name: record.name, encoding: record.encoding, data: record.data }));
    } else if (record.type === "Channel" && !channels.has(record.id)) {
      const id = await writer.registerChannel({
        topic: record.topic, messageEncoding: record.messageEncoding, schemaId: schemas.get(record.schemaId) ?? 0,
        metadata: record.metadata,
      });
      channels.set(record.id, { id, topic: record.topic });
    } else if (record.type === "Message") {
      const channel = channels.get(record.channelId);
      await writer.addMessage({ ...record, channelId: channel.id, data: foreignPayload(record.data, channel.topic) });
      if (++count % ROSOUT_EVERY === 0) {
        await writer.addMessage({
          channelId: rosout, sequence: count, logTime: record.logTime, publishTime: record.logTime,
          data: new Uint8Array([0, 1, 0, 0, 20, 0, 0, 0]),
        });
      }
    }
  }
  if (!reader.done()) throw new Error(`${input} ends inside a record`);
  await writer.end();
  await writeFile(output, buffer.get());
  console.log(`wrote ${output}: ${count} messages and ${Math.floor(count / ROSOUT_EVERY)} on /rosout`);
}

main(process.argv.slice(2)).catch((error) => {
  console.error(`rewrite.mjs: ${error.message}`);
  process.exit(1);
});
