// The review page: a recording played back on one timeline — both eyes of the recorded
// video (the MP4 the server remuxes from the recorded H.264, played and seeked by a
// <video>) with the AR ball and the ghost arm at the recorded *predicted* pose (the
// commanded target joints, as the live page draws them) beside a thin ring at the
// recorded actual tool position, both projected with the calibration in force at that
// moment; the force plot with a cursor, the episodes and the safety events on a strip
// under it (and listed), and the command log. Pause, seek, 0.25–4× speed. The picture is
// the live page's: without the cameras' timecode stripe (review/frame.ts). Whatever the
// recording lacks (video, forces, commands, episodes) is left out, not shown empty.
// A multi-arm recording (review/arms.ts) plays every arm back: each arm's ghost and ring
// through P · its mount, its forces in a band of the plot of its own, and its joints at
// the cursor in a readout under the plot.
// Data: GET /api/v1/recordings/{id}/timeline, …/video.mp4, /api/v1/robot/arms and
// /api/v1/robot/model (each recorded arm's, from the server's arm of its name).
// Loading (issue 55): a loading indicator from the first moment (review/loading.ts); the
// video asked for at once (not after the timeline: the server makes it first), then the
// timeline's first piece, the player drawing the picture as soon as it comes; the rest of
// the timeline a piece at a time (review/recording.ts), the plots and lists growing as
// each comes, the cursor working meanwhile. Nothing is drawn again while nothing changed
// (a paused picture, a still cursor): the CPU goes to what is loading. The list of
// recordings (the picker: maybe a read of recordings not listed yet) once all is there.
// `data-review-ready` once the whole timeline is there.
// Each part is set up by a module of review/ (the recording, the player, the command log,
// the marks strip, the force plot, the joints readout, the overlay), each returning a
// handle whose update(t) the frame loop below calls with the time at the cursor.
import { Api, MessageLog, readToken, withoutToken } from "./api";
import { setupCommandLog } from "./review/command-log";
import { setupForcePlot } from "./review/force-plot";
import { setupJointsReadout } from "./review/joints-readout";
import { setupLoading } from "./review/loading";
import { setupMarksStrip } from "./review/marks-strip";
import { setupOverlay } from "./review/overlay";
import { setupPlayer } from "./review/player";
import { growRecording, lastPiece, loadModels, loadPiece, pieceAfter, shapeRecording, type ReviewContext } from "./review/recording";
import { setupRecordingPick } from "./review/recording-pick";
import { exposeForTests, recordingTestView, type ReviewTestView } from "./review/test-view";
import { $ } from "./ui/dom";

const api = new Api(`${location.origin}/`, readToken(location.search, localStorage, sessionStorage));
const recordingId = new URLSearchParams(location.search).get("id") ?? "";
history.replaceState(history.state, "", withoutToken(location.href));
const log = new MessageLog($("messages"));

/** A part of the page drawn at the cursor's time, and grown as the timeline's pieces come. */
interface Part {
  update(t: number): void;
  grow?(): void;
}

async function main(): Promise<void> {
  if (!recordingId) {
    void setupRecordingPick(recordingId);
    $("review-loading").hidden = true;
    log.add("open a recording: review.html?id=<file name> (or pick one above)");
    return;
  }
  $("review-name").textContent = recordingId;
  const loading = setupLoading();
  // The video asked for first (the server's reads run one at a time, the video's first),
  // then the timeline's first piece. The <video>'s own request leaves later, from the
  // browser's media stack (after the timeline's, seen on a busy machine): a request of
  // the page's own (one byte of it) has the server start making it at once.
  prepareVideo(recordingId);
  const player = setupPlayer(recordingId, log);
  const video = player.testView.video;
  loading.follow(video);
  const waiting = (why: string | null) => {
    loading.state.timelineWaiting = why;
    loading.show();
  };
  let range = pieceAfter(0, null);
  const firstPiece = loadPiece(api, recordingId, range, waiting);
  let view: Partial<ReviewTestView> = { ...player.testView, loading: loading.state };
  exposeForTests(view as ReviewTestView);

  // Every frame the cursor moved or something changed (a video frame, a piece, a model):
  // everything at the cursor's time (the parts there are so far).
  const parts: Part[] = [];
  let overlay: ReturnType<typeof setupOverlay> | null = null;
  let drawnAt = NaN;
  let changed = true;
  const redraw = () => (changed = true);
  for (const event of ["loadeddata", "seeked", "resize"]) video.addEventListener(event, redraw);
  function frame(): void {
    const t = player.cursorTime();
    if (changed || t !== drawnAt) {
      changed = false;
      drawnAt = t;
      player.update(t);
      // The overlay over the picture, not without one.
      if (player.drawPicture()) overlay?.update(t);
      for (const part of parts) part.update(t);
    }
    requestAnimationFrame(frame);
  }
  requestAnimationFrame(frame);

  const piece = await firstPiece.catch((e: Error) => {
    loading.state.timelineFailed = e.message;
    loading.show();
    throw e;
  });
  const recording = shapeRecording(recordingId, piece, []);
  const ctx: ReviewContext = { recording, log };
  player.know(recording);
  if (video.getAttribute("src") === null) loading.state.video = "none";
  void loadModels(api, recording, log).then(redraw);
  const commandLog = setupCommandLog(ctx);
  const marksStrip = setupMarksStrip(ctx, player.seekTo);
  const forcePlot = setupForcePlot(ctx);
  parts.push(setupJointsReadout(ctx), forcePlot, marksStrip, commandLog);
  overlay = setupOverlay(ctx, player.picture);
  // For tests (review/test-view.ts): what the timeline holds so far, and the video.
  const expose = () => {
    view = { ...recordingTestView(recording), ...player.testView, ...overlay?.testView, ...forcePlot.testView, ...commandLog.testView, ...marksStrip.testView, loading: loading.state };
    exposeForTests(view as ReviewTestView);
  };
  const grown = (loadedTo: number, complete: boolean) => {
    Object.assign(loading.state, { loadedTo, duration: recording.duration, timelineComplete: complete });
    loading.show();
    expose();
    redraw();
  };

  // The rest of the timeline, a piece at a time, each appended as it comes.
  let complete = lastPiece(range, recording.duration);
  grown(range.end_s ?? recording.duration, complete);
  while (!complete) {
    range = pieceAfter(range.end_s ?? recording.duration, recording.duration);
    try {
      growRecording(recording, await loadPiece(api, recordingId, range, waiting));
    } catch (e) {
      loading.state.timelineFailed = (e as Error).message;
      loading.show();
      throw e;
    }
    for (const part of parts) part.grow?.();
    complete = lastPiece(range, recording.duration);
    grown(range.end_s ?? recording.duration, complete);
  }
  document.body.dataset.reviewReady = "1";
}

/** Has the server make the recording's video now (its first byte asked for, with the
 * token when the page has one; the answer is not needed: the <video> asks for it all). */
function prepareVideo(id: string): void {
  const url = `${location.origin}/api/v1/recordings/${encodeURIComponent(id)}/video.mp4`;
  const headers: Record<string, string> = { Range: "bytes=0-0", ...(api.token ? { Authorization: `Bearer ${api.token}` } : {}) };
  void fetch(url, { headers, cache: "no-store" }).catch(() => undefined);
}

main()
  .catch((e: Error) => log.add(e.message, true))
  .finally(() => {
    if (recordingId) void setupRecordingPick(recordingId); // once the recording is there (or failed)
  });
