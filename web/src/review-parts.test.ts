// The review page's parts (review/player.ts, command-log.ts, marks-strip.ts,
// force-plot.ts, joints-readout.ts, overlay.ts): what each decides without a browser.
import { describe, expect, it } from "vitest";
import { ghostChain } from "./ar/ghost";
import { project } from "./ar/projection";
import { PUMA } from "./puma.fixture";
import { recordedArms } from "./review/arms";
import { commandLine } from "./review/command-log";
import { CursorRows } from "./review/cursor-rows";
import { bandLabel, bandY, plotX } from "./review/force-plot";
import { jointsText } from "./review/joints-readout";
import { stripMarks } from "./review/marks-strip";
import { armInEye, emptyOverlay } from "./review/overlay";
import { cursorTime } from "./review/player";
import type { RecordedCommand } from "./review/recording";

/** An <li>'s class list, as far as the greying uses it. */
class Row {
  readonly classes = new Set<string>();
  toggles = 0;
  readonly classList = {
    toggle: (token: string, force?: boolean): boolean => {
      this.toggles++;
      if (force ?? !this.classes.has(token)) this.classes.add(token);
      else this.classes.delete(token);
      return this.classes.has(token);
    },
  };
}
const greyed = (rows: Row[]) => rows.map((r) => r.classes.has("future"));

describe("the review's lists greyed after the cursor", () => {
  const times = [{ time: 1 }, { time: 2 }, { time: 2 }, { time: 5 }];
  it("greys the rows after the cursor, none at the end, all before the first", () => {
    const rows = times.map(() => new Row());
    const list = new CursorRows(times, rows);
    expect(list.update(0)).toBe(-1);
    expect(greyed(rows)).toEqual([true, true, true, true]);
    expect(list.update(2)).toBe(2); // both rows at 2 s: the cursor is on the last
    expect(greyed(rows)).toEqual([false, false, false, true]);
    expect(list.update(9)).toBe(3);
    expect(greyed(rows)).toEqual([false, false, false, false]);
    expect(list.update(1.5)).toBe(0); // seeking back greys again
    expect(greyed(rows)).toEqual([false, true, true, true]);
  });
  it("redoes nothing while the cursor stays between the same two rows", () => {
    const rows = times.map(() => new Row());
    const list = new CursorRows(times, rows);
    list.update(3);
    const toggles = rows.map((r) => r.toggles);
    expect(list.update(4.9)).toBe(null);
    expect(rows.map((r) => r.toggles)).toEqual(toggles);
    expect(new CursorRows([], []).update(1)).toBe(-1); // an empty list: once, no row
  });
});

describe("the review's command log", () => {
  const jog: RecordedCommand = { time: 61.25, kind: "cartesian_increment", accepted: true, reason: "", source: "ws", client: "ws 127.0.0.1:5000", args: { arm: "left" } };
  it("says when, who (once), what and, several arms, which arm", () => {
    expect(commandLine(jog, false)).toBe("1:01.3 ws 127.0.0.1:5000 cartesian_increment");
    expect(commandLine(jog, true)).toBe("1:01.3 ws 127.0.0.1:5000 cartesian_increment left");
    expect(commandLine({ ...jog, args: {} }, true)).toBe("1:01.3 ws 127.0.0.1:5000 cartesian_increment");
  });
  it("says a refused command's reason", () => {
    expect(commandLine({ ...jog, accepted: false, reason: "e-stop latched", source: "rest", client: "" }, false)).toBe("1:01.3 rest cartesian_increment refused: e-stop latched");
  });
});

describe("the review's marks strip", () => {
  const episodes = [
    { episode: 0, task: "pick", success: true, notes: "", start: 1, end: 4.5 },
    { episode: 1, task: "", success: null, notes: "", start: 9, end: null },
  ];
  const safety = [{ time: 2, kind: "estop" as const, text: "e-stop: pressed" }];
  const drove = [{ mode: "autonomous" as const, start: 0, end: 5, who: "policy act" }];
  it("draws the episodes' spans, then the safety ticks, then who drove, on the recording's axis", () => {
    const marks = stripMarks(episodes, safety, drove, 10);
    expect(marks.map((m) => [m.className, m.left, m.width])).toEqual([
      ["episode success", 10, 35],
      ["episode unlabelled", 90, 10], // not ended: to the end
      ["safety estop", 20, null], // a tick: as wide as the style makes it
      ["drove autonomous", 0, 50],
    ]);
    expect(marks[0]?.text).toBe("0:01.0–0:04.5 episode 0 “pick” ✓");
    expect(marks[0]?.title).toBe(marks[0]?.text);
    expect(marks[2]?.text).toBe(null);
    expect(marks[2]?.title).toBe("0:02.0 e-stop: pressed");
    expect(marks[3]?.title).toBe("0:00.0–0:05.0 policy act");
  });
  it("seeks to an episode's start and to a safety event, not from who drove", () => {
    expect(stripMarks(episodes, safety, drove, 10).map((m) => m.seekTo)).toEqual([1, 9, 2, null]);
    expect(stripMarks([], [], [], 10)).toEqual([]); // nothing: the strip hidden
  });
});

