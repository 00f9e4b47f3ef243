import { describe, expect, it } from "vitest";
import { ArBall } from "./ar/ball";
import { identity4 } from "./robot/math";
import { Clicks, NUDGE_PX, neededFor } from "./ui/calibration/clicks";

describe("calibration clicks", () => {
  it("go left image first, then right, as many as the method needs", () => {
    const clicks = new Clicks();
    const needed = neededFor("affine", 12);
    expect(needed).toBe(4);
    expect(neededFor("dlt", 12)).toBe(12);
    expect(clicks.prompt(needed, false)).toBe("Freeze the images first.");
    expect(clicks.prompt(needed, true)).toBe("Click fiducial 1 of 4 in the LEFT image.");
    for (let i = 0; i < 4; i++) expect(clicks.add("left", [i, i], needed)).toBe(true);
    expect(clicks.add("left", [9, 9], needed)).toBe(false); // all clicked: nothing added
    expect(clicks.next(needed)).toBe("right");
    for (let i = 0; i < 4; i++) clicks.add("right", [i, i], needed);
    expect(clicks.next(needed)).toBeUndefined();
    expect(clicks.prompt(needed, true)).toBe("All fiducials clicked: compute.");
  });

  it("nudge the last click with the arrows and undo it with Backspace", () => {
    const clicks = new Clicks();
    expect(clicks.key("Backspace")).toBeNull(); // nothing clicked yet
    clicks.add("right", [10, 20], 12);
    expect(clicks.key("ArrowRight")).toBe("right");
    expect(clicks.key("ArrowUp")).toBe("right");
    expect(clicks.byCamera.right).toEqual([[10 + NUDGE_PX, 20 - NUDGE_PX]]);
    expect(clicks.key("KeyA")).toBeNull();
    clicks.key("Backspace");
    expect(clicks.byCamera.right).toEqual([]);
  });
});

describe("the AR ball", () => {
  it("is where each camera sees the tool, and stays put without a pose", () => {
    const P = [[100, 0, 0, 0], [0, 100, 0, 0], [0, 0, 0, 1]]; // u = 100 x, v = 100 y
    const shifted = [[100, 0, 0, 10], [0, 100, 0, 0], [0, 0, 0, 1]];
    const ar = new ArBall([{ name: "left", P }, { name: "right", P: shifted }]);
    expect(ar.update(null)).toEqual({ left: null, right: null });
    const T = identity4();
    T[3] = 0.5;
    T[7] = 0.25;
    expect(ar.update(T)).toEqual({ left: [50, 25], right: [60, 25] });
    expect(ar.update(null)).toBe(ar.ball);
    expect(ar.ball.left).toEqual([50, 25]);
  });
});
