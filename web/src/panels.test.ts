import { describe, expect, it, vi } from "vitest";
import { FRAME_KEYS } from "./input/loop";
import { helpKeyAction, helpSections } from "./ui/help";
import { HomeButton } from "./ui/panels";
import { FORCE_AXES, forceRows, orientationText, rotvecFromMatrix, rpyFromMatrix, speedText } from "./ui/readouts";

const deg = (r: number[]) => r.map((a) => Number(((a * 180) / Math.PI).toFixed(6)));
const Rx = (a: number) => [[1, 0, 0], [0, Math.cos(a), -Math.sin(a)], [0, Math.sin(a), Math.cos(a)]];
const Ry = (a: number) => [[Math.cos(a), 0, Math.sin(a)], [0, 1, 0], [-Math.sin(a), 0, Math.cos(a)]];
const Rz = (a: number) => [[Math.cos(a), -Math.sin(a), 0], [Math.sin(a), Math.cos(a), 0], [0, 0, 1]];
const mul = (a: number[][], b: number[][]) => a.map((row) => b[0]!.map((_, j) => row.reduce((s, v, k) => s + v * b[k]![j]!, 0)));
const rad = (d: number) => (d * Math.PI) / 180;

describe("the tool's orientation", () => {
  it("is roll/pitch/yaw with R = Rz(yaw) Ry(pitch) Rx(roll)", () => {
    expect(deg(rpyFromMatrix([[1, 0, 0], [0, 1, 0], [0, 0, 1]]))).toEqual([0, 0, 0]);
    const R = mul(Rz(rad(30)), mul(Ry(rad(-20)), Rx(rad(45))));
    expect(deg(rpyFromMatrix(R))).toEqual([45, -20, 30]);
    expect(deg(rpyFromMatrix(Rx(rad(180))))).toEqual([180, 0, 0]);
  });

  it("at pitch ±90° puts it all in yaw (gimbal lock), and the matrix still comes back", () => {
    const R = mul(Rz(rad(40)), Ry(rad(90)));
    const [roll, pitch, yaw] = rpyFromMatrix(R);
    expect(roll).toBe(0);
    expect(deg([pitch])[0]).toBeCloseTo(90, 4);
    const back = mul(Rz(yaw), mul(Ry(pitch), Rx(roll)));
    back.forEach((row, i) => row.forEach((v, j) => expect(v).toBeCloseTo(R[i]![j]!, 6)));
  });

  it("as a rotation vector: axis × angle, at 0°, in between and at 180°", () => {
    expect(rotvecFromMatrix([[1, 0, 0], [0, 1, 0], [0, 0, 1]])).toEqual([0, 0, 0]);
    expect(deg(rotvecFromMatrix(Ry(rad(90))))).toEqual([0, 90, 0]); // the home pose qn's
    const axis = [1, 2, 2].map((v) => v / 3);
    // Rodrigues: R = I + sin θ K + (1 − cos θ) K²
    const rodrigues = (a: number[], t: number) => {
      const K = [[0, -a[2]!, a[1]!], [a[2]!, 0, -a[0]!], [-a[1]!, a[0]!, 0]];
      const K2 = mul(K, K);
      return K.map((row, i) => row.map((v, j) => (i === j ? 1 : 0) + Math.sin(t) * v + (1 - Math.cos(t)) * K2[i]![j]!));
    };
    for (const t of [1e-8, 0.3, 2, Math.PI - 1e-4, Math.PI]) {
      const rv = rotvecFromMatrix(rodrigues(axis, t));
      rv.forEach((v, i) => expect(Math.abs(v)).toBeCloseTo(axis[i]! * t, 6));
      if (t < 3) rv.forEach((v, i) => expect(v).toBeCloseTo(axis[i]! * t, 6));
    }
  });

  it("reads as degrees (the rotation vector checked against pinocchio.log3)", () => {
    expect(orientationText(mul(Rz(rad(90)), Rx(rad(-12.5))))).toBe("rotation vector -9.8, -9.8, 89.6° · roll -12.5° pitch 0.0° yaw 90.0°");
    expect(orientationText([[0, 1e-17, 1], [-1e-17, 1, -1e-17], [-1, -1e-17, 1e-17]])).toBe("rotation vector 0.0, 90.0, 0.0° · roll 0.0° pitch 90.0° yaw 0.0°"); // never -0.0
  });
});

