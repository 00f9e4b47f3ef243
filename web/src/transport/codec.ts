// Encode and decode the binary messages described by the generated `messages.ts`.
// Both are typed by the generated interfaces: `encode(CART_INC, {...})` needs exactly
// CART_INC's fields, and `decode` returns the union of decoded messages keyed by `type`.
import {
  FORCE,
  FORCE_SAMPLE_SIZE,
  MESSAGES,
  type FieldsOf,
  type ForceSample,
  type Message,
  type MessageName,
  type MessageSpec,
} from "./messages";

export type { ForceSample, Message } from "./messages";
export type FieldValue = number | Uint8Array;

const BY_ID = new Map<number, MessageSpec<MessageName>>(MESSAGES.map((m) => [m.typeId, m]));
const utf8 = new TextEncoder();
const fromUtf8 = new TextDecoder();

export function encode<N extends MessageName>(spec: MessageSpec<N>, values: FieldsOf<N>, text = ""): ArrayBuffer {
  const byName = values as unknown as Record<string, FieldValue | number[] | undefined>;
  const joints = spec.tail === "joints" ? ((byName.joints as number[] | undefined) ?? []) : [];
  const tail = spec.tail === "text" ? utf8.encode(text) : new Uint8Array(8 * joints.length);
  const buffer = new ArrayBuffer(spec.size + tail.length);
  const view = new DataView(buffer);
  view.setUint8(0, spec.typeId);
  for (const f of spec.fields) {
    const v = byName[f.name] ?? 0;
    if (f.kind === "bytes") {
      const bytes = v instanceof Uint8Array ? v : new Uint8Array();
      new Uint8Array(buffer, f.offset, f.size).set(bytes.subarray(0, f.size));
    } else if (typeof v === "number") {
      if (f.kind === "u8") view.setUint8(f.offset, v);
      else if (f.kind === "u16") view.setUint16(f.offset, v, true);
      else if (f.kind === "u32") view.setUint32(f.offset, v >>> 0, true);
      else view.setFloat64(f.offset, v, true);
    }
  }
  if (spec.tail === "joints") joints.forEach((q, i) => view.setFloat64(spec.size + 8 * i, q, true));
  else new Uint8Array(buffer, spec.size).set(tail);
  return buffer;
}

/** One message from the server (or any known type): its fields by name, `type` its name,
 * `text` for a message with a text tail, `samples` for FORCE. */
export function decode(data: ArrayBuffer): Message {
  const view = new DataView(data);
  if (data.byteLength === 0) throw new Error("empty message");
  const spec = BY_ID.get(view.getUint8(0));
  if (!spec) throw new Error(`unknown message type 0x${view.getUint8(0).toString(16)}`);
  if (spec.tail === "samples") return { type: "FORCE", arm: view.getUint8(1), samples: decodeForce(data) };
  if (data.byteLength < spec.size) throw new Error(`${spec.name} is too short`);
  // The layout table and the interfaces are generated from the same Python definitions:
  // the object built from the table is the interface of `spec.name`.
  const out: Record<string, FieldValue | string | number[]> = { type: spec.name };
  for (const f of spec.fields) {
    if (f.kind === "bytes") out[f.name] = new Uint8Array(data, f.offset, f.size);
    else if (f.kind === "u8") out[f.name] = view.getUint8(f.offset);
    else if (f.kind === "u16") out[f.name] = view.getUint16(f.offset, true);
    else if (f.kind === "u32") out[f.name] = view.getUint32(f.offset, true);
    else out[f.name] = view.getFloat64(f.offset, true);
  }
  if (spec.tail === "text") out.text = fromUtf8.decode(new Uint8Array(data, spec.size));
  if (spec.tail === "joints") {
    if ((data.byteLength - spec.size) % 8 !== 0) throw new Error(`${spec.name} has a partial joint`);
    const joints: number[] = [];
    for (let o = spec.size; o < data.byteLength; o += 8) joints.push(view.getFloat64(o, true));
    out.joints = joints;
  }
  return out as unknown as Message;
}

export function decodeForce(data: ArrayBuffer): ForceSample[] {
  const view = new DataView(data);
  if (view.getUint8(0) !== FORCE.typeId) throw new Error("not a FORCE message");
  // type (u8), arm (u8), count (u16), then the samples
  const head = FORCE.size + 2;
  if (data.byteLength < head) throw new Error("FORCE has the wrong size");
  const count = view.getUint16(FORCE.size, true);
  if (data.byteLength !== head + count * FORCE_SAMPLE_SIZE) throw new Error("FORCE has the wrong size");
  const out: ForceSample[] = [];
  for (let i = 0; i < count; i++) {
    const o = head + i * FORCE_SAMPLE_SIZE;
    const values = [];
    for (let k = 0; k < 6; k++) values.push(view.getFloat64(o + 12 + 8 * k, true));
    out.push({ seq: view.getUint32(o, true), time: view.getFloat64(o + 4, true), values });
  }
  return out;
}
