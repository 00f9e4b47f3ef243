// The review page's episodes, safety events, command senders and picture: the pure
// parts review.ts draws from.
import { describe, expect, it } from "vitest";
import { TIMECODE_ROWS, shownFrame } from "./review/frame";
import { droveSpans, episodeLabel, episodesOf, markRows, safetyMarks, spanOf, whoSent, type SafetySnapshot } from "./review/marks";
import { episodeText } from "./ui/recording";
import { TIMECODE_ROWS as LIVE_TIMECODE_ROWS } from "./view/stereo";

describe("episodes on the review's timeline", () => {
  // As the recorder logs them: each message with the episode's whole label.
  const events = [
    { time: 1, event: "start", episode: 0, task: "pick", success: null, notes: "" },
    { time: 4.5, event: "end", episode: 0, task: "pick", success: true, notes: "clean" },
    { time: 5, event: "start", episode: 1, task: "place", success: null, notes: "" },
    { time: 7, event: "end", episode: 1, task: "place", success: false, notes: "dropped it" },
    { time: 8, event: "label", episode: 1, task: "place", success: false, notes: "dropped it twice" },
    { time: 9, event: "start", episode: 2, task: "", success: null, notes: "" },
  ];
  it("folds start, end and relabels into one episode each, by number", () => {
    const eps = episodesOf(events);
    expect(eps.map((e) => [e.episode, e.start, e.end, e.success])).toEqual([
      [0, 1, 4.5, true],
      [1, 5, 7, false],
      [2, 9, null, null],
    ]);
    expect(eps[1]?.notes).toBe("dropped it twice"); // the last label
    expect(episodesOf([])).toEqual([]);
  });
  it("numbers and words them as the Recording panel and the API do (from 0)", () => {
    const [first, second, open] = episodesOf(events);
    expect(episodeLabel(first!)).toBe("0:01.0–0:04.5 episode 0 “pick” ✓ — clean");
    expect(episodeLabel(second!)).toBe("0:05.0–0:07.0 episode 1 “place” ✗ — dropped it twice");
    expect(episodeLabel(open!)).toBe("0:09.0–end episode 2 (unlabelled) (not ended)");
    // the panel's own words for the same episode, the same number
    expect(episodeText({ episode: 0, task: "pick", success: true, notes: "clean", ended: 4.5 })).toBe("episode 0 “pick” ✓ — clean");
  });
  it("places a span on the strip in % of the recording, an instant still seen", () => {
    expect(spanOf(1, 4.5, 10)).toEqual({ left: 10, width: 35 });
    expect(spanOf(9, null, 10)).toEqual({ left: 90, width: 10 }); // not ended: to the end
    expect(spanOf(5, 5, 10).width).toBeGreaterThan(0);
    expect(spanOf(-1, 20, 10)).toEqual({ left: 0, width: 100 });
    expect(spanOf(0, 0, 0).left).toBe(0); // an empty recording: no NaN
  });
});

describe("safety events on the review's timeline", () => {
  const clear = { estop: false, estop_reason: "", force_limited: false, halted: false, lease_holder: "c1", lease_holder_name: "ws 127.0.0.1:5000", lease_note: "taken by 'ws 127.0.0.1:5000'" };
  const at = (time: number, over: Partial<SafetySnapshot>): SafetySnapshot => ({ ...clear, time, ...over });
  it("says each change once: e-stop and reset, force limit, dead-man halt, the lease", () => {
    const marks = safetyMarks([
      at(0.5, {}), // the lease taken: the recording's first change
      at(1, { estop: true, estop_reason: "e-stop pressed over REST from 127.0.0.1 (server)" }),
      at(2, {}),
      at(3, { force_limited: true }),
      at(3.5, {}),
      at(4, { halted: true }),
      at(4.2, {}),
      at(5, { lease_holder: null, lease_holder_name: null, lease_note: "controller disconnected" }),
    ]);
    expect(marks.map((m) => [m.time, m.kind])).toEqual([
      [0.5, "lease"],
      [1, "estop"],
      [2, "reset"],
      [3, "force"],
      [3.5, "force-clear"],
      [4, "halt"],
      [4.2, "resume"],
      [5, "lease"],
    ]);
    expect(marks[0]?.text).toBe("lease: taken by 'ws 127.0.0.1:5000'");
    expect(marks[1]?.text).toBe("e-stop: e-stop pressed over REST from 127.0.0.1 (server)");
    expect(marks[5]?.text).toContain("the link stalled");
    expect(marks[7]?.text).toBe("lease: controller disconnected");
  });
  it("a recording's first message is an e-stop: not also a lease change", () => {
    expect(safetyMarks([at(1, { estop: true })]).map((m) => m.kind)).toEqual(["estop"]);
    expect(safetyMarks([])).toEqual([]);
  });
  it("lists episodes and safety events together, in time order, each with its time", () => {
    const eps = episodesOf([
      { time: 1, event: "start", episode: 0, task: "pick" },
      { time: 4, event: "end", episode: 0, task: "pick", success: true, notes: "" },
    ]);
    const rows = markRows(eps, safetyMarks([at(2, { estop: true, estop_reason: "pressed" })]));
    expect(rows.map((r) => [r.kind, r.text])).toEqual([
      ["success", "0:01.0–0:04.0 episode 0 “pick” ✓"],
      ["estop", "0:02.0 e-stop: pressed"],
    ]);
  });
});

describe("the command log names who sent each command once", () => {
  it("an unnamed connection, a task, the server: their name says their source", () => {
    expect(whoSent("ws", "ws 127.0.0.1:51234")).toBe("ws 127.0.0.1:51234");
    expect(whoSent("priority", "priority 127.0.0.1:6000")).toBe("priority 127.0.0.1:6000");
    expect(whoSent("task", "task 3")).toBe("task 3");
    expect(whoSent("server", "server")).toBe("server");
  });
  it("a named client (a script's lease), or the server acting on a REST call, says how", () => {
    expect(whoSent("rest", "pick-script")).toBe("pick-script (rest)");
    expect(whoSent("rest", "server")).toBe("server (rest)");
    expect(whoSent("rest", "")).toBe("rest");
  });
});

describe("the review's picture hides the timecode stripe as the live page does", () => {
  it("crops the live page's rows", () => {
    expect(TIMECODE_ROWS).toBe(LIVE_TIMECODE_ROWS);
  });
  it("draws the rows below the stripe of a side-by-side frame", () => {
    expect(shownFrame(1280, 360)).toEqual({ crop: 28, width: 1280, height: 332 });
    expect(shownFrame(1280, 10)).toEqual({ crop: 9, width: 1280, height: 1 }); // a row left
    expect(shownFrame(0, 0)).toEqual({ crop: 0, width: 0, height: 1 });
  });
});

describe("who drove", () => {
  it("colours the spans of a supervised policy's recording by who drove", () => {
    const spans = droveSpans(
      [
        { time: 0, mode: "off" },
        { time: 1, mode: "autonomous", policy: "act" },
        { time: 3, mode: "correcting", policy: "act", operator: "alice" },
        { time: 4, mode: "autonomous", policy: "act" },
        { time: 6, mode: "paused", policy: "act" },
      ],
      8,
    );
    expect(spans.map((s) => [s.mode, s.start, s.end, s.who])).toEqual([
      ["autonomous", 1, 3, "act drove"],
      ["correcting", 3, 4, "alice corrected"],
      ["autonomous", 4, 6, "act drove"],
      ["paused", 6, 8, "act paused"],
    ]);
    expect(droveSpans([], 5)).toEqual([]);
  });
});