describe("the force rows", () => {
  it("name each axis, give its value with its unit and a bar against the limit", () => {
    const rows = forceRows([10, -25, 60, 0.5, -0.001, -1], 50); // no "-0.00"
    expect(rows.map((r) => r.axis)).toEqual([...FORCE_AXES]);
    expect(rows.map((r) => r.text)).toEqual(["10.00 N", "-25.00 N", "60.00 N", "0.50 N·m", "0.00 N·m", "-1.00 N·m"]);
    expect(rows.map((r) => r.percent)).toEqual([20, 50, 100, 1, 0.002, 2]);
    expect(rows.map((r) => r.over)).toEqual([false, false, true, false, false, false]);
  });
});

describe("the speed's value", () => {
  it("shows two decimals", () => {
    expect(speedText(0.5)).toBe("0.50");
    expect(speedText(0.35)).toBe("0.35");
    expect(speedText(Number.NaN)).toBe("—");
  });
});

describe("the help", () => {
  it("? toggles it; Escape closes it only when open (the e-stop is the loop's, untouched)", () => {
    expect(helpKeyAction("?", false)).toBe("toggle");
    expect(helpKeyAction("?", true)).toBe("toggle");
    expect(helpKeyAction("Escape", true)).toBe("close");
    expect(helpKeyAction("Escape", false)).toBeNull();
    expect(helpKeyAction("w", true)).toBeNull();
  });

  it("lists every key and control, and the frames the loop has", () => {
    const text = JSON.stringify(helpSections(["view", "base", "wrist", "tool"], { Digit4: "view", Digit1: "base", Digit2: "wrist", Digit3: "tool" }));
    for (const needed of ["Space", "W / S", "A / D", "R / F", "Q / E", "Escape", "E-STOP", "1 / 2 / 3 / 4", "base / wrist / tool / view", "away from / toward the camera", "Alt + arrows", "fullscreen", "R1", "Y", "grip / pinch", "Home"]) {
      expect(text).toContain(needed);
    }
    // the page's own list: every frame the loop has, by its key
    const own = JSON.stringify(helpSections());
    expect(own).toContain(Object.keys(FRAME_KEYS).sort().map((code) => code.replace("Digit", "")).join(" / "));
    for (const frame of Object.values(FRAME_KEYS)) expect(own).toContain(frame);
  });
});

describe("the Home button", () => {
  const setup = (request: () => Promise<unknown>) => {
    const api = { request: vi.fn(request) };
    const log = { add: vi.fn() };
    const home = new HomeButton(api as never, { clientId: "client-7" }, log);
    return { api, log, home };
  };

  it("asks for a second click, then initialises as the client holding the lease", async () => {
    const { api, log, home } = setup(() => Promise.resolve({}));
    home.click();
    expect(home.step).toBe("confirm");
    expect(api.request).not.toHaveBeenCalled();
    home.click();
    expect(home.step).toBe("moving");
    home.click(); // ignored while the move is in flight
    expect(api.request).toHaveBeenCalledTimes(1);
    expect(api.request).toHaveBeenCalledWith("post", "/api/v1/robot/initialize", { body: {}, headers: { "X-Client-Id": "client-7" } });
    await vi.waitFor(() => expect(home.step).toBe("idle"));
    expect(log.add).toHaveBeenLastCalledWith("home: at the home pose");
  });

  it("puts an error in the log", async () => {
    const { log, home } = setup(() => Promise.reject(new Error("only the client in control can move the arm")));
    home.click();
    home.click();
    await vi.waitFor(() => expect(home.step).toBe("idle"));
    expect(log.add).toHaveBeenLastCalledWith("home: only the client in control can move the arm", true);
  });

  it("forgets an unconfirmed click", () => {
    vi.useFakeTimers();
    try {
      const { api, home } = setup(() => Promise.resolve({}));
      home.click();
      vi.advanceTimersByTime(5000);
      expect(home.step).toBe("idle");
      home.click();
      expect(api.request).not.toHaveBeenCalled();
    } finally {
      vi.useRealTimers();
    }
  });
});
