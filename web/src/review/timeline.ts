// The review page's pure parts: which recorded sample stands at a time, the speeds,
// and the force plot's geometry.
export const SPEEDS = [0.25, 0.5, 1, 2, 4] as const;

/** The index of the last item whose `time` ≤ t (-1 if none): items sorted by time. */
export function latestAt(items: readonly { time: number }[], t: number): number {
  let lo = 0;
  let hi = items.length - 1;
  let found = -1;
  while (lo <= hi) {
    const mid = (lo + hi) >> 1;
    if ((items[mid]?.time ?? Infinity) <= t) {
      found = mid;
      lo = mid + 1;
    } else hi = mid - 1;
  }
  return found;
}

/** Timeline seconds of a video time (the MP4's 0 is the first frame's capture). */
export function timelineOf(videoTime: number, videoStart: number | null | undefined): number {
  return videoTime + (videoStart ?? 0);
}

/** The video time of a timeline time, within the video. */
export function videoTimeOf(t: number, videoStart: number | null | undefined, videoDuration: number): number {
  const v = t - (videoStart ?? 0);
  return Math.min(Math.max(v, 0), Number.isFinite(videoDuration) ? videoDuration : v);
}

/** The symmetric y range of a force plot: the largest magnitude (≥ 1 N). */
export function forceRange(samples: readonly { values: readonly number[] }[]): number {
  let m = 1;
  for (const s of samples) for (const v of s.values) m = Math.max(m, Math.abs(v));
  return m;
}

/** "m:ss.s", rounded to a tenth first (119.97 s is 2:00.0, not 1:60.0). */
export function formatTime(s: number): string {
  const tenths = Math.round(s * 10);
  const m = Math.floor(tenths / 600);
  return `${m}:${((tenths - m * 600) / 10).toFixed(1).padStart(4, "0")}`;
}
