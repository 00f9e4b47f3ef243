// The review page loading a recording (issue 55): the timeline's pieces it asks for, the
// recording growing as they come, and what its loading indicator says meanwhile.
import { describe, expect, it } from "vitest";
import { ApiError } from "./api";
import { initialLoad, loadingDone, loadingFraction, loadingWords, type LoadState } from "./review/loading";
import { FIRST_PIECE_S, PIECE_ATTEMPTS, growRecording, lastPiece, pieceAfter, retryAfterMs, shapeRecording, type PieceRange } from "./review/recording";
import { recordingTestView } from "./review/test-view";

/** The pieces a page asks for, in order, for a recording of `duration` s. */
function plan(duration: number): PieceRange[] {
  const asked: PieceRange[] = [];
  let range = pieceAfter(0, null);
  asked.push(range);
  while (!lastPiece(range, duration) && asked.length < 50) {
    range = pieceAfter(range.end_s ?? duration, duration);
    asked.push(range);
  }
  return asked;
}

describe("the timeline's pieces", () => {
  it("starts small, then grows fourfold, the last one open-ended", () => {
    expect(plan(126)).toEqual([
      { start_s: 0, end_s: FIRST_PIECE_S },
      { start_s: 10, end_s: 50 },
      { start_s: 50, end_s: undefined },
    ]);
    expect(plan(3600).map((r) => r.start_s)).toEqual([0, 10, 50, 210, 850, 3410]);
    expect(plan(3600).at(-1)?.end_s).toBeUndefined();
  });
  it("covers the recording without a gap or an overlap", () => {
    for (const duration of [0, 0.5, 9.99, 10, 10.01, 49.9, 50, 126, 7200]) {
      const pieces = plan(duration);
      pieces.forEach((p, i) => expect(p.start_s).toBe(i === 0 ? 0 : pieces[i - 1]?.end_s));
      const last = pieces.at(-1);
      // The last piece reaches past the recording's last message (at `duration`).
      expect(last?.end_s === undefined || (last.end_s ?? 0) > duration).toBe(true);
    }
  });
  it("a recording of exactly the first piece's length asks once more for its last message", () => {
    expect(lastPiece({ start_s: 0, end_s: 10 }, 10)).toBe(false);
    expect(lastPiece({ start_s: 0, end_s: 10 }, 9.5)).toBe(true);
  });
  it("asks again, later, only while the server is busy or a budget is spent", () => {
    expect(retryAfterMs(new ApiError("busy", 503, {}), 0)).toBe(1000);
    expect(retryAfterMs(new ApiError("too many", 429, {}), 9)).toBe(1000);
    expect(retryAfterMs(new ApiError("too many", 429, {}), 10)).toBe(4000);
    expect(retryAfterMs(new ApiError("too many", 429, {}), PIECE_ATTEMPTS)).toBeNull();
    expect(retryAfterMs(new ApiError("no such", 404, {}), 0)).toBeNull();
    expect(retryAfterMs(new Error("network"), 0)).toBeNull();
  });
});

