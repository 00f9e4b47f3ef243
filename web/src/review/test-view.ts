// What the review page shows its browser tests as `window.review` (read by
// tests/test_web_review.py, tests/test_web_review_arms.py, tests/test_web_recording.py and
// tests/test_web_review_loading.py): each part of the page gives its fields as its
// handle's `testView`, and review.ts puts them together here, in one object, again as
// each piece of the timeline comes (the player's and the loading's first: before any).
// Renaming or reshaping a field breaks those tests.
import type { LoadState } from "./loading";
import type { OverlayPixels } from "./overlay";
import type { ShownFrame } from "./player";
import type { DroveSpan, ReviewEpisode, SafetyMark } from "./marks";
import type { ReviewRecording } from "./recording";

export interface ReviewTestView {
  /** The <video> playing the recording: tests wait for its frames, seek and play it. */
  video: HTMLVideoElement;
  /** What the overlay shows now, per eye (0 left, 1 right): the predicted tool and the
   * actual one, camera pixels (the first arm's; every arm's by name in `overlay.arms`). */
  overlay: OverlayPixels;
  /** The recording's length: s from its first message to its last. */
  duration: number;
  /** Timeline s of the video's time 0 (its first frame's capture); null: no video. */
  videoStart: number | null | undefined;
  /** How many force samples the plot has (every arm's). */
  forces: number;
  /** How many arm states the recording has (every arm's). */
  states: number;
  /** How many commands the command log lists. */
  commands: number;
  /** The episodes as the strip and the event list show them. */
  episodes: ReviewEpisode[];
  /** The safety events as the strip and the event list show them. */
  safety: SafetyMark[];
  /** Who drove when (a supervised policy's recording; else none). */
  drove: DroveSpan[];
  /** The part of each frame shown: the rows below the timecode stripe (`crop` rows cut),
   * set once the video's size is known (the same object all along). */
  frame: ShownFrame;
  /** Each recorded arm: its name, and how many states and force samples it has. */
  arms: { name: string; states: number; forces: number }[];
  /** How many times a video frame was drawn on the canvas (live: the same object all along). */
  pictures: { drawn: number };
  /** What the loading indicator shows: the timeline's seconds loaded, the video's state
   * (live: the same object all along). */
  loading: LoadState;
}

/** The recording's own fields of the test view (its length, its video, its arms). */
export function recordingTestView(recording: ReviewRecording): Pick<ReviewTestView, "duration" | "videoStart" | "states" | "arms"> {
  return {
    duration: recording.duration,
    videoStart: recording.videoStart,
    states: recording.armStates.flat().length,
    arms: recording.arms.map((a, k) => ({ name: a.name, states: recording.armStates[k]?.length ?? 0, forces: recording.armForces[k]?.length ?? 0 })),
  };
}

/** Shows the tests `view` as `window.review`. */
export function exposeForTests(view: ReviewTestView): void {
  Object.assign(window, { review: view });
}
