import { describe, expect, it } from "vitest";
import { GhostArm } from "./ar/ghost";
import type { Projection } from "./ar/projection";
import { PUMA } from "./puma.fixture";
import { PredictedArm, jointOrigins } from "./robot/model";
import { ServerArmReloader, RELOAD_TRIES, sameArm, type ServerArm } from "./robot/server-arm";
import { SO101 } from "./so101.fixture";

// A camera 2 m in front of the base looking back along −x (any P that sees both arms).
const P: Projection = [
  [0, -500, 0, 1000],
  [0, 0, -500, 1000],
  [-1, 0, 0, 2],
];
const CAMERAS = [
  { name: "left", P },
  { name: "right", P: P.map((row, i) => (i === 0 ? [row[0]!, row[1]!, row[2]!, row[3]! - 40] : row)) as Projection },
];
const IDENTITY = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
/** A one-arm server's arms (GET /robot/arms): "arm", at the origin. */
const oneArm = (model: typeof PUMA) => [{ name: "arm", index: 1, mount: IDENTITY, model }];
const pumaServer: ServerArm = { cameras: CAMERAS, arms: oneArm(PUMA) };
const so101Server: ServerArm = { cameras: CAMERAS, arms: oneArm(SO101) };

function reloader(start: ServerArm, answers: (ServerArm | Error)[]) {
  const applied: ServerArm[] = [];
  const log: [string, boolean][] = [];
  const read = () => {
    const a = answers.shift();
    if (!a) throw new Error("no more answers");
    return a instanceof Error ? Promise.reject(a) : Promise.resolve(a);
  };
  const r = new ServerArmReloader(start, read, (arm) => applied.push(arm), { add: (t, e = false) => log.push([t, e]) }, () => Promise.resolve());
  return { r, applied, log };
}

describe("the arm the page draws, after a new session", () => {
  it("is the new server's when it restarted with another model (PUMA → SO-101): applied, and said", async () => {
    const { r, applied, log } = reloader(pumaServer, [so101Server]);
    expect(await r.reload()).toBe(true);
    expect(applied).toEqual([so101Server]);
    expect(r.current.arms[0]!.model.joint_names).toEqual(SO101.joint_names); // the panels' labels
    expect(log[0]![0]).toContain("now drives the SO-101 (so101), not the PUMA 560 (puma560)");
  });

  it("and back again (SO-101 → PUMA)", async () => {
    const { r, applied } = reloader(so101Server, [pumaServer]);
    expect(await r.reload()).toBe(true);
    expect(applied.map((a) => a.arms[0]!.model.model)).toEqual(["puma560"]);
  });

  it("is left alone when the server's arm is the same (a reconnect to the same server)", async () => {
    const { r, applied, log } = reloader(pumaServer, [structuredClone(pumaServer)]);
    expect(await r.reload()).toBe(false);
    expect(applied).toEqual([]);
    expect(log).toEqual([]);
  });

  it("follows other cameras with the same arm (a calibration made meanwhile)", async () => {
    const moved: ServerArm = { cameras: [CAMERAS[0]!, { name: "right", P: CAMERAS[0]!.P }], arms: oneArm(PUMA) };
    expect(sameArm(pumaServer, moved)).toBe(false);
    const { r, applied } = reloader(pumaServer, [moved]);
    expect(await r.reload()).toBe(true);
    expect(applied).toEqual([moved]);
  });

  it("is read again when the server's HTTP side is not up yet, a bounded number of times, then says so", async () => {
    const ok = reloader(pumaServer, [new Error("503"), new Error("503"), so101Server]);
    expect(await ok.r.reload()).toBe(true);
    const never = reloader(pumaServer, Array.from({ length: RELOAD_TRIES + 3 }, () => new Error("connection refused")));
    expect(await never.r.reload()).toBe(false);
    expect(never.applied).toEqual([]);
    expect(never.log).toHaveLength(1);
    expect(never.log[0]![1]).toBe(true);
    expect(never.log[0]![0]).toContain("connection refused");
  });

  it("is the latest session's: an older reload answering late is not applied over it", async () => {
    let release: (a: ServerArm) => void = () => {};
    const slow = new Promise<ServerArm>((resolve) => (release = resolve));
    const answers = [slow, Promise.resolve(so101Server)];
    const applied: ServerArm[] = [];
    const r = new ServerArmReloader(pumaServer, () => answers.shift()!, (a) => applied.push(a), { add: () => {} });
    const first = r.reload();
    const second = r.reload();
    expect(await second).toBe(true);
    release(pumaServer); // the first session's answer, late
    expect(await first).toBe(false);
    expect(applied.map((a) => a.arms[0]!.model.model)).toEqual(["so101"]);
  });
});

describe("what is drawn from it", () => {
  it("the predicted arm starts again from the new arm's reported joints", () => {
    const arm = new PredictedArm(PUMA);
    arm.report([0, 0, 0, 0, 0, 0], false, 0);
    const pumaTool = arm.pose;
    arm.setModel(SO101);
    expect(arm.pose).toBeNull(); // not the PUMA's tool pose any more
    arm.report([0, 0, 0, 0, 0, 0], false, 1000);
    expect(arm.pose).not.toEqual(pumaTool);
    expect(arm.model).toBe(SO101);
  });

  it("the ghost's chain is the new arm's (the PUMA's 8 points, then the SO-101's 7)", () => {
    const ghost = new GhostArm(PUMA, CAMERAS);
    const q = [0, 0, 0, 0, 0, 0];
    ghost.update(q);
    expect(ghost.pixels.map((c) => c.length)).toEqual([jointOrigins(PUMA, q).length, jointOrigins(PUMA, q).length]);
    expect(ghost.setArm(SO101, CAMERAS)).toBe(true); // it was drawn: redraw
    expect(ghost.pixels).toEqual([[], []]);
    expect(ghost.update(q)).toBe(true);
    expect(ghost.pixels.map((c) => c.length)).toEqual([7, 7]);
  });
});
