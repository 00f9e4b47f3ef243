import { describe, expect, it } from "vitest";
import { DrawPacer, GPU_POLL_MS } from "./view/draw-pacer";

/** A pacer on a GPU that is busy while `busy` says so, with timers run by hand. */
function rig() {
  const state = { busy: false, draws: 0 };
  const timers: Array<{ f: () => void; ms: number }> = [];
  const pacer = new DrawPacer(
    () => state.busy,
    () => (state.draws += 1),
    (f, ms) => void timers.push({ f, ms }),
  );
  const runTimers = () => {
    for (const t of timers.splice(0)) t.f();
  };
  return { state, timers, pacer, runTimers };
}

describe("drawing no faster than the GPU finishes", () => {
  it("draws every frame at once while the GPU keeps up", () => {
    const { state, pacer, timers } = rig();
    for (let i = 0; i < 5; i++) pacer.request();
    expect(state.draws).toBe(5);
    expect(timers).toHaveLength(0);
    expect([pacer.waited, pacer.skipped]).toEqual([0, 0]);
  });

  it("queues nothing behind a draw the GPU has not finished: the newest frame is drawn once it has", () => {
    const { state, pacer, timers, runTimers } = rig();
    state.busy = true;
    pacer.request(); // waits
    pacer.request(); // newer frames while waiting: skipped, the waiting draw shows them
    pacer.request();
    expect(state.draws).toBe(0);
    expect(timers.map((t) => t.ms)).toEqual([GPU_POLL_MS]); // one look at a time
    runTimers(); // still busy: looks again
    expect(state.draws).toBe(0);
    expect(timers).toHaveLength(1);
    state.busy = false;
    runTimers();
    expect(state.draws).toBe(1);
    expect([pacer.waited, pacer.skipped]).toEqual([1, 2]);
    pacer.request(); // caught up: at once again
    expect(state.draws).toBe(2);
  });
});
