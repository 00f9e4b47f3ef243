import { afterEach, describe, expect, it, vi } from "vitest";
import { Rolling } from "./stats";
import {
  CLOCK_ERROR_AMBER_MS,
  CLOCK_ERROR_RED_MS,
  COMMAND_AGE_AMBER_MS,
  COMMAND_AGE_RED_MS,
  COMMAND_IDLE_MS,
  ConnectionHud,
  FORCE_AGE_AMBER_MS,
  FORCE_AGE_RED_MS,
  PLAYOUT_AMBER_MS,
  FREEZE_MS,
  FREEZE_WINDOW_MS,
  FREEZES_RED,
  FROZEN_RED_MS,
  FreezeCounter,
  LOSS_AMBER_PERCENT,
  LOSS_RED_PERCENT,
  RTT_AMBER_MS,
  RTT_RED_MS,
  STATS_WINDOW_MS,
  drawHud,
  fpsLimits,
  layerOf,
  hudView,
  readVideoStats,
  videoRates,
  type HudFigures,
  type HudKey,
  type HudRow,
  type HudView,
} from "./ui/connection-hud";

// A healthy loopback link: the figures the browser test sees.
const good: HudFigures = {
  videoUp: true,
  videoRttMs: 0.6,
  pingRttMs: 0.4,
  lossPercent: 0,
  fps: 30,
  nominalFps: 30,
  bitrateKbps: 2400,
  layer: "full",
  frameSize: "1280×360",
  sinceFrameMs: 20,
  freezes: 0,
  longestFreezeMs: 0,
  linkOpen: true,
  synced: true,
  offsetMs: 12.5,
  forceAgeMs: 8,
  commandAgeMs: null,
  commandSeenAgoMs: null,
};

const view = (over: Partial<HudFigures> = {}) => hudView({ ...good, ...over });
const row = (over: Partial<HudFigures>, key: HudKey): HudRow => {
  const r = view(over).rows.find((x) => x.key === key);
  if (!r) throw new Error(`no ${key} row`);
  return r;
};

