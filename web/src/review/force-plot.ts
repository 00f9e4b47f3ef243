// The review's force plot: each arm's recorded forces and torques (six axes, one colour
// each) in a band of its own, on the recording's time axis, with a cursor at the time
// shown. No force sensor recorded: no plot.
import { $ } from "../ui/dom";
import { forceBand } from "./arms";
import type { ForceSample, ReviewContext } from "./recording";
import type { ReviewTestView } from "./test-view";
import { forceRange } from "./timeline";

const FORCE_COLOURS = ["#e44", "#4c4", "#48f", "#e9e", "#ee4", "#4ee"];

export interface ForcePlotHandle {
  update(t: number): void;
  /** The plot's scale and extent again (the timeline's last piece brought more). */
  grow(): void;
  testView: Pick<ReviewTestView, "forces">;
}

/** The plot's x of timeline time s: the recording's length across `width` px. */
export function plotX(duration: number, width: number): (s: number) => number {
  return (s) => (s / Math.max(duration, 1e-6)) * width;
}

/** A band's y of a force or torque v: 0 in the band's middle, ±`range` 4 px inside its edges. */
export function bandY(band: { top: number; height: number }, range: number): (v: number) => number {
  return (v) => band.top + band.height / 2 - (v / range) * (band.height / 2 - 4);
}

/** A band's label: its scale (and, several arms, whose band it is). */
export function bandLabel(arm: string | null, range: number): string {
  return arm === null ? `±${range.toFixed(1)} N / N·m` : `${arm}  ±${range.toFixed(1)} N / N·m`;
}

export function setupForcePlot({ recording }: ReviewContext): ForcePlotHandle {
  const { armForces, arms, several } = recording; // (grown in place)
  const plot = $<HTMLCanvasElement>("review-force");
  const context = plot.getContext("2d");
  let range = 1;
  const testView = { forces: 0 };
  const grow = () => {
    const forces = armForces.flat();
    range = forceRange(forces);
    plot.hidden = forces.length === 0; // no force sensor recorded: no empty plot
    testView.forces = forces.length;
  };
  grow();
  // Several arms: the plot twice as tall, a band for each arm's forces.
  if (several) plot.height = plot.height * Math.min(arms.length, 4);
  return {
    update(t) {
      if (!context) return;
      const { width: w, height: h } = plot;
      context.clearRect(0, 0, w, h);
      const x = plotX(recording.duration, w);
      armForces.forEach((series, k) => {
        const band = forceBand(k, armForces.length, h);
        drawBand(context, series, x, bandY(band, range));
        context.fillStyle = "#ccc";
        context.fillText(bandLabel(several ? (arms[k]?.name ?? "") : null, range), 4, band.top + 12);
      });
      context.strokeStyle = "#fff";
      context.beginPath();
      context.moveTo(x(t), 0);
      context.lineTo(x(t), h);
      context.stroke();
    },
    grow,
    testView,
  };
}

/** One arm's forces and torques: a line per axis. */
function drawBand(context: CanvasRenderingContext2D, series: readonly ForceSample[], x: (s: number) => number, y: (v: number) => number): void {
  for (let axis = 0; axis < 6; axis++) {
    context.strokeStyle = FORCE_COLOURS[axis] ?? "#fff";
    context.beginPath();
    series.forEach((f, i) => (i ? context.lineTo(x(f.time), y(f.values[axis] ?? 0)) : context.moveTo(x(f.time), y(f.values[axis] ?? 0))));
    context.stroke();
  }
}
