// Opens an MCAP file the way Foxglove does, with the libraries Foxglove is built on: the indexed
// reader of @mcap/core with @mcap/support's decompressors, ROS 2 .msg definitions parsed by
// @foxglove/rosmsg (ros2: true) and CDR decoded by @foxglove/rosmsg2-serialization, JSON by
// JSON.parse. Prints one JSON document: the header's profile and, per topic, the count, the
// schema and encodings, the first decoded message and every decoding error.
// Usage: node read_mcap.mjs FILE.mcap
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers } from "@mcap/support";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";

const file = process.argv[2];
const handle = await open(file, "r");
const result = { profile: null, library: null, topics: {}, errors: [] };
try {
  const reader = await McapIndexedReader.Initialize({
    readable: new FileHandleReadable(handle),
    decompressHandlers: await loadDecompressHandlers(),
  });
  result.profile = reader.header.profile;
  result.library = reader.header.library;
  const decoders = new Map();
  const text = new TextDecoder();
  const decoderFor = (channel) => {
    if (decoders.has(channel.id)) return decoders.get(channel.id);
    const schema = reader.schemasById.get(channel.schemaId);
    let decode;
    if (channel.messageEncoding === "cdr" && schema?.encoding === "ros2msg") {
      const definitions = parse(text.decode(schema.data), { ros2: true });
      const messageReader = new MessageReader(definitions);
      decode = (data) => messageReader.readMessage(data);
    } else if (channel.messageEncoding === "json") {
      decode = (data) => JSON.parse(text.decode(data));
    } else {
      throw new Error(`no decoder for message encoding ${channel.messageEncoding} with schema encoding ${schema?.encoding}`);
    }
    const entry = { decode, schema };
    decoders.set(channel.id, entry);
    return entry;
  };
  for await (const message of reader.readMessages()) {
    const channel = reader.channelsById.get(message.channelId);
    let topic = result.topics[channel.topic];
    if (!topic) {
      const schema = reader.schemasById.get(channel.schemaId);
      topic = result.topics[channel.topic] = {
        count: 0, schema: schema?.name ?? null, schemaEncoding: schema?.encoding ?? null,
        messageEncoding: channel.messageEncoding, first: null, errors: 0, firstError: null,
      };
    }
    topic.count += 1;
    try {
      const value = decoderFor(channel).decode(message.data);
      if (topic.first === null) topic.first = value;
    } catch (err) {
      topic.errors += 1;
      if (topic.firstError === null) topic.firstError = String(err);
    }
  }
} catch (err) {
  result.errors.push(String(err));
} finally {
  await handle.close();
}
const plain = (key, value) => (typeof value === "bigint" ? Number(value) : ArrayBuffer.isView(value) ? Array.from(value) : value);
process.stdout.write(JSON.stringify(result, plain) + "\n");
