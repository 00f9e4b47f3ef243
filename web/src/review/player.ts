// The review's player: the recorded video (the MP4 the server remuxes from the recorded
// H.264, played and seeked by a <video>) drawn on the page's canvas as the live page shows
// it — without the cameras' timecode stripe (review/frame.ts) — with play/pause, 0.25–4×
// speed and a seek slider on the recording's timeline. Without video, the slider is the
// time and there is no picture.
// Set up before the timeline (issue 55): the video is asked for at once, its picture
// shown as soon as it comes; the recording's length and the video's place on the
// timeline are known from the timeline's first piece (know()); until then the video's own
// time is the cursor's.
import type { MessageLog } from "../api";
import { $ } from "../ui/dom";
import { shownFrame } from "./frame";
import { hasVideo, type ReviewRecording } from "./recording";
import type { ReviewTestView } from "./test-view";
import { SPEEDS, formatTime, timelineOf, videoTimeOf } from "./timeline";

/** What the player needs of the recording (from the timeline's first piece). */
type Known = Pick<ReviewRecording, "duration" | "videoStart">;

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
  /** The recording's length and its video's start are known (the timeline's first
   * piece): the slider spans it; a recording without video shows no picture. */
  know(recording: Known): void;
  testView: Pick<ReviewTestView, "video" | "frame" | "pictures">;
}

/** The timeline time at the cursor: the video's time on the timeline, or without video the slider's value. */
export function cursorTime(videoStart: number | null | undefined, sliderValue: number, videoTime: number): number {
  return videoStart === null || videoStart === undefined ? sliderValue : timelineOf(videoTime, videoStart);
}

export function setupPlayer(id: string, log: MessageLog): PlayerHandle {
  const video = $<HTMLVideoElement>("review-video");
  const canvas = $<HTMLCanvasElement>("review-view");
  const context = canvas.getContext("2d");
  const seek = $<HTMLInputElement>("review-seek");
  const time = $("review-time");
  let known: Known | null = null;
  let withVideo = true; // until the timeline says otherwise: asked for at once
  const videoStart = () => (known ? known.videoStart : 0); // before: the video's own time
  setupControls(video, seek, videoStart);
  video.src = `${location.origin}/api/v1/recordings/${encodeURIComponent(id)}/video.mp4`;
  video.onerror = () => {
    if (withVideo) log.add(`video: ${video.error?.message ?? "cannot play"}`, true);
  };
  // The part of each frame shown: the rows below the timecode stripe (as the live page).
  const shown: ShownFrame = { crop: 0, width: canvas.width, height: canvas.height };
  const pictures = { drawn: 0 };
  video.onloadedmetadata = () => {
    Object.assign(shown, shownFrame(video.videoWidth, video.videoHeight));
    canvas.width = shown.width;
    canvas.height = shown.height;
    if (!known && Number.isFinite(video.duration)) seek.max = String(video.duration);
  };
  return {
    picture: { canvas, context, shown },
    cursorTime: () => cursorTime(videoStart(), Number(seek.value), video.currentTime),
    seekTo(t) {
      seek.value = String(t);
      if (withVideo) video.currentTime = videoTimeOf(t, videoStart(), video.duration);
    },
    update(t) {
      if (document.activeElement !== seek) seek.value = String(t);
      time.textContent = `${formatTime(t)} / ${known ? formatTime(known.duration) : "…"}`;
    },
    drawPicture() {
      if (!withVideo || !context || video.readyState < 2) return false;
      context.drawImage(video, 0, shown.crop, shown.width, shown.height, 0, 0, canvas.width, canvas.height);
      pictures.drawn++;
      return true;
    },
    know(recording) {
      known = recording;
      seek.max = String(recording.duration);
      if (hasVideo(recording)) return;
      withVideo = false;
      log.add("this recording has no video");
      canvas.hidden = true; // not a black box where there is no picture
      video.removeAttribute("src");
      video.load();
    },
    testView: { video, frame: shown, pictures },
  };
}

/** Play/pause, the speeds and the seek slider, on the recording's timeline. */
function setupControls(video: HTMLVideoElement, seek: HTMLInputElement, videoStart: () => number | null | undefined): void {
  const play = $<HTMLButtonElement>("review-play");
  const speed = $<HTMLSelectElement>("review-speed");
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
    video.currentTime = videoTimeOf(Number(seek.value), videoStart(), video.duration);
  };
}
