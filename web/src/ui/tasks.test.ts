import { describe, expect, it } from "vitest";
import { ApiError } from "../api";
import type { Schema } from "../api";
import { approachQuestion, armOptions, AWAY_FROM_START, farFromStart, otherArm, previewText, recordingChoices, refusalView, whyNotRun } from "./tasks";

// The server's 422 for a Run from where the README's script leaves the arm.
const AWAY = "the tool is 60.8 mm / 5.7° from the task's first pose (it starts within 5 mm / 3°): move there, or confirm the approach (approach: true), a slow joint move there (its way: POST /tasks/preview, approach)";
const refused = (type: string, detail: string) => new ApiError(detail, 422, { type, title: "invalid command", status: 422, detail });
const ready = { chosen: true, operator: true, control: true, underWay: false, starting: false };

describe("a refused Run", () => {
  it("offers the approach only when the server's reason is the distance to the first pose", () => {
    expect(farFromStart(refused(AWAY_FROM_START, AWAY))).toBe(true);
    // Another refusal that speaks of the first pose (an approach the server cannot make) does not.
    expect(farFromStart(refused("urn:telerobot:error:limit_exceeded", "the approach to the task's first pose would take the tool outside the workspace"))).toBe(false);
    expect(farFromStart(new Error(AWAY))).toBe(false);
    expect(farFromStart(new ApiError("HTTP 502", 502, undefined))).toBe(false);
  });

  it("says the server's reason, and enables Approach first when a task could start now", () => {
    const view = refusalView(AWAY, true, whyNotRun(ready));
    expect(view.text).toBe(`Run refused: ${AWAY}`);
    expect(view.approach).toEqual({ disabled: false, title: expect.stringContaining("slow joint move") });
  });

  it("says why Approach first cannot be pressed (before: disabled with no reason)", () => {
    const blocked = whyNotRun({ ...ready, control: false });
    expect(blocked).toMatch(/take control first/);
    const view = refusalView(AWAY, true, blocked);
    expect(view.approach).toEqual({ disabled: true, title: `Approach first: ${blocked}` });
    expect(view.text).toBe(`Run refused: ${AWAY} — to approach it: ${blocked}`);
  });

  it("shows any other reason without offering the approach", () => {
    const view = refusalView("the recorded path jumps near s = 0.48 s", false, "");
    expect(view).toEqual({ text: "Run refused: the recorded path jumps near s = 0.48 s", approach: null });
  });

  it("names what stops a start, first things first", () => {
    expect(whyNotRun(ready)).toBe("");
    expect(whyNotRun({ ...ready, chosen: false, control: false })).toMatch(/choose a recording/);
    expect(whyNotRun({ ...ready, operator: false, control: false })).toMatch(/operator token/);
    expect(whyNotRun({ ...ready, underWay: true })).toMatch(/under way/);
    expect(whyNotRun({ ...ready, starting: true })).toMatch(/starting/);
  });
});