describe("the connection HUD's rows", () => {
  it("a healthy link: every row ok, the figures shown", () => {
    const v = view();
    expect(v.level).toBe("ok");
    expect(v.reason).toBe("");
    expect(v.rows.map((r) => r.key)).toEqual(["rtt", "loss", "video", "freezes", "playout", "force", "command", "clock"]);
    expect(v.rows.every((r) => r.level === "ok")).toBe(true);
    expect(row({}, "rtt").text).toBe("video 0.6 ms · ping 0.4 ms");
    expect(row({}, "video").text).toBe("30 fps · 2400 kbit/s · full 1280×360");
    expect(row({}, "force").text).toBe("8.0 ms");
    expect(row({}, "command").text).toBe("— (no command yet)");
    expect(row({}, "clock").text).toBe("+12.5 ms ± 0.2 ms");
    expect(row({ offsetMs: -1_234_567 }, "clock").text).toBe("−1234.567 s ± 0.2 ms");
    expect(row({}, "freezes").text).toBe("none in 10 s");
    for (const r of v.rows) expect(r.limits.length).toBeGreaterThan(10); // the tooltip says the thresholds
  });

  it("RTT: amber over 100 ms, red over 250 ms, judged by the slower of video and ping", () => {
    expect(row({ videoRttMs: RTT_AMBER_MS }, "rtt").level).toBe("ok");
    expect(row({ videoRttMs: RTT_AMBER_MS + 1 }, "rtt")).toMatchObject({ level: "amber", text: "video 101 ms · ping 0.4 ms (> 100 ms)" });
    expect(row({ pingRttMs: RTT_RED_MS }, "rtt").level).toBe("amber");
    expect(row({ pingRttMs: RTT_RED_MS + 1 }, "rtt")).toMatchObject({ level: "red", text: "video 0.6 ms · ping 251 ms (> 250 ms)" });
    expect(row({ videoRttMs: null, pingRttMs: 3 }, "rtt")).toMatchObject({ level: "ok", text: "ping 3.0 ms" });
    expect(row({ videoRttMs: null, pingRttMs: null }, "rtt")).toMatchObject({ level: "amber", text: "not measured yet" });
  });

  it("loss: amber over 1 %, red over 5 %; none measured is not an alarm", () => {
    expect(row({ lossPercent: LOSS_AMBER_PERCENT }, "loss").level).toBe("ok");
    expect(row({ lossPercent: 2.5 }, "loss")).toMatchObject({ level: "amber", text: "2.5 % (> 1 %)" });
    expect(row({ lossPercent: LOSS_RED_PERCENT + 0.1 }, "loss")).toMatchObject({ level: "red", text: "5.1 % (> 5 %)" });
    expect(row({ lossPercent: null }, "loss")).toMatchObject({ level: "ok", text: "—" });
  });

  it("video rate: amber below 20 fps, red below 10; a server sending fewer is judged against its own rate", () => {
    expect(fpsLimits(30)).toEqual({ amber: 20, red: 10 });
    expect(fpsLimits(null)).toEqual({ amber: 20, red: 10 });
    expect(fpsLimits(20)).toEqual({ amber: 15, red: 10 });
    expect(fpsLimits(10)).toEqual({ amber: 7.5, red: 5 });
    expect(row({ fps: 20 }, "video").level).toBe("ok");
    expect(row({ fps: 19 }, "video")).toMatchObject({ level: "amber", text: "19 fps of 30 (< 20) · 2400 kbit/s · full 1280×360" });
    expect(row({ fps: 9 }, "video")).toMatchObject({ level: "red", text: "9 fps of 30 (< 10) · 2400 kbit/s · full 1280×360" });
    expect(row({ fps: 19, nominalFps: 20 }, "video").level).toBe("ok"); // the test server's 20 fps
    expect(row({ fps: 14, nominalFps: 20 }, "video").level).toBe("amber");
  });

  it("video frozen: amber past 200 ms without a new frame, red past 500 ms, with how long", () => {
    expect(row({ sinceFrameMs: FREEZE_MS }, "video").level).toBe("ok");
    expect(row({ sinceFrameMs: FREEZE_MS + 50 }, "video")).toMatchObject({ level: "amber", text: "frozen: no new frame for 0.3 s" });
    expect(row({ sinceFrameMs: FROZEN_RED_MS + 700 }, "video")).toMatchObject({ level: "red", text: "frozen: no new frame for 1.2 s" });
    expect(row({ videoUp: false }, "video")).toMatchObject({ level: "red", text: "no video peer (reconnecting)" });
    expect(row({ sinceFrameMs: null }, "video")).toMatchObject({ level: "amber", text: "waiting for the first frame" });
  });

  it("shows the layer with the picture's size", () => {
    expect(row({ layer: "low", frameSize: "1280×360" }, "video").text).toContain("low 1280×360");
    expect(row({ frameSize: null }, "video").text).toBe("30 fps · 2400 kbit/s · full");
  });

  it("the layer is read from the picture's width against the server's full one", () => {
    expect(layerOf(2560, 1280)).toBe("full");
    expect(layerOf(1280, 1280)).toBe("low"); // half each way
    expect(layerOf(null, 1280)).toBe("—"); // no frame yet
    expect(layerOf(1280, null)).toBe("full"); // the server's size unknown: nothing to compare
  });

  it("freezes: one in 10 s is amber, three red", () => {
    expect(row({ freezes: 1, longestFreezeMs: 450 }, "freezes")).toMatchObject({ level: "amber", text: "1 in 10 s (longest 0.5 s)" });
    expect(row({ freezes: FREEZES_RED - 1, longestFreezeMs: 300 }, "freezes").level).toBe("amber");
    expect(row({ freezes: FREEZES_RED, longestFreezeMs: 300 }, "freezes").level).toBe("red");
    expect(row({ decoderFreezes: 2, decoderFreezeS: 0.84 }, "freezes").text).toBe("none in 10 s · decoder 2 (0.8 s)");
  });

  it("force age: amber over 50 ms, red over 200 ms; a dead link or no samples is red", () => {
    expect(row({ forceAgeMs: FORCE_AGE_AMBER_MS }, "force").level).toBe("ok");
    expect(row({ forceAgeMs: 80 }, "force")).toMatchObject({ level: "amber", text: "80 ms (> 50 ms)" });
    expect(row({ forceAgeMs: FORCE_AGE_RED_MS + 1 }, "force")).toMatchObject({ level: "red", text: "201 ms (> 200 ms)" });
    expect(row({ forceAgeMs: 3400 }, "force")).toMatchObject({ level: "red", text: "no new sample for 3.4 s (> 200 ms)" });
    expect(row({ forceAgeMs: null }, "force")).toMatchObject({ level: "red", text: "no force samples yet" });
    expect(row({ linkOpen: false }, "force")).toMatchObject({ level: "red", text: "realtime link down" });
    expect(row({ synced: false }, "force")).toMatchObject({ level: "amber", text: "waiting for the clock sync" });
  });

  it("command age: amber over 100 ms, red over 250 ms (the server's max command age); idle after 5 s", () => {
    const driving = { commandSeenAgoMs: 100 };
    expect(row({ ...driving, commandAgeMs: 1.25 }, "command")).toMatchObject({ level: "ok", text: "1.3 ms" });
    expect(row({ ...driving, commandAgeMs: COMMAND_AGE_AMBER_MS }, "command").level).toBe("ok");
    expect(row({ ...driving, commandAgeMs: 120 }, "command")).toMatchObject({ level: "amber", text: "120 ms (> 100 ms)" });
    expect(row({ ...driving, commandAgeMs: COMMAND_AGE_RED_MS + 10 }, "command")).toMatchObject({ level: "red", text: "260 ms (> 250 ms)" });
    expect(row({ commandAgeMs: 300, commandSeenAgoMs: COMMAND_IDLE_MS + 1 }, "command")).toMatchObject({ level: "ok", text: "idle (last 300 ms)" });
  });

  it("the clock offset is judged by how exactly it is known (± half the best ping), not by its size", () => {
    expect(row({ offsetMs: 1e9 }, "clock").level).toBe("ok"); // a server up for days: fine
    expect(row({ pingRttMs: 2 * CLOCK_ERROR_AMBER_MS }, "clock").level).toBe("ok");
    expect(row({ pingRttMs: 2 * CLOCK_ERROR_AMBER_MS + 2 }, "clock")).toMatchObject({ level: "amber", text: "+12.5 ms ± 26 ms (> ± 25 ms)" });
    expect(row({ pingRttMs: 2 * CLOCK_ERROR_RED_MS + 2 }, "clock")).toMatchObject({ level: "red", text: "+12.5 ms ± 101 ms (> ± 100 ms)" });
    expect(row({ pingRttMs: 2 * CLOCK_ERROR_RED_MS + 2 }, "clock").limits).toContain("its size is arbitrary");
    expect(row({ synced: false }, "clock")).toMatchObject({ level: "amber", text: "not synced yet" });
  });

  it("the HUD is as bad as its worst row, and says why, worst first", () => {
    expect(view({ lossPercent: 2 }).level).toBe("amber");
    const v = view({ lossPercent: 2, forceAgeMs: 500 });
    expect(v.level).toBe("red");
    expect(v.reason).toBe("force age: 500 ms (> 200 ms); loss: 2.0 % (> 1 %)");
  });
});

