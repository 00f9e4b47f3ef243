// The review's player: the recorded video (the MP4 the server remuxes from the recorded
// H.264, played and seeked by a <video>) drawn on the page's canvas as the live page shows
// it — without the cameras' timecode stripe (review/frame.ts) — with play/pause, 0.25–4×
// speed and a seek slider on the recording's timeline. Without video, the slider is the
// time and there is no picture.
import { $ } from "../ui/dom";
import { shownFrame } from "./frame";
import { hasVideo, type ReviewContext } from "./recording";
import type { ReviewTestView } from "./test-view";
import { SPEEDS, formatTime, timelineOf, videoTimeOf } from "./timeline";

/** The part of each frame shown, and the canvas's size: `crop` rows cut at the top. */
export interface ShownFrame {
  crop: number;
  width: number;
  height: number;
}

/** The canvas the picture is drawn on, for what is drawn over it (camera pixels moved up by `shown.crop`). */
export interface Picture {
  canvas: HTMLCanvasElement;
  context: CanvasRenderingContext2D | null;
  shown: ShownFrame;
}

export interface PlayerHandle {
  picture: Picture;
  /** The timeline time at the cursor: the video's, or without video the slider's. */
  cursorTime(): number;
  /** Go to timeline time t (the video follows; without one, the slider is the time). */
  seekTo(t: number): void;
  /** Shows time t on the slider (unless it is being dragged) and in words. */
  update(t: number): void;
  /** Draws the video's current frame, cropped, on the canvas; false while there is none
   * (nothing to draw over). */
  drawPicture(): boolean;
  testView: Pick<ReviewTestView, "video" | "frame">;
}

/** The timeline time at the cursor: the video's time on the timeline, or without video the slider's value. */
export function cursorTime(videoStart: number | null | undefined, sliderValue: number, videoTime: number): number {
  return videoStart === null || videoStart === undefined ? sliderValue : timelineOf(videoTime, videoStart);
}

export function setupPlayer({ recording, log }: ReviewContext): PlayerHandle {
  const video = $<HTMLVideoElement>("review-video");
  const canvas = $<HTMLCanvasElement>("review-view");
  const context = canvas.getContext("2d");
  const seek = $<HTMLInputElement>("review-seek");
  const time = $("review-time");
  const withVideo = hasVideo(recording);
  setupControls(video, seek, recording);
  if (withVideo) {
    video.src = `${location.origin}/api/v1/recordings/${encodeURIComponent(recording.id)}/video.mp4`;
    video.onerror = () => log.add(`video: ${video.error?.message ?? "cannot play"}`, true);
  } else log.add("this recording has no video");
  canvas.hidden = !withVideo; // not a black box where there is no picture
  // The part of each frame shown: the rows below the timecode stripe (as the live page).
  const shown: ShownFrame = { crop: 0, width: canvas.width, height: canvas.height };
  video.onloadedmetadata = () => {
    Object.assign(shown, shownFrame(video.videoWidth, video.videoHeight));
    canvas.width = shown.width;
    canvas.height = shown.height;
  };
  return {
    picture: { canvas, context, shown },
    cursorTime: () => cursorTime(recording.videoStart, Number(seek.value), video.currentTime),
    seekTo(t) {
      seek.value = String(t);
      if (withVideo) video.currentTime = videoTimeOf(t, recording.videoStart, video.duration);
    },
    update(t) {
      if (document.activeElement !== seek) seek.value = String(t);
      time.textContent = `${formatTime(t)} / ${formatTime(recording.duration)}`;
    },
    drawPicture() {
      if (!context || video.readyState < 2) return false;
      context.drawImage(video, 0, shown.crop, shown.width, shown.height, 0, 0, canvas.width, canvas.height);
      return true;
    },
    testView: { video, frame: shown },
  };
}

/** Play/pause, the speeds and the seek slider, on the recording's timeline. */
function setupControls(video: HTMLVideoElement, seek: HTMLInputElement, recording: ReviewContext["recording"]): void {
  const play = $<HTMLButtonElement>("review-play");
  const speed = $<HTMLSelectElement>("review-speed");
  seek.max = String(recording.duration);
  for (const s of SPEEDS) {
    const o = document.createElement("option");
    o.value = String(s);
    o.textContent = `${s}×`;
    o.selected = s === 1;
    speed.append(o);
  }
  speed.onchange = () => (video.playbackRate = Number(speed.value));
  play.onclick = () => (video.paused ? void video.play() : video.pause());
  video.onplay = () => (play.textContent = "Pause");
  video.onpause = () => (play.textContent = "Play");
  seek.oninput = () => {
    video.currentTime = videoTimeOf(Number(seek.value), recording.videoStart, video.duration);
  };
}
