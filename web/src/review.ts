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
// Each part is set up by a module of review/ (the recording, the player, the command log,
// the marks strip, the force plot, the joints readout, the overlay), each returning a
// handle whose update(t) the frame loop below calls with the time at the cursor.
import { Api, MessageLog, readToken, withoutToken } from "./api";
import { setupCommandLog } from "./review/command-log";
import { setupForcePlot } from "./review/force-plot";
import { setupJointsReadout } from "./review/joints-readout";
import { setupMarksStrip } from "./review/marks-strip";
import { setupOverlay } from "./review/overlay";
import { setupPlayer } from "./review/player";
import { loadRecording, type ReviewContext } from "./review/recording";
import { setupRecordingPick } from "./review/recording-pick";
import { exposeForTests, recordingTestView } from "./review/test-view";
import { $ } from "./ui/dom";

const api = new Api(`${location.origin}/`, readToken(location.search, localStorage, sessionStorage));
const recordingId = new URLSearchParams(location.search).get("id") ?? "";
history.replaceState(history.state, "", withoutToken(location.href));
const log = new MessageLog($("messages"));

async function main(): Promise<void> {
  void setupRecordingPick(recordingId);
  if (!recordingId) {
    log.add("open a recording: review.html?id=<file name> (or pick one above)");
    return;
  }
  $("review-name").textContent = recordingId;
  const ctx: ReviewContext = { recording: await loadRecording(api, recordingId, log), log };
  const player = setupPlayer(ctx);
  const commandLog = setupCommandLog(ctx);
  const marksStrip = setupMarksStrip(ctx, player.seekTo);
  const forcePlot = setupForcePlot(ctx);
  const jointsReadout = setupJointsReadout(ctx);
  const overlay = setupOverlay(ctx, player.picture);

  // Every frame, everything at the cursor's time.
  function frame(): void {
    const t = player.cursorTime();
    player.update(t);
    jointsReadout.update(t);
    if (player.drawPicture()) overlay.update(t); // the overlay over the picture, not without one
    forcePlot.update(t);
    marksStrip.update(t);
    commandLog.update(t);
    requestAnimationFrame(frame);
  }
  requestAnimationFrame(frame);
  // For tests (review/test-view.ts): what the timeline holds, and the video.
  exposeForTests({ ...recordingTestView(ctx.recording), ...player.testView, ...overlay.testView, ...forcePlot.testView, ...commandLog.testView, ...marksStrip.testView });
  document.body.dataset.reviewReady = "1";
}

main().catch((e: Error) => log.add(e.message, true));