describe("reading getStats()", () => {
  const report = (over: Record<string, unknown> = {}) => [
    { type: "inbound-rtp", id: "a", kind: "audio", bytesReceived: 1e9 },
    { type: "inbound-rtp", id: "v", kind: "video", framesDecoded: 100, bytesReceived: 500_000, packetsLost: 2, packetsReceived: 998, frameWidth: 1280, frameHeight: 360, freezeCount: 1, totalFreezesDuration: 0.4, ...over },
    { type: "transport", id: "t", selectedCandidatePairId: "p2" },
    { type: "candidate-pair", id: "p1", nominated: true, state: "succeeded", currentRoundTripTime: 0.5 },
    { type: "candidate-pair", id: "p2", nominated: true, state: "succeeded", currentRoundTripTime: 0.002 },
  ];

  it("takes the inbound video stream and the transport's selected candidate pair", () => {
    const s = readVideoStats(report(), 1000);
    expect(s).toMatchObject({ at: 1000, framesDecoded: 100, bytesReceived: 500_000, packetsLost: 2, packetsReceived: 998, frameWidth: 1280, freezeCount: 1, totalFreezesDuration: 0.4, rttS: 0.002 });
    expect(s.framesPerSecond).toBeNull();
    // Without a transport entry: the nominated, succeeded pair.
    expect(readVideoStats(report().filter((x) => x.type !== "transport" && x.id !== "p2"), 0).rttS).toBe(0.5);
    expect(readVideoStats([], 0)).toMatchObject({ framesDecoded: null, rttS: null });
  });

  it("rates over the window: frames, kbit/s, loss", () => {
    const a = readVideoStats(report(), 0);
    const b = readVideoStats(report({ framesDecoded: 140, bytesReceived: 1_000_000, packetsLost: 12, packetsReceived: 1988 }), STATS_WINDOW_MS);
    expect(videoRates(a, b)).toEqual({ fps: 20, kbps: 2000, lossPercent: 1, playoutMs: null });
    // framesPerSecond (Chromium's, over the last second) wins when there is one.
    expect(videoRates(a, { ...b, framesPerSecond: 24 }).fps).toBe(24);
    // The first sample: no rates yet; no packets: no loss figure; duplicates are not negative loss.
    expect(videoRates(undefined, b)).toEqual({ fps: null, kbps: null, lossPercent: null, playoutMs: null });
    expect(videoRates(a, { ...a, at: 1000 }).lossPercent).toBeNull();
    expect(videoRates(a, { ...b, packetsLost: 0 }).lossPercent).toBe(0);
  });
});

