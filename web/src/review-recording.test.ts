// The review page's recording as its parts play it (review/recording.ts) and what the
// tests are shown of it (review/test-view.ts).
import { describe, expect, it } from "vitest";
import { PUMA } from "./puma.fixture";
import { armStatesAt, camerasAt, hasVideo, shapeRecording } from "./review/recording";
import { recordingTestView } from "./review/test-view";

const P = [
  [800, 0, 320, 0],
  [0, 800, 240, 0],
  [0, 0, 1, 0],
];
const Q = [
  [800, 0, 320, -80],
  [0, 800, 240, 0],
  [0, 0, 1, 0],
];

describe("the recording as the review plays it", () => {
  const oneArm = {
    duration: 10,
    video_start: 0.5,
    topics: {
      "/robot/state": [
        { time: 1, position: [0, 0, 1], target_joints: [0, 0, 0, 0, 0, 0], joints: [0, 0, 0, 0, 0, 0] },
        { time: 2, position: [0, 0, 2] },
      ],
      "/force": [{ time: 1, values: [1, 2, 3, 0, 0, 0] }],
      "/commands": [{ time: 1.5, kind: "home", accepted: true, reason: "", source: "rest", client: "" }],
      "/episodes": [{ time: 1, event: "start", episode: 0, task: "pick" }],
      "/calibration": [
        { time: 0, cameras: { left: { P }, right: { P: Q } } },
        { time: 5, ground_truth_P: { left: Q, right: P } }, // a simulated camera's
      ],
    },
  };
  it("shapes a one-arm recording: its arm's series, commands, episodes, calibrations", () => {
    const r = shapeRecording("a.mcap", oneArm, [PUMA]);
    expect(r.arms.map((a) => a.name)).toEqual(["arm"]);
    expect(r.several).toBe(false);
    expect(r.models).toEqual([PUMA]);
    expect(r.armStates[0]?.length).toBe(2);
    expect(r.armForces[0]?.length).toBe(1);
    expect(r.commands.map((c) => c.kind)).toEqual(["home"]);
    expect(r.episodes.map((e) => [e.episode, e.task, e.end])).toEqual([[0, "pick", null]]);
    expect(r.safety).toEqual([]);
    expect(r.drove).toEqual([]);
    expect(r.calibrations.map((c) => c.cameras.map((cam) => cam.P))).toEqual([
      [P, Q],
      [Q, P], // the recorded ground truth where the cameras' own are not recorded
    ]);
    expect(hasVideo(r)).toBe(true);
    expect(hasVideo(shapeRecording("b", { ...oneArm, video_start: null }, []))).toBe(false);
  });
  it("finds each arm's state and the calibration in force at a time", () => {
    const r = shapeRecording("a.mcap", oneArm, []);
    expect(r.models).toEqual([null]); // not drawn, still played
    expect(armStatesAt(r, 0.5)).toEqual([undefined]);
    expect(armStatesAt(r, 1.9)[0]?.position).toEqual([0, 0, 1]);
    expect(armStatesAt(r, 9)[0]?.position).toEqual([0, 0, 2]);
    expect(camerasAt(r, 0)[0]?.P).toEqual(P);
    expect(camerasAt(r, 6)[0]?.P).toEqual(Q);
    expect(camerasAt({ calibrations: [] }, 1)).toEqual([]);
  });
  it("shapes a two-arm recording each arm on its own, and tells the tests so", () => {
    const r = shapeRecording(
      "two.mcap",
      {
        duration: 3,
        video_start: null,
        topics: {
          "/arms/left/state": [{ time: 0, position: [0, 0, 0] }, { time: 1, position: [0, 0, 0] }],
          "/arms/right/state": [{ time: 0, position: [1, 0, 0] }],
          "/arms/right/force": [{ time: 0, values: [0, 0, 0, 0, 0, 0] }],
        },
      },
      [PUMA, null],
    );
    expect(r.arms.map((a) => a.name)).toEqual(["left", "right"]);
    expect(r.several).toBe(true);
    expect(r.armForces.map((f) => f.length)).toEqual([0, 1]);
    expect(armStatesAt(r, 0.5).map((s) => s?.position)).toEqual([[0, 0, 0], [1, 0, 0]]);
    expect(recordingTestView(r)).toEqual({
      duration: 3,
      videoStart: null,
      states: 3,
      arms: [
        { name: "left", states: 2, forces: 0 },
        { name: "right", states: 1, forces: 1 },
      ],
    });
  });
});