describe("the approach's confirm", () => {
  it("asks with how far the tool is and how it gets there", () => {
    const q = approachQuestion({ start_distance_m: 0.0608, start_angle_rad: (5.73 * Math.PI) / 180 }, AWAY);
    expect(q).toBe("The tool is 60.8 mm / 5.7° from the task's first pose. Move it there first — a slow joint move, shown dashed amber — then run the task?");
    // Without a preview's figures: the server's own words.
    expect(approachQuestion(null, AWAY)).toMatch(/^The tool is 60\.8 mm \/ 5\.7° from the task's first pose .*slow joint move/);
  });

  it("logs the preview with the approach, or why there is none", () => {
    const points: [number, number, number][] = [
      [0.6, -0.1, 0.9],
      [0.6, -0.1, 0.88],
    ];
    const base = { start_distance_m: 0.0608, start_angle_rad: 0.1, approach: [] as [number, number, number][], approach_refused: "" };
    expect(previewText(0, points, { ...base, start_distance_m: 0.001 })).toBe("task path: episode 0, 2.0 cm (cyan)");
    expect(previewText(0, points, { ...base, approach: [[0.607, -0.04, 0.9], points[0]!] })).toBe("task path: episode 0, 2.0 cm (cyan); the tool is 61 mm / 5.7° from its start: the approach, a joint move, dashed amber");
    expect(previewText(0, points, { ...base, approach_refused: "out of reach" })).toMatch(/cannot approach its start: out of reach$/);
  });
});

// The Tasks panel once offered a PUMA recording on an SO-101 server.
describe("recordings of another arm model", () => {
  const SO101 = { model: "so101", name: "SO-101" };
  const rec = (file: string, robot_model: string | null | undefined): Schema<"RecordingEntry"> => ({
    file,
    name: file.slice(16, -5),
    bytes: 1000,
    duration_s: 2,
    episodes: [{ episode: 0, task: "stay", started: 1, ended: 2, success: true, notes: "" }],
    episode_count: 1,
    complete: true,
    stop_reason: "stopped by the operator",
    active: false,
    robot_model,
  });
  const puma = rec("20261126-070000-puma.mcap", "puma560");
  const mine = rec("20261126-080000-mine.mcap", "so101");
  const older = rec("20261126-060000-older.mcap", null); // before the list said the model

  it("are greyed out saying so; this arm's and those not known are offered", () => {
    expect(otherArm(puma, SO101)).toBe("recorded with another arm model (puma560): this server drives the SO-101 (so101), and a task repeats the recorded tool path");
    expect(otherArm(mine, SO101)).toBe("");
    expect(otherArm(older, SO101)).toBe(""); // the server refuses it if it is another's
    expect(otherArm(rec("x", undefined), SO101)).toBe("");
    expect(otherArm(puma, null)).toBe(""); // the arm not read yet
    const { options, value } = recordingChoices([puma, mine, older], SO101, "");
    expect(options.map((o) => [o.value, o.disabled])).toEqual([
      [puma.file, true],
      [mine.file, false],
      [older.file, false],
    ]);
    expect(options[0]!.text).toBe("puma — 20261126-070000 (1 ep.) — another arm (puma560)");
    expect(options[0]!.title).toBe(otherArm(puma, SO101));
    expect(value).toBe(mine.file); // the first that can be repeated, never the PUMA's
  });

  it("is never the one chosen, even if it was before (a server restarted with another arm)", () => {
    expect(recordingChoices([puma, mine], SO101, puma.file).value).toBe(mine.file);
    expect(recordingChoices([puma, mine], { model: "puma560", name: "PUMA 560" }, puma.file).value).toBe(puma.file);
    expect(recordingChoices([mine, older], SO101, older.file).value).toBe(older.file);
  });

  it("leaves nothing chosen, saying why, when every recording is another arm's", () => {
    const { options, value } = recordingChoices([puma], SO101, puma.file);
    expect(value).toBe("");
    expect(options[0]).toEqual({ value: "", text: "no recording of the SO-101 with episodes (1 of another arm)", disabled: false, title: "" });
    expect(options[1]).toMatchObject({ value: puma.file, disabled: true });
    const why = "every recording here was made with another arm model than this server's SO-101";
    expect(whyNotRun({ ...ready, chosen: false, arm: why })).toBe(why);
    expect(recordingChoices([], SO101, "")).toEqual({ options: [{ value: "", text: "no recording with episodes", disabled: false, title: "" }], value: "" });
  });
});

describe("the Arm choice on a server of several arms", () => {
  it("offers each recorded arm on its own, or a one-arm recording on an arm named", () => {
    expect(armOptions(["arm"])).toEqual([]);
    expect(armOptions(["left", "right"]).map((o) => o.value)).toEqual(["", "left", "right"]);
    expect(armOptions(["left", "right"])[2]!.text).toBe("on right (a one-arm recording)");
  });
});