describe("the playout delay and FEC", () => {
  const stats = (over: Record<string, unknown>) => [{ type: "inbound-rtp", kind: "video", ...over }];

  it("is the time each frame of the window spent in the jitter buffer, and FEC's counts", () => {
    const a = readVideoStats(stats({ jitterBufferDelay: 1.0, jitterBufferEmittedCount: 100, fecPacketsReceived: 10, fecPacketsDiscarded: 2 }), 0);
    const b = readVideoStats(stats({ jitterBufferDelay: 13.0, jitterBufferEmittedCount: 140, fecPacketsReceived: 30, fecPacketsDiscarded: 5 }), STATS_WINDOW_MS);
    expect(videoRates(a, b).playoutMs).toBe(300); // 12 s over 40 frames
    expect(videoRates(a, { ...b, jitterBufferEmittedCount: 100 }).playoutMs).toBeNull(); // no frame: no figure
    expect(b).toMatchObject({ fecPacketsReceived: 30, fecPacketsDiscarded: 5 });
  });

  it("is amber while frames are held long enough to lag the picture, and says what FEC did", () => {
    expect(row({ playoutMs: 0 }, "playout")).toMatchObject({ level: "ok", text: "0.0 ms" });
    expect(row({ playoutMs: PLAYOUT_AMBER_MS + 80, fecPackets: 120, fecUsed: 30 }, "playout")).toMatchObject({
      level: "amber",
      text: `230 ms (> ${PLAYOUT_AMBER_MS} ms) · FEC 120 packets, 30 used`,
    });
    expect(row({ playoutMs: null }, "playout")).toMatchObject({ level: "ok", text: "—" });
  });

  it("says the server's cap: a repair longer than it is not waited for", () => {
    expect(row({ playoutMs: 120, playoutCapMs: 300 }, "playout")).toMatchObject({ level: "ok", text: "120 ms · cap 300 ms" });
  });
});

describe("freezes as the page sees them", () => {
  it("counts gaps over 200 ms between frames for 10 s, and says how long it has been", () => {
    const f = new FreezeCounter();
    expect(f.since(0)).toBeNull();
    for (let t = 0; t <= 1000; t += 50) f.frame(t);
    expect(f.window(1000).count).toBe(0);
    f.frame(1000 + FREEZE_MS); // exactly the limit: not a freeze
    expect(f.window(1200).count).toBe(0);
    expect(f.since(1500)).toBe(300);
    f.frame(1900); // 700 ms without a frame
    expect(f.window(1900)).toEqual({ count: 1, longestMs: 700 });
    expect(f.window(1900 + FREEZE_WINDOW_MS + 1).count).toBe(0);
    expect(f.total).toBe(1);
  });
});