describe("the recording growing piece by piece", () => {
  const first = {
    duration: 20,
    video_start: 0.2,
    topics: {
      "/robot/state": [{ time: 1, position: [0, 0, 1] }],
      "/force": [{ time: 1, values: [1, 0, 0, 0, 0, 0] }],
      "/commands": [{ time: 2, kind: "home", accepted: true, reason: "", source: "rest", client: "" }],
      "/episodes": [{ time: 5, event: "start", episode: 0, task: "pick" }],
      "/safety": [],
    },
  };
  const second = {
    duration: 20,
    video_start: 0.2,
    topics: {
      "/robot/state": [{ time: 12, position: [0, 0, 2] }],
      "/force": [{ time: 12, values: [5, 0, 0, 0, 0, 0] }],
      "/commands": [{ time: 13, kind: "stop", accepted: false, reason: "no lease", source: "rest", client: "" }],
      "/episodes": [
        { time: 15, event: "end", episode: 0, task: "pick" },
        { time: 15.1, event: "label", episode: 0, task: "pick", success: true },
      ],
      "/safety": [{ time: 14, estop: true, estop_reason: "pressed" }],
    },
  };
  it("appends each piece's messages to the same lists, and makes the marks again", () => {
    const r = shapeRecording("a.mcap", first, []);
    const states = r.armStates[0];
    const episodes = r.episodes;
    expect(r.episodes.map((e) => e.end)).toEqual([null]); // its end not loaded yet
    growRecording(r, second);
    expect(r.armStates[0]).toBe(states); // the same list, grown: what a part holds sees it
    expect(r.armStates[0]?.map((s) => s.time)).toEqual([1, 12]);
    expect(r.armForces[0]?.map((f) => f.values[0])).toEqual([1, 5]);
    expect(r.commands.map((c) => c.kind)).toEqual(["home", "stop"]);
    expect(r.episodes).toBe(episodes);
    expect(r.episodes.map((e) => [e.start, e.end, e.success])).toEqual([[5, 15, true]]);
    expect(r.safety.map((m) => m.kind)).toEqual(["estop"]);
    expect(recordingTestView(r)).toEqual({ duration: 20, videoStart: 0.2, states: 2, arms: [{ name: "arm", states: 2, forces: 2 }] });
  });
  it("is the same in pieces as in one", () => {
    const whole = {
      duration: 20,
      video_start: 0.2,
      topics: Object.fromEntries(Object.keys(first.topics).map((t) => [t, [...(first.topics as Record<string, unknown[]>)[t]!, ...(second.topics as Record<string, unknown[]>)[t]!]])),
    };
    const inPieces = shapeRecording("a.mcap", first, []);
    growRecording(inPieces, second);
    expect(inPieces).toEqual(shapeRecording("a.mcap", whole, []));
  });
});

describe("the loading indicator", () => {
  it("says a length just under a minute's end as the next minute (not 1:60.0)", () => {
    expect(loadingWords(at({ loadedTo: 10, duration: 119.97, video: "none" }))).toBe("Loading the recording: timeline 0:10.0 of 2:00.0");
  });
  const at = (s: Partial<LoadState>): LoadState => ({ ...initialLoad(), ...s });
  it("says from the start what it waits for, with no progress yet", () => {
    const s = initialLoad();
    expect(loadingWords(s)).toBe("Loading the recording: timeline: asking for its first seconds · video: being prepared by the server");
    expect(loadingFraction(s)).toBe(0);
    expect(loadingDone(s)).toBe(false);
  });
  it("says how far the timeline and the video are", () => {
    const s = at({ loadedTo: 10, duration: 126, video: "arriving", videoFraction: 0.5 });
    expect(loadingWords(s)).toBe("Loading the recording: timeline 0:10.0 of 2:06.0 · video 50 % received");
    expect(loadingFraction(s)).toBeCloseTo((10 / 126 + 0.45) / 2);
    expect(loadingDone(s)).toBe(false);
  });
  it("goes once both are there (or the video is not), and says a failure", () => {
    expect(loadingDone(at({ timelineComplete: true, duration: 5, loadedTo: 5, video: "ready" }))).toBe(true);
    expect(loadingDone(at({ timelineComplete: true, duration: 5, video: "none" }))).toBe(true);
    expect(loadingDone(at({ timelineComplete: true, duration: 5, video: "asked" }))).toBe(false);
    expect(loadingDone(at({ timelineComplete: false, duration: 5, video: "ready" }))).toBe(false);
    expect(loadingFraction(at({ timelineComplete: true, duration: 5, video: "none" }))).toBe(1);
    expect(loadingWords(at({ timelineFailed: "HTTP 500", video: "ready" }))).toBe("Loading the recording: timeline failed: HTTP 500 · video ready");
    expect(loadingWords(at({ loadedTo: 10, duration: 20, timelineWaiting: "too many reads", video: "ready" }))).toBe(
      "Loading the recording: timeline 0:10.0 of 0:20.0 (asked again shortly: too many reads) · video ready",
    );
  });
});
