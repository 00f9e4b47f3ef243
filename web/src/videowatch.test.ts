// The view's staleness watch (an injected clock) and the video's reconnect backoff.
import { afterEach, describe, expect, it, vi } from "vitest";
import type { Api } from "./api";
import { Backoff, VideoConnection } from "./transport/video";
import { FrameWatch } from "./view/staleness";
import { staleText } from "./view/stereo";

describe("FrameWatch", () => {
  it("is live until no frame has come for the threshold, then says for how long", () => {
    let t = 1000;
    const watch = new FrameWatch(300, () => t);
    expect(watch.stale()).toBeNull(); // just started
    t += 299;
    expect(watch.stale()).toBeNull();
    t += 1;
    expect(watch.stale()).toBe(300);
    watch.frame();
    expect(watch.stale()).toBeNull();
    t += 120;
    watch.frame();
    t += 250;
    expect(watch.stale()).toBeNull(); // 250 ms since the last frame
    t += 200;
    expect(watch.stale()).toBe(450);
  });
});

describe("the stale view's text", () => {
  it("counts ms for 2 s, then whole seconds: a long stall is redrawn once a second, not 20 times", () => {
    expect(staleText(300)).toBe("VIDEO STALE 300 ms");
    expect(staleText(1999.6)).toBe("VIDEO STALE 2000 ms");
    expect(staleText(2000)).toBe("VIDEO STALE 2 s");
    const shown = new Set(Array.from({ length: 200 }, (_, i) => staleText(2000 + 50 * i))); // 10 s of checks
    expect(shown.size).toBe(10);
  });
});

describe("Backoff", () => {
  it("doubles from 0.5 s to at most 8 s and starts again after a success", () => {
    const b = new Backoff();
    expect(Array.from({ length: 7 }, () => b.next())).toEqual([500, 1000, 2000, 4000, 8000, 8000, 8000]);
    b.reset();
    expect(b.next()).toBe(500);
  });
});

describe("VideoConnection", () => {
  afterEach(() => vi.useRealTimers());

  it("retries a failing negotiation on the backoff's schedule, one attempt at a time", async () => {
    vi.useFakeTimers();
    const attempts: number[] = [];
    // Every attempt fails at once (no server): the ICE configuration comes, the peer cannot be made.
    const ice = { ice_servers: [], ice_transport_policy: "all", enabled: true }; // (GET /video/ice and /video)
    const api = { request: (method: string) => (method === "get" ? Promise.resolve(ice) : Promise.reject(new Error("refused"))) } as unknown as Api;
    vi.stubGlobal(
      "RTCPeerConnection",
      class {
        constructor() {
          attempts.push(Date.now());
          throw new Error("refused");
        }
      },
    );
    const video = new VideoConnection(api, { onStream: () => undefined });
    const t0 = Date.now();
    await video.start().catch(() => undefined);
    video.stalled(5000); // while a retry is pending, more stalls add no attempts
    await vi.advanceTimersByTimeAsync(16_000);
    expect(attempts.map((t) => t - t0)).toEqual([0, 500, 1500, 3500, 7500, 15500]);
    vi.unstubAllGlobals();
  });

  it("makes no peer on a server with no video: says so once and asks again every 8 s", async () => {
    vi.useFakeTimers();
    let peers = 0;
    const asked: number[] = [];
    const said: string[] = [];
    const status = { ice_servers: [], ice_transport_policy: "all", enabled: false };
    const api = {
      request: (_method: string, path: string) => {
        if (path === "/api/v1/video") asked.push(Date.now());
        return Promise.resolve(status);
      },
    } as unknown as Api;
    vi.stubGlobal(
      "RTCPeerConnection",
      class {
        constructor() {
          peers += 1; // (the old page made one, and dropped it, every few seconds)
          throw new Error("refused");
        }
      },
    );
    const video = new VideoConnection(api, { onStream: () => undefined, onError: (t) => said.push(t) });
    const t0 = Date.now();
    await video.start().catch(() => undefined);
    video.stalled(5000, performance.now() + 60_000); // the view's stale watch adds nothing
    await vi.advanceTimersByTimeAsync(30_000);
    expect(peers).toBe(0);
    expect(video.noVideo).toBe(true);
    expect(asked.map((t) => t - t0)).toEqual([0, 8000, 16000, 24000]);
    expect(said).toEqual(["video: this server sends no video (it was started with video off)"]);
    vi.unstubAllGlobals();
  });

  it("re-negotiates a stalled video only once the newest peer had its grace", () => {
    const api = {} as Api;
    const video = new VideoConnection(api, { onStream: () => undefined, staleMs: 1000, graceMs: 5000 });
    const retried: string[] = [];
    video.retry = (why: string) => void retried.push(why);
    (video as unknown as { attemptAt: number }).attemptAt = 10_000;
    video.stalled(null, 20_000);
    video.stalled(900, 20_000); // not stale long enough
    video.stalled(2000, 14_000); // the newest peer is still in its grace
    expect(retried).toEqual([]);
    video.stalled(1200, 15_000);
    expect(retried).toEqual(["no video for 1200 ms"]);
  });
});