describe("the review's force plot", () => {
  it("puts the recording across the plot", () => {
    expect(plotX(10, 500)(5)).toBe(250);
    expect(plotX(10, 500)(10)).toBe(500);
    expect(Number.isFinite(plotX(0, 500)(0))).toBe(true); // an empty recording: no NaN
  });
  it("puts each arm's forces in its band: 0 in the middle, ±range 4 px inside its edges", () => {
    const y = bandY({ top: 160, height: 160 }, 5);
    expect(y(0)).toBe(240);
    expect(y(5)).toBe(164);
    expect(y(-5)).toBe(316);
  });
  it("labels a band with its scale, and several arms with whose it is", () => {
    expect(bandLabel(null, 2.345)).toBe("±2.3 N / N·m");
    expect(bandLabel("left", 2.345)).toBe("left  ±2.3 N / N·m");
  });
});

describe("the review's joints readout", () => {
  it("names each arm's joints as the recording does, else as its model does", () => {
    const arms = recordedArms({ "/arms": [{ time: 0, arms: [{ name: "left", joint_names: ["pan", "lift"] }, { name: "right" }] }] });
    const text = jointsText(arms, [{ time: 0, position: [], joints: [Math.PI / 2, 0] }, { time: 0, position: [], joints: [0.1] }], [null, { joint_names: ["shoulder"] }]);
    expect(text).toBe("left: pan 90.0°  lift 0.0°\nright: shoulder 5.7°");
    expect(jointsText(arms, [undefined, undefined], [null, null])).toBe("left: —\nright: —");
  });
});

describe("the review's overlay", () => {
  const P = [
    [800, 0, 320, 0],
    [0, 800, 240, 0],
    [0, -0.2, 1, 2],
  ]; // looking at the arm from 2 m
  const QN = PUMA.named_poses.qn ?? [];
  it("puts the ghost and the ball at the commanded joints, the ring at the actual tool", () => {
    const { chain, tool, actual } = armInEye(PUMA, { time: 0, position: [0.5, 0.1, 0.3], target_joints: QN }, P);
    expect(chain.length).toBeGreaterThan(1);
    expect(chain).toEqual(ghostChain(PUMA, QN, P));
    expect(tool).not.toBe(null);
    expect(tool).toEqual(chain[chain.length - 1]);
    expect(actual).toEqual(project(P, [0.5, 0.1, 0.3]));
  });
  it("draws no ghost without a model or a commanded pose of its joints, and no ring without a position", () => {
    expect(armInEye(null, { time: 0, position: [0, 0, 0], target_joints: QN }, P)).toMatchObject({ chain: [], tool: null });
    expect(armInEye(PUMA, { time: 0, position: [0, 0, 0], target_joints: [0, 0] }, P).chain).toEqual([]);
    expect(armInEye(PUMA, { time: 0, position: [] }, P)).toEqual({ chain: [], tool: null, actual: null });
    expect(armInEye(PUMA, undefined, P)).toEqual({ chain: [], tool: null, actual: null });
  });
  it("starts with nothing shown, for each arm by name", () => {
    expect(emptyOverlay(["left", "right"])).toEqual({
      predicted: [null, null],
      actual: [null, null],
      arms: { left: { predicted: [null, null], actual: [null, null] }, right: { predicted: [null, null], actual: [null, null] } },
    });
  });
});

describe("the review's cursor", () => {
  it("is the video's time on the timeline, or without video the slider's", () => {
    expect(cursorTime(0.5, 3, 2)).toBe(2.5);
    expect(cursorTime(null, 3, 2)).toBe(3);
    expect(cursorTime(undefined, 3, 0)).toBe(3);
  });
});
