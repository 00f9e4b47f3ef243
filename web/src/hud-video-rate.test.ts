// The HUD's video row at 60 fps (issue 56): the decoded rate judged against what the
// server sends now, and while the server has dropped to 30 by itself, the rate it sends
// and why (GET /api/v1/video's fps_target and fps_why, read every few seconds).
import { describe, expect, it } from "vitest";
import { Rolling } from "./stats";
import { ConnectionHud, SERVER_VIDEO_PERIOD_MS, hudView, shortWhy, type HudFigures } from "./ui/connection-hud";

const at60: HudFigures = {
  videoUp: true,
  videoRttMs: 0.6,
  pingRttMs: 0.4,
  lossPercent: 0,
  fps: 60,
  nominalFps: 60,
  serverFps: 60,
  serverFpsWhy: "configured (60 fps)",
  bitrateKbps: 8000,
  layer: "full",
  frameSize: "2560×720",
  sinceFrameMs: 10,
  freezes: 0,
  longestFreezeMs: 0,
  linkOpen: true,
  synced: true,
  offsetMs: 1,
  forceAgeMs: 3,
  commandAgeMs: null,
  commandSeenAgoMs: null,
};
const video = (over: Partial<HudFigures>) => hudView({ ...at60, ...over }).rows.find((r) => r.key === "video");
const WHY = "encoding took 14.2 ms a frame (p90 over 5 s), over 12.5 ms (75% of 60 fps's 16.7 ms): 30 fps";

describe("the HUD's video row at 60 fps", () => {
  it("at the configured rate: the rate decoded, nothing more", () => {
    expect(video({})).toMatchObject({ level: "ok", text: "60 fps · 8000 kbit/s · full 2560×720" });
    expect(video({ fps: 40 })).toMatchObject({ level: "ok", text: "40 fps · 8000 kbit/s · full 2560×720" });
    expect(video({ fps: 15 })).toMatchObject({ level: "amber", text: "15 fps of 60 (< 20) · 8000 kbit/s · full 2560×720" });
  });

  it("dropped to 30 by the server: the rate it sends and why, judged against 30, the whole reason in the tooltip", () => {
    const row = video({ fps: 30, serverFps: 30, serverFpsWhy: WHY });
    expect(row?.level).toBe("ok");
    expect(row?.text).toBe("30 fps · 8000 kbit/s · full 2560×720 · sent at 30 of 60 fps: encoding took 14.2 ms a frame");
    expect(row?.limits).toContain(`the server sends 30 of 60 fps: ${WHY}`);
    expect(video({ fps: 18, serverFps: 30, serverFpsWhy: WHY })).toMatchObject({ level: "amber" });
    expect(shortWhy("the camera delivers 25 fps (asked for 60)")).toBe("the camera delivers 25 fps");
    expect(shortWhy("6% of the camera's frames skipped over 5 s (over 5%): 30 fps")).toBe("6% of the camera's frames skipped over 5 s");
  });

  it("reads the server's rate every SERVER_VIDEO_PERIOD_MS, not on every redraw", async () => {
    let reads = 0;
    let target = 60;
    const link = { open: true, bestRtt: 0.001, offset: 0, commandLatency: new Rolling(10) };
    const hud = new ConnectionHud({
      pc: () => null,
      link,
      force: () => null,
      video: Promise.resolve({ fps: 60, width: 1280 }),
      serverVideo: () => {
        reads += 1;
        return Promise.resolve({ stats: { fps_target: target, fps_why: target < 60 ? WHY : "configured (60 fps)" } });
      },
    });
    await hud.collect(0);
    target = 30;
    await hud.collect(SERVER_VIDEO_PERIOD_MS / 2);
    expect(reads).toBe(1);
    await hud.collect(SERVER_VIDEO_PERIOD_MS);
    await Promise.resolve();
    const f = await hud.collect(SERVER_VIDEO_PERIOD_MS + 1);
    expect(reads).toBe(2);
    expect(f).toMatchObject({ nominalFps: 60, serverFps: 30, serverFpsWhy: WHY });
  });
});