describe("the collector", () => {
  function fakePc(frames: { n: number }) {
    return {
      connectionState: "connected",
      getStats: () =>
        Promise.resolve(
          new Map<string, Record<string, unknown>>([
            ["v", { type: "inbound-rtp", kind: "video", framesDecoded: frames.n, bytesReceived: frames.n * 10_000, packetsLost: 0, packetsReceived: frames.n * 5, frameWidth: 2560, frameHeight: 720 }],
            ["p", { type: "candidate-pair", id: "p", nominated: true, state: "succeeded", currentRoundTripTime: 0.001 }],
          ]),
        ),
    } as unknown as RTCPeerConnection;
  }

  it("turns the peer's counters, the link's figures and the newest force sample into rows", async () => {
    const frames = { n: 0 };
    const pc = fakePc(frames);
    const commandLatency = new Rolling();
    const link = { open: true, bestRtt: 0.0004, offset: 100, commandLatency };
    let force = { time: 100 + 0.99 }; // page time 1.0 s = server time 101.0 s: 10 ms old
    const hud = new ConnectionHud({ pc: () => pc, link, force: () => force, video: Promise.resolve({ fps: 20, width: 1280 }) });
    await Promise.resolve();
    for (let t = 0; t <= 1000; t += 50) hud.frame(t);
    await hud.update(500);
    frames.n = 10;
    const v = await hud.update(1000);
    expect(hud.figures).toMatchObject({ fps: 20, bitrateKbps: 1600, lossPercent: 0, videoRttMs: 1, pingRttMs: 0.4, offsetMs: 100_000, nominalFps: 20 });
    expect(hud.figures?.forceAgeMs).toBeCloseTo(10, 6);
    expect(v.reason).toBe("");
    expect(hud.level).toBe("ok");
    expect(hud.rows.find((r) => r.key === "video")?.text).toBe("20 fps · 1600 kbit/s · full 2560×720");

    // The force stream stops: its age grows on the server's clock.
    commandLatency.add(3);
    await hud.update(1300);
    expect(hud.rows.find((r) => r.key === "command")?.text).toBe("3.0 ms");
    force = { time: 100.99 };
    await hud.update(2000);
    expect(hud.level).toBe("red");
    expect(hud.reason).toContain("force age: no new sample for 1.0 s");
    expect(hud.reason).toContain("video: frozen: no new frame for 1.0 s");
  });

  it("with no peer: video red; a new peer's counters start afresh, the gap across it is a freeze", async () => {
    let pc: RTCPeerConnection | null = fakePc({ n: 50 });
    const hud = new ConnectionHud({ pc: () => pc, link: { open: true, bestRtt: 0.001, offset: 0, commandLatency: new Rolling() }, force: () => ({ time: 0 }) });
    hud.frame(0);
    await hud.update(0);
    pc = null;
    await hud.update(500);
    expect(hud.rows.find((r) => r.key === "video")).toMatchObject({ level: "red", text: "no video peer (reconnecting)" });
    pc = fakePc({ n: 5 }); // counters from zero: no rate against the old peer's 50 frames
    hud.frame(2500);
    await hud.update(2500);
    expect(hud.figures).toMatchObject({ fps: null, bitrateKbps: null, freezes: 1, longestFreezeMs: 2500 });
    expect(hud.rows.find((r) => r.key === "freezes")).toMatchObject({ level: "amber", text: "1 in 10 s (longest 2.5 s)" });
  });
});

