// Encode and decode the binary messages described by the generated `messages.ts`.
import { FORCE, FORCE_SAMPLE_SIZE, MESSAGES, type MessageSpec } from "./messages";

export type FieldValue = number | Uint8Array;
export interface Decoded {
  spec: MessageSpec;
  fields: Record<string, number>;
  bytes: Record<string, Uint8Array>;
  text: string;
}
export interface ForceSample {
  seq: number;
  time: number;
  values: number[];
}

const BY_ID = new Map(MESSAGES.map((m) => [m.typeId, m]));
const utf8 = new TextEncoder();
const fromUtf8 = new TextDecoder();

export function encode(spec: MessageSpec, values: Record<string, FieldValue>, text = ""): ArrayBuffer {
  const tail = spec.tail === "text" ? utf8.encode(text) : new Uint8Array();
  const buffer = new ArrayBuffer(spec.size + tail.length);
  const view = new DataView(buffer);
  view.setUint8(0, spec.typeId);
  for (const f of spec.fields) {
    const v = values[f.name] ?? 0;
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
  new Uint8Array(buffer, spec.size).set(tail);
  return buffer;
}

export function decode(data: ArrayBuffer): Decoded {
  const view = new DataView(data);
  if (data.byteLength === 0) throw new Error("empty message");
  const spec = BY_ID.get(view.getUint8(0));
  if (!spec) throw new Error(`unknown message type 0x${view.getUint8(0).toString(16)}`);
  const fields: Record<string, number> = {};
  const bytes: Record<string, Uint8Array> = {};
  if (spec.tail !== "samples" && data.byteLength < spec.size) throw new Error(`${spec.name} is too short`);
  for (const f of spec.fields) {
    if (f.kind === "bytes") bytes[f.name] = new Uint8Array(data, f.offset, f.size);
    else if (f.kind === "u8") fields[f.name] = view.getUint8(f.offset);
    else if (f.kind === "u16") fields[f.name] = view.getUint16(f.offset, true);
    else if (f.kind === "u32") fields[f.name] = view.getUint32(f.offset, true);
    else fields[f.name] = view.getFloat64(f.offset, true);
  }
  const text = spec.tail === "text" ? fromUtf8.decode(new Uint8Array(data, spec.size)) : "";
  return { spec, fields, bytes, text };
}

export function decodeForce(data: ArrayBuffer): ForceSample[] {
  const view = new DataView(data);
  if (view.getUint8(0) !== FORCE.typeId) throw new Error("not a FORCE message");
  const count = view.getUint16(1, true);
  if (data.byteLength !== 3 + count * FORCE_SAMPLE_SIZE) throw new Error("FORCE has the wrong size");
  const out: ForceSample[] = [];
  for (let i = 0; i < count; i++) {
    const o = 3 + i * FORCE_SAMPLE_SIZE;
    const values = [];
    for (let k = 0; k < 6; k++) values.push(view.getFloat64(o + 12 + 8 * k, true));
    out.push({ seq: view.getUint32(o, true), time: view.getFloat64(o + 4, true), values });
  }
  return out;
}
