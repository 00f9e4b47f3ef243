// The review page's loading indicator (issue 55): from the first moment (review.html
// shows it before any script runs) until the timeline and the video are both there, what
// is being loaded and how far — the timeline's seconds of the recording's, the video
// being prepared by the server (its MP4 is remuxed before it is sent) then received — as
// words and a bar. Pure words and fraction here (loadingWords, loadingFraction); the page
// shows them (setupLoading).
import { $ } from "../ui/dom";
import { formatTime } from "./timeline";

/** Where the video is: asked for (the server prepares it), arriving, ready to show, or none. */
export type VideoLoad = "asked" | "arriving" | "ready" | "none" | "failed";

export interface LoadState {
  /** Timeline s loaded (the pieces so far cover [0, loadedTo)). */
  loadedTo: number;
  /** The recording's length, once the first piece said it. */
  duration: number | null;
  timelineComplete: boolean;
  timelineFailed: string | null;
  /** The server said to wait (a read budget, its reads busy): its words, until it answers. */
  timelineWaiting: string | null;
  video: VideoLoad;
  /** Of the video received, 0–1 (while arriving). */
  videoFraction: number;
}

export function initialLoad(): LoadState {
  return { loadedTo: 0, duration: null, timelineComplete: false, timelineFailed: null, timelineWaiting: null, video: "asked", videoFraction: 0 };
}

function timelineWords(s: LoadState): string {
  if (s.timelineFailed !== null) return `timeline failed: ${s.timelineFailed}`;
  if (s.timelineComplete) return "timeline loaded";
  const waiting = s.timelineWaiting === null ? "" : ` (asked again shortly: ${s.timelineWaiting})`;
  if (s.duration === null) return `timeline: asking for its first seconds${waiting}`;
  return `timeline ${formatTime(Math.min(s.loadedTo, s.duration))} of ${formatTime(s.duration)}${waiting}`;
}

function videoWords(s: LoadState): string | null {
  switch (s.video) {
    case "asked":
      return "video: being prepared by the server";
    case "arriving":
      return `video ${Math.round(s.videoFraction * 100)} % received`;
    case "ready":
      return "video ready";
    case "failed":
      return "video failed";
    case "none":
      return null;
  }
}

/** "Loading the recording: timeline 0:10.0 of 2:06.0 · video: being prepared by the server". */
export function loadingWords(s: LoadState): string {
  return `Loading the recording: ${[timelineWords(s), videoWords(s)].filter((w) => w !== null).join(" · ")}`;
}

/** How far, 0–1: the timeline's share of the recording and the video's received share, alike. */
export function loadingFraction(s: LoadState): number {
  const timeline = s.timelineComplete ? 1 : s.duration ? Math.min(s.loadedTo / s.duration, 1) : 0;
  if (s.video === "none" || s.video === "failed") return timeline;
  const video = s.video === "ready" ? 1 : s.video === "arriving" ? Math.min(s.videoFraction, 1) * 0.9 : 0;
  return (timeline + video) / 2;
}

/** Whether there is nothing left to wait for (the indicator goes). */
export function loadingDone(s: LoadState): boolean {
  const timeline = s.timelineComplete || s.timelineFailed !== null;
  return timeline && s.video !== "asked" && s.video !== "arriving";
}

export interface LoadingHandle {
  state: LoadState;
  /** Shows the state as it is now (call after changing it). */
  show(): void;
  /** Follows the <video>'s loading: prepared, arriving, ready. */
  follow(video: HTMLVideoElement): void;
}

export function setupLoading(): LoadingHandle {
  const box = $("review-loading");
  const bar = $<HTMLProgressElement>("review-loading-bar");
  const words = $("review-loading-text");
  const state = initialLoad();
  const show = () => {
    bar.value = loadingFraction(state);
    words.textContent = loadingWords(state);
    box.hidden = loadingDone(state);
  };
  show();
  return {
    state,
    show,
    follow(video) {
      const received = () => {
        const end = video.buffered.length ? video.buffered.end(video.buffered.length - 1) : 0;
        return Number.isFinite(video.duration) && video.duration > 0 ? end / video.duration : 0;
      };
      video.addEventListener("progress", () => {
        if (state.video !== "asked" && state.video !== "arriving") return;
        state.video = "arriving";
        state.videoFraction = received();
        show();
      });
      video.addEventListener("loadeddata", () => {
        if (state.video === "none") return;
        state.video = "ready";
        show();
      });
      video.addEventListener("error", () => {
        if (state.video === "none") return;
        state.video = "failed";
        show();
      });
    },
  };
}
