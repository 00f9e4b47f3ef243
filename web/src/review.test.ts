import { describe, expect, it } from "vitest";
import { forceRange, formatTime, latestAt, timelineOf, videoTimeOf } from "./review/timeline";

describe("review timeline", () => {
  const items = [{ time: 0 }, { time: 1 }, { time: 2 }];
  it("finds the sample in force at a time", () => {
    expect(latestAt(items, -1)).toBe(-1);
    expect(latestAt(items, 0)).toBe(0);
    expect(latestAt(items, 1.5)).toBe(1);
    expect(latestAt(items, 9)).toBe(2);
    expect(latestAt([], 1)).toBe(-1);
  });
  it("maps video time and timeline time both ways", () => {
    expect(timelineOf(2, 0.5)).toBe(2.5);
    expect(videoTimeOf(2.5, 0.5, 10)).toBe(2);
    expect(videoTimeOf(0.1, 0.5, 10)).toBe(0);
    expect(videoTimeOf(20, 0.5, 10)).toBe(10);
  });
  it("scales the force plot and says times", () => {
    expect(forceRange([{ values: [0.1, -3] }])).toBe(3);
    expect(forceRange([])).toBe(1);
    expect(formatTime(65.25)).toBe("1:05.3");
  });
});
