import { describe, expect, it } from "vitest";
import { decode, decodeForce, encode } from "./transport/codec";
import { CART_INC, HELLO, JOINT_INC, PROTOCOL_VERSION } from "./transport/messages";

// Byte vectors made by the Python definitions (telerobot/protocol/messages.py).
const hex = (s: string) => new Uint8Array(s.match(/../g)!.map((b) => parseInt(b, 16))).buffer;
const CART =
  "0207000000000000000000f83f02fca9f1d24d62503ffca9f1d24d6260bffa7e6abc7493683f00000000000000009a9999999999b93f9a9999999999b9bf00";
const ERR = "850900000006006f7574736964652074686520776f726b7370616365";
const FORCE =
  "83010100050000000000000000000240000000000000f03f00000000000000400000000000000840000000000000104000000000000014400000000000001840";

// The joints are a tail of as many f64 as the arm has (WELCOME's joints): 6 and 5 here.
const JOINTS6 =
  "0303000000000000000000e03f009a9999999999b93f9a9999999999c9bf333333333333d33f00000000000000000000000000000000000000000000f83f";
const STATE5 =
  "820400000000000000000000400301000000000000e03f0000000000000000000000000000d03f000000000000f03f000000000000000000000000000000000000000000000000000000000000f03f000000000000000000000000000000000000000000000000000000000000f03f010000000000000000000000000000f03f000000000000f0bf000000000000e03f000000000000d03f";

describe("binary protocol", () => {
  it("carries as many joints as the arm has", () => {
    const out = encode(JOINT_INC, { seq: 3, client_time: 0.5, arm: 0, joints: [0.1, -0.2, 0.3, 0, 0, 1.5] });
    expect(new Uint8Array(out)).toEqual(new Uint8Array(hex(JOINTS6)));
    const state = decode(hex(STATE5));
    if (state.type !== "STATE") throw new Error(`decoded ${state.type}`);
    expect(state.joints).toEqual([0, 1, -1, 0.5, 0.25]);
    expect([state.x, state.z, state.flags]).toEqual([0.5, 0.25, 1]);
    expect(() => decode(hex(STATE5).slice(0, -3))).toThrow("partial joint");
  });

  it("encodes exactly as the server does", () => {
    const out = encode(CART_INC, { seq: 7, client_time: 1.5, frame: 2, dx: 0.001, dy: -0.002, dz: 0.003, rx: 0, ry: 0.1, rz: -0.1, arm: 0 });
    expect(new Uint8Array(out)).toEqual(new Uint8Array(hex(CART)));
  });

  it("decodes the server's messages", () => {
    expect(decode(hex(ERR))).toEqual({ type: "ERROR", seq: 9, code: 6, text: "outside the workspace" });
    const samples = [{ seq: 5, time: 2.25, values: [1, 2, 3, 4, 5, 6] }];
    expect(decodeForce(hex(FORCE))).toEqual(samples);
    expect(decode(hex(FORCE))).toEqual({ type: "FORCE", arm: 1, samples });
  });

  it("narrows the decoded union by its type", () => {
    const msg = decode(encode(HELLO, { version: PROTOCOL_VERSION, flags: 1, token: new TextEncoder().encode("abc") }));
    if (msg.type !== "HELLO") throw new Error(`decoded ${msg.type}`);
    expect([msg.version, msg.flags]).toEqual([PROTOCOL_VERSION, 1]);
    expect(new TextDecoder().decode(msg.token.subarray(0, 4))).toBe("abc\0");
    // @ts-expect-error: CART_INC has no field "dq1" (a renamed field fails to compile)
    encode(CART_INC, { seq: 1, client_time: 0, frame: 0, dx: 0, dy: 0, dz: 0, rx: 0, ry: 0, rz: 0, arm: 0, dq1: 0 });
  });

  it("refuses what it cannot read", () => {
    expect(() => decode(new ArrayBuffer(0))).toThrow("empty");
    expect(() => decode(new Uint8Array([0x7f]).buffer)).toThrow("unknown message type");
    expect(() => decode(new Uint8Array([0x86, 1]).buffer)).toThrow("too short");
    expect(() => decodeForce(new Uint8Array([0x83, 1, 2, 0]).buffer)).toThrow("wrong size");
  });
});
