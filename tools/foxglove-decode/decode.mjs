// Decode every message of an MCAP file the way Foxglove does: @mcap/core reads the records,
// @foxglove/rosmsg parses each ros2msg schema, @foxglove/rosmsg2-serialization decodes the CDR.
// Usage: node decode.mjs FILE.mcap  ->  JSON on stdout:
//   {"messages": N, "decoded": N, "topics": {topic: {"schema", "messages", "decoded", "error"}},
//    "metadata": [names], "channel_metadata": {topic: {key: value}}}
import { readFileSync } from "node:fs";

import { McapStreamReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import { decompress } from "fzstd";

const path = process.argv[2];
if (!path) {
  console.error("usage: node decode.mjs FILE.mcap");
  process.exit(2);
}

const reader = new McapStreamReader({
  decompressHandlers: { zstd: (data, size) => decompress(data, new Uint8Array(Number(size))) },
  validateCrcs: true,
});
reader.append(readFileSync(path));

const schemas = new Map(); // schema id -> {name, reader | error}
const channels = new Map(); // channel id -> {topic, schemaId}
const out = { messages: 0, decoded: 0, topics: {}, metadata: [], channel_metadata: {} };
const text = new TextDecoder();

for (let record; (record = reader.nextRecord()) !== undefined; ) {
  if (record.type === "Schema") {
    const entry = { name: record.name };
    try {
      if (record.encoding !== "ros2msg") throw new Error(`schema encoding ${record.encoding}`);
      entry.reader = new MessageReader(parse(text.decode(record.data), { ros2: true }));
    } catch (err) {
      entry.error = `schema: ${err.message}`;
    }
    schemas.set(record.id, entry);
  } else if (record.type === "Channel") {
    channels.set(record.id, { topic: record.topic, schemaId: record.schemaId });
    out.channel_metadata[record.topic] = Object.fromEntries(record.metadata);
  } else if (record.type === "Metadata") {
    out.metadata.push(record.name);
  } else if (record.type === "Message") {
    const channel = channels.get(record.channelId);
    const schema = schemas.get(channel.schemaId);
    const topic = (out.topics[channel.topic] ??= { schema: schema.name, messages: 0, decoded: 0, error: null });
    topic.messages += 1;
    out.messages += 1;
    try {
      if (!schema.reader) throw new Error(schema.error);
      schema.reader.readMessage(record.data);
      topic.decoded += 1;
      out.decoded += 1;
    } catch (err) {
      topic.error ??= err.message;
    }
  }
}
if (!reader.done()) {
  console.error(`${path}: the file ended inside a record`);
  process.exit(1);
}
process.stdout.write(JSON.stringify(out) + "\n");
