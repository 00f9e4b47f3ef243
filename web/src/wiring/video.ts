// The video: the WebRTC peer kept up by itself (a failed or stalled peer is
// re-negotiated, with backoff), the glass-to-glass meter on a copy of its track, and the
// connection HUD over the picture (RTT, loss, video, freezes, force and command age).
import { Rolling } from "../stats";
import type { RealtimeLink } from "../transport/link";
import { PeerSilence, packetsIn } from "../transport/peer-silence";
import { VideoConnection, layerParam } from "../transport/video";
import type { Alignment } from "../ui/alignment";
import { ConnectionHud } from "../ui/connection-hud";
import { $ } from "../ui/dom";
import { measureGlass } from "../view/glass";
import type { PageContext } from "./context";

export interface VideoHandle {
  connection: VideoConnection;
  /** Capture → presented, ms, for every frame the page decoded. */
  glass: Rolling;
  /** The interval between frames drawn, ms. */
  videoInterval: Rolling;
  hud: ConnectionHud;
}

export function setupVideo(ctx: PageContext, link: RealtimeLink, alignment: Alignment): VideoHandle {
  const { api, log, view, video } = ctx;
  const glass = new Rolling(900);
  const videoInterval = new Rolling(900);
  let glassMeter: { stop(): void } | null = null;
  const connection = new VideoConnection(api, {
    onStream: (stream) => {
      video.srcObject = stream;
      void video.play();
      const track = stream.getVideoTracks()[0];
      glassMeter?.stop(); // the previous peer's copy: its frames are read no more
      glassMeter = track ? measureGlass(track.clone(), link, glass, () => (view.nativeSize ? 2 * view.nativeSize.width : null)) : null;
    },
    onPeer: (peer) => alignment.useVideoPeer(peer),
    onError: (text) => log.add(text),
    layer: layerParam(location.search),
  });
  // Leaving the page: the latency meter's queued frames are closed, not left to the
  // garbage collector (which Chromium reports on the console, "A VideoFrame was garbage
  // collected without being closed": seen as a page closed on a busy machine).
  addEventListener("pagehide", () => glassMeter?.stop());
  connection.start().catch((e: Error) => log.add(`video: ${e.message}`, true));
  const videoStatus = api.request("get", "/api/v1/video");
  videoStatus.then((v) => (view.nativeSize = { width: v.width, height: v.height })).catch(() => undefined);
  const hud = new ConnectionHud({
    pc: () => connection.peer?.pc ?? null,
    link,
    force: () => ctx.arms.newestForce(),
    video: videoStatus,
    // its rate of the moment (30 while the machine cannot keep a configured 60) and why
    serverVideo: () => api.request("get", "/api/v1/video"),
  });
  hud.start($("hud"));
  view.onFrame = () => {
    const now = performance.now();
    videoInterval.tick(now);
    connection.frame();
    hud.frame(now);
  };
  view.onStale = stallWatch(connection);
  return { connection, glass, videoInterval, hud };
}

/** A stalled picture gets a new peer only when the peer is dead (its packets stopped)
 * or the picture has waited for a repair too long (transport/peer-silence.ts): the
 * counters are read, at most every 250 ms, only while the picture is stale. */
function stallWatch(connection: VideoConnection): (ms: number | null) => void {
  const silence = new PeerSilence(performance.now());
  let seen: RTCPeerConnection | null = null;
  let reading = false;
  let readAt = -Infinity;
  return (ms) => {
    const now = performance.now();
    const pc = connection.peer?.pc ?? null;
    if (pc !== seen) {
      seen = pc;
      silence.reset(now);
    }
    if (ms === null) {
      silence.reset(now); // live: a stall's silence counts from its first read
      return connection.stalled(null);
    }
    if (pc && !reading && now - readAt >= 250) {
      reading = true;
      readAt = now;
      pc.getStats()
        .then((stats) => silence.sample(packetsIn(stats.values() as Iterable<{ type: string }>), performance.now()))
        .catch(() => undefined)
        .finally(() => (reading = false));
    }
    if (silence.renegotiate(ms, now)) connection.stalled(ms);
  };
}
