// What of the recorded video the review page shows: the live page's picture, i.e. without
// the timecode stripe the simulated cameras draw at the top of
// each eye (drivers/camera/timecode.py) — a barcode the live page reads and crops
// (view/stereo.ts), and the recording keeps, since it records the frames as sent.

/** Rows at the top of each eye not shown: view/stereo.ts's TIMECODE_ROWS (a test holds
 * the two equal; not imported from there, which would bring three.js into this page). */
export const TIMECODE_ROWS = 28;

/** The part of a side-by-side frame drawn, and the canvas it is drawn on: every row
 * below the cropped ones (at least one row left, as the live page does), the overlay
 * moved up by `crop` (the calibration's pixels are the full camera image's). */
export function shownFrame(videoWidth: number, videoHeight: number, rows: number = TIMECODE_ROWS): { crop: number; width: number; height: number } {
  const crop = Math.max(0, Math.min(rows, videoHeight - 1));
  return { crop, width: videoWidth, height: Math.max(videoHeight - crop, 1) };
}