describe("each row's amber and red, with the reason the HUD gives", () => {
  // One row off at a time, on the healthy link's figures: the box takes that row's
  // level, and its reason is exactly that row's label and text.
  const cases: [string, Partial<HudFigures>, "amber" | "red", string][] = [
    ["RTT amber", { videoRttMs: 150 }, "amber", "RTT: video 150 ms · ping 0.4 ms (> 100 ms)"],
    ["RTT red", { videoRttMs: 300 }, "red", "RTT: video 300 ms · ping 0.4 ms (> 250 ms)"],
    ["clock known roughly", { pingRttMs: 60 }, "amber", "clock offset: +12.5 ms ± 30 ms (> ± 25 ms)"],
    ["RTT unmeasured", { videoRttMs: null, pingRttMs: null }, "amber", "RTT: not measured yet"],
    ["loss amber", { lossPercent: 2.5 }, "amber", "loss: 2.5 % (> 1 %)"],
    ["loss red", { lossPercent: 7 }, "red", "loss: 7.0 % (> 5 %)"],
    ["video slow", { fps: 14, nominalFps: 20 }, "amber", "video: 14 fps of 20 (< 15) · 2400 kbit/s · full 1280×360"],
    ["video very slow", { fps: 8, nominalFps: 20 }, "red", "video: 8 fps of 20 (< 10) · 2400 kbit/s · full 1280×360"],
    ["video paused", { sinceFrameMs: 300 }, "amber", "video: frozen: no new frame for 0.3 s"],
    ["video frozen", { sinceFrameMs: 2000 }, "red", "video: frozen: no new frame for 2.0 s"],
    ["video peer dropped", { videoUp: false }, "red", "video: no video peer (reconnecting)"],
    ["video not started", { sinceFrameMs: null }, "amber", "video: waiting for the first frame"],
    ["one freeze", { freezes: 1, longestFreezeMs: 300 }, "amber", "freezes: 1 in 10 s (longest 0.3 s)"],
    ["freezes", { freezes: 3, longestFreezeMs: 300 }, "red", "freezes: 3 in 10 s (longest 0.3 s)"],
    ["force late", { forceAgeMs: 80 }, "amber", "force age: 80 ms (> 50 ms)"],
    ["force stopped", { forceAgeMs: 2500 }, "red", "force age: no new sample for 2.5 s (> 200 ms)"],
    ["no force", { forceAgeMs: null }, "red", "force age: no force samples yet"],
    ["link cut", { linkOpen: false }, "red", "force age: realtime link down"],
    ["command late", { commandAgeMs: 120, commandSeenAgoMs: 10 }, "amber", "command age: 120 ms (> 100 ms)"],
    ["command stale", { commandAgeMs: 300, commandSeenAgoMs: 10 }, "red", "command age: 300 ms (> 250 ms)"],
  ];
  it.each(cases)("%s", (_, over, level, reason) => {
    const v = view(over);
    expect(v.level).toBe(level);
    expect(v.reason).toBe(reason);
    expect(v.rows.filter((r) => r.level !== "ok")).toHaveLength(1);
  });

  it("not synced yet: the force row and the clock row wait, amber", () => {
    const v = view({ synced: false });
    expect(v.level).toBe("amber");
    expect(v.reason).toBe("force age: waiting for the clock sync; clock offset: not synced yet");
  });

  it("red rows come before amber ones, each level in the box's order", () => {
    const v = view({ videoRttMs: 150, lossPercent: 2, forceAgeMs: 900, videoUp: false });
    expect(v.level).toBe("red");
    expect(v.reason).toBe("video: no video peer (reconnecting); force age: 900 ms (> 200 ms); RTT: video 150 ms · ping 0.4 ms (> 100 ms); loss: 2.0 % (> 1 %)");
  });
});

describe("the box drawn", () => {
  // No DOM under vitest (node): the few element members drawHud uses.
  class El {
    className = "";
    title = "";
    textContent = "";
    dataset: Record<string, string> = {};
    children: El[] = [];
    append(...c: El[]) {
      this.children.push(...c);
    }
    replaceChildren(...c: El[]) {
      this.children = c;
    }
  }
  afterEach(() => vi.unstubAllGlobals());
  const draw = (v: HudView): El => {
    vi.stubGlobal("document", { createElement: () => new El() });
    const box = new El();
    drawHud(box as unknown as HTMLElement, v);
    return box;
  };

  it("green, titled ok, one line per row with its level, key and thresholds", () => {
    const v = view();
    const box = draw(v);
    expect(box.className).toBe("hud-ok");
    expect(box.title).toBe("connection ok");
    expect(box.children[0]).toMatchObject({ className: "hud-title", textContent: "connection ok" });
    const lines = box.children.slice(1);
    expect(lines.map((l) => l.dataset.key)).toEqual(v.rows.map((r) => r.key));
    expect(lines.every((l) => l.className === "hud-row hud-ok")).toBe(true);
    expect(lines[2]?.title).toBe(v.rows[2]?.limits);
    expect(lines[2]?.children.map((c) => c.textContent)).toEqual(["video", "30 fps · 2400 kbit/s · full 1280×360"]);
  });

  it("amber, degraded; red, bad, the reason in the tooltip", () => {
    const amber = draw(view({ lossPercent: 2 }));
    expect(amber.className).toBe("hud-amber");
    expect(amber.children[0]?.textContent).toBe("connection degraded");
    expect(amber.children.find((l) => l.dataset.key === "loss")?.className).toBe("hud-row hud-amber");
    const red = draw(view({ forceAgeMs: 3000 }));
    expect(red.className).toBe("hud-red");
    expect(red.children[0]?.textContent).toBe("connection bad");
    expect(red.title).toBe("force age: no new sample for 3.0 s (> 200 ms)");
    expect(red.children.find((l) => l.dataset.key === "force")?.className).toBe("hud-row hud-red");
  });
});

