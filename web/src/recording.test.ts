import { describe, expect, it } from "vitest";
import {
  defaultName,
  droppedText,
  episodeText,
  formatElapsed,
  formatSize,
  isRecordingEvent,
  lastRecording,
  recordingView,
  reviewHref,
  type ActiveRecording,
  type Episode,
} from "./ui/recording";

const episode = (over: Partial<Episode> = {}): Episode => ({ episode: 0, task: "pick", started: 10, ended: null, success: null, notes: "", ...over });
const active = (over: Partial<ActiveRecording> = {}): ActiveRecording => ({
  recording: true,
  name: "demo",
  file: "20250101-120000-demo.mcap",
  started: "2025-01-01T12:00:00Z",
  elapsed_s: 83.7,
  bytes: 4_560_000,
  messages: 1000,
  queued: 0,
  dropped: {},
  episodes: [],
  ...over,
});

describe("formatting", () => {
  it("elapsed as mm:ss, h:mm:ss from an hour, nonsense as 00:00", () => {
    expect(formatElapsed(0)).toBe("00:00");
    expect(formatElapsed(59.99)).toBe("00:59");
    expect(formatElapsed(83.7)).toBe("01:23");
    expect(formatElapsed(3599)).toBe("59:59");
    expect(formatElapsed(3600 + 62)).toBe("1:01:02");
    expect(formatElapsed(-3)).toBe("00:00");
    expect(formatElapsed(null)).toBe("00:00");
    expect(formatElapsed(Number.NaN)).toBe("00:00");
  });
  it("sizes in MB: two decimals under 10, one under 100, none above", () => {
    expect(formatSize(0)).toBe("0.00 MB");
    expect(formatSize(123_456)).toBe("0.12 MB");
    expect(formatSize(4_560_000)).toBe("4.56 MB");
    expect(formatSize(45_600_000)).toBe("45.6 MB");
    expect(formatSize(1_234_000_000)).toBe("1234 MB");
    expect(formatSize(undefined)).toBe("0.00 MB");
  });
  it("a default name from the local date, kept by the server's name rule", () => {
    const name = defaultName(new Date(2025, 2, 7, 9, 5));
    expect(name).toBe("session-20250307-0905");
    expect(name).toMatch(/^[A-Za-z0-9_-]+$/);
  });
  it("the review page's address takes the file name as ?id=", () => {
    expect(reviewHref("20250101-120000-demo.mcap")).toBe("review.html?id=20250101-120000-demo.mcap");
    expect(reviewHref("a b&c")).toBe("review.html?id=a%20b%26c");
  });
  it("the last recording is the newest one not being recorded", () => {
    expect(lastRecording([])).toBeNull();
    expect(lastRecording([{ file: "b.mcap", active: true }, { file: "a.mcap", active: false }])).toBe("a.mcap");
  });
  it("dropped counts: only the non-zero ones", () => {
    expect(droppedText({})).toBe("");
    expect(droppedText({ "/force": 0 })).toBe("");
    expect(droppedText({ "/force": 3, "/video/stereo": 0, "/commands": 1 })).toBe("dropped: /force 3, /commands 1");
  });
  it("an episode: its number as the API's (from 0), task, verdict, notes once ended", () => {
    expect(episodeText(episode())).toBe("episode 0 “pick” (recording)");
    expect(episodeText(episode({ ended: 12, success: true, notes: "clean" }))).toBe("episode 0 “pick” ✓ — clean");
    expect(episodeText(episode({ episode: 2, task: "", ended: 12, success: false }))).toBe("episode 2 ✗");
    expect(episodeText(episode({ ended: 12 }))).toBe("episode 0 “pick” (unlabelled)");
  });
  it("the realtime events that announce a recording", () => {
    expect(isRecordingEvent("RECORDING started: x.mcap")).toBe(true);
    expect(isRecordingEvent("RECORDING stopped: x.mcap (stopped by the operator)")).toBe(true);
    expect(isRecordingEvent("LEASE granted")).toBe(false);
  });
});

describe("the panel's state", () => {
  it("status unknown: nothing to press, the indicator says so", () => {
    const v = recordingView(null, true);
    expect(v.recording).toBe(false);
    expect(v.indicator).toMatchObject({ text: "recording: unknown", on: false });
    expect(v.record).toEqual({ visible: true, enabled: false });
    expect(v.stop.visible).toBe(false);
  });
  it("not recording: the operator may record, an observer only reads", () => {
    const op = recordingView({ recording: false, dropped: {}, episodes: [] }, true);
    expect(op.indicator).toMatchObject({ text: "not recording", on: false });
    expect(op.record).toEqual({ visible: true, enabled: true });
    expect(op.stop.visible).toBe(false);
    expect(op.episodeStart.visible).toBe(false);
    expect(op.episodeEnd.visible).toBe(false);
    const obs = recordingView({ recording: false, dropped: {}, episodes: [] }, false);
    expect(obs.record.visible).toBe(false);
    expect(obs.indicator.text).toBe("not recording");
    expect(recordingView({ recording: false, dropped: {}, episodes: [] }, true, true).record.enabled).toBe(false); // a request under way
  });
  it("recording: the red indicator with elapsed and size, for every viewer", () => {
    for (const operator of [true, false]) {
      const v = recordingView(active(), operator);
      expect(v.indicator).toMatchObject({ text: "● REC 01:23 · 4.56 MB", on: true });
      expect(v.summary).toContain("01:23, 4.56 MB, 0 episodes");
      expect(v.record.visible).toBe(false);
      expect(v.stop).toEqual(operator ? { visible: true, enabled: true } : { visible: false, enabled: false });
    }
  });
  it("episodes: start while none is open, end while one is", () => {
    const none = recordingView(active(), true);
    expect(none.episodeStart).toEqual({ visible: true, enabled: true });
    expect(none.episodeEnd).toEqual({ visible: true, enabled: false });
    expect(none.episode).toBe("");
    const open = recordingView(active({ episodes: [episode()] }), true);
    expect(open.episodeStart.enabled).toBe(false);
    expect(open.episodeEnd.enabled).toBe(true);
    expect(open.episode).toBe("episode 0 “pick” (recording)");
    expect(open.summary).toContain("1 episode.");
    const ended = recordingView(active({ episodes: [episode({ ended: 20, success: true })] }), true);
    expect(ended.episodeStart.enabled).toBe(true);
    expect(ended.episodeEnd.enabled).toBe(false);
    expect(ended.episode).toBe("episode 0 “pick” ✓");
    const observer = recordingView(active({ episodes: [episode()] }), false);
    expect(observer.episodeStart.visible || observer.episodeEnd.visible).toBe(false);
    expect(observer.episode).toBe("episode 0 “pick” (recording)"); // seen, not changed
  });
  it("dropped messages shown when there are any", () => {
    expect(recordingView(active(), true).dropped).toBe("");
    const v = recordingView(active({ dropped: { "/force": 7 } }), false);
    expect(v.dropped).toBe("dropped: /force 7");
    expect(v.indicator.title).toContain("dropped: /force 7");
  });
});