describe("the collector over time (an injected clock)", () => {
  // A peer whose counters the test advances, a link and a force stream it controls, and
  // the clock passed to frame() and update(): a 20 fps stream, sampled every 500 ms.
  function rig() {
    const counters = { frames: 0, bytes: 0, packets: 0, lost: 0 };
    const makePc = () =>
      ({
        connectionState: "connected",
        getStats: () =>
          Promise.resolve(
            new Map<string, Record<string, unknown>>([
              ["v", { type: "inbound-rtp", kind: "video", framesDecoded: counters.frames, bytesReceived: counters.bytes, packetsLost: counters.lost, packetsReceived: counters.packets, frameWidth: 2560, frameHeight: 720 }],
              ["p", { type: "candidate-pair", id: "p", nominated: true, state: "succeeded", currentRoundTripTime: 0.001 }],
            ]),
          ),
      }) as unknown as RTCPeerConnection;
    const s = {
      counters,
      pc: makePc() as RTCPeerConnection | null,
      makePc,
      link: { open: true, bestRtt: 0.0005, offset: 0, commandLatency: new Rolling() },
      forceFlowing: true,
      lastForce: null as { time: number } | null,
      now: 0,
      framesFlowing: true,
      hud: null as unknown as ConnectionHud,
    };
    s.hud = new ConnectionHud({ pc: () => s.pc, link: s.link, force: () => s.lastForce, video: Promise.resolve({ fps: 20, width: 1280 }) });
    /** Advance the clock by `ms` in 50 ms frames, the force stream's 10 ms batches
     * and the peer's counters following what flows; the HUD updates every 500 ms. */
    const run = async (ms: number) => {
      for (const end = s.now + ms; s.now < end; ) {
        s.now += 50;
        if (s.forceFlowing) s.lastForce = { time: (s.now - 20) / 1000 };
        if (s.framesFlowing && s.pc) {
          s.hud.frame(s.now);
          counters.frames += 1;
          counters.bytes += 10_000;
          counters.packets += 10;
        }
        if (s.now % 500 === 0) await s.hud.update(s.now);
      }
    };
    return { s, run, row: (key: HudKey) => s.hud.rows.find((r) => r.key === key) };
  }

  it("green on a good link, measured figures shown", async () => {
    const { s, run, row } = rig();
    await run(3000);
    expect(s.hud.level).toBe("ok");
    expect(s.hud.reason).toBe("");
    expect(row("video")?.text).toBe("20 fps · 1600 kbit/s · full 2560×720");
    expect(row("rtt")?.text).toBe("video 1.0 ms · ping 0.5 ms");
    expect(row("loss")?.text).toBe("0.0 %");
    expect(row("force")?.text).toBe("20 ms");
  });

  it("the force stream stops: red within the red limit, with the reason; ok again once it resumes", async () => {
    const { s, run, row } = rig();
    await run(3000);
    s.forceFlowing = false;
    await run(500); // the newest sample is now 520 ms old
    expect(s.hud.level).toBe("red");
    expect(s.hud.reason).toBe("force age: 520 ms (> 200 ms)");
    await run(1500);
    expect(row("force")).toMatchObject({ level: "red", text: "no new sample for 2.0 s (> 200 ms)" });
    s.forceFlowing = true;
    await run(500);
    expect(row("force")).toMatchObject({ level: "ok", text: "20 ms" });
    expect(s.hud.level).toBe("ok");
  });

  it("the realtime link is cut: red, 'realtime link down'; back when it reopens", async () => {
    const { s, run } = rig();
    await run(2000);
    s.link.open = false;
    await run(500);
    expect(s.hud).toMatchObject({ level: "red", reason: "force age: realtime link down" });
    s.link.open = true;
    await run(500);
    expect(s.hud.level).toBe("ok");
  });

  it("loss over the 2 s window: red while packets are lost, ok once the window has passed", async () => {
    const { s, run, row } = rig();
    await run(3000);
    s.counters.lost += 40; // 40 of ~540 packets over the window
    await run(500);
    expect(row("loss")).toMatchObject({ level: "red" });
    expect(s.hud.reason).toMatch(/^loss: [\d.]+ % \(> 5 %\)$/);
    await run(STATS_WINDOW_MS + 500);
    expect(row("loss")).toMatchObject({ level: "ok", text: "0.0 %" });
    expect(s.hud.level).toBe("ok");
  });

  it("the video pauses: amber, then red with how long; the freeze counted for 10 s, then green", async () => {
    const { s, run, row } = rig();
    await run(3000);
    s.framesFlowing = false;
    await run(500);
    expect(row("video")).toMatchObject({ level: "amber", text: "frozen: no new frame for 0.5 s" });
    expect(s.hud.reason).toBe("video: frozen: no new frame for 0.5 s");
    await run(500);
    expect(row("video")).toMatchObject({ level: "red", text: "frozen: no new frame for 1.0 s" });
    expect(s.hud.level).toBe("red");
    s.framesFlowing = true;
    await run(500);
    // Frames again; the rate over the stats window still has the pause in it.
    expect(row("video")).toMatchObject({ level: "amber", text: "10 fps of 20 (< 15) · 800 kbit/s · full 2560×720" });
    expect(row("freezes")).toMatchObject({ level: "amber", text: "1 in 10 s (longest 1.1 s)" });
    await run(STATS_WINDOW_MS);
    expect(row("video")?.level).toBe("ok");
    expect(s.hud.reason).toBe("freezes: 1 in 10 s (longest 1.1 s)");
    await run(FREEZE_WINDOW_MS - 3000);
    expect(row("freezes")?.level).toBe("amber"); // still inside the window
    await run(1000);
    expect(row("freezes")).toMatchObject({ level: "ok", text: "none in 10 s" });
    expect(s.hud.level).toBe("ok");
  });

  it("three freezes in 10 s are red; they leave the window one by one", async () => {
    const { s, run, row } = rig();
    await run(1000);
    for (let i = 0; i < FREEZES_RED; i += 1) {
      s.framesFlowing = false;
      await run(300);
      s.framesFlowing = true;
      await run(1700);
    }
    // Freezes ended at 1350, 3350 and 5350 ms; now is 7000.
    expect(row("freezes")).toMatchObject({ level: "red", text: "3 in 10 s (longest 0.3 s)" });
    expect(s.hud.level).toBe("red");
    await run(4500); // 11 500: the first has left the window
    expect(row("freezes")).toMatchObject({ level: "amber", text: "2 in 10 s (longest 0.3 s)" });
    await run(4000); // 15 500: all three have
    expect(row("freezes")?.level).toBe("ok");
    expect(s.hud.level).toBe("ok");
  });

  it("the video peer is dropped: red; a new peer and its frames bring the row back, the gap counted", async () => {
    const { s, run, row } = rig();
    await run(3000);
    s.pc = null;
    await run(1000);
    expect(row("video")).toMatchObject({ level: "red", text: "no video peer (reconnecting)" });
    expect(s.hud.reason).toContain("video: no video peer (reconnecting)");
    s.pc = s.makePc(); // its counters go on from the old ones here; the HUD starts afresh
    await run(1000);
    expect(row("video")).toMatchObject({ level: "ok", text: "20 fps · 1600 kbit/s · full 2560×720" });
    expect(row("freezes")).toMatchObject({ level: "amber", text: "1 in 10 s (longest 1.1 s)" });
  });

  it("a command's age: amber while driving late, idle (ok) 5 s after the last", async () => {
    const { s, run, row } = rig();
    await run(1000);
    s.link.commandLatency.add(150);
    await run(500);
    expect(row("command")).toMatchObject({ level: "amber", text: "150 ms (> 100 ms)" });
    await run(COMMAND_IDLE_MS + 500); // acknowledged (seen) at the update after it
    expect(row("command")).toMatchObject({ level: "ok", text: "idle (last 150 ms)" });
  });

  it("the test seam: pinned figures replace the measured ones, the rest is still judged", async () => {
    const { s, run, row } = rig();
    await run(1000);
    s.framesFlowing = false;
    s.hud.pinned = { fps: 20, freezes: 0, longestFreezeMs: 0, sinceFrameMs: 10 };
    s.forceFlowing = false;
    await run(1000);
    expect(row("video")?.level).toBe("ok");
    expect(row("freezes")?.level).toBe("ok");
    expect(s.hud.reason).toMatch(/^force age: /);
    s.hud.pinned = null;
    await run(500);
    expect(row("video")?.level).toBe("red");
  });
});
