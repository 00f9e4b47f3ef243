// Stereo video over WebRTC: one POST with our offer, the server's answer back. Before
// each offer the page asks the server for its ICE servers (STUN; TURN with credentials
// minted for this peer) and whether video goes through TURN only (GET /api/v1/video/ice).
// VideoConnection keeps it up: when the peer fails or no frame has come for a while
// (a server restart, a dropped peer), it closes the old peer and negotiates a new one,
// retrying with a doubling backoff (0.5 s … 8 s) until frames flow again.
// On a server with a media server an observer's video comes through it (GET
// /api/v1/video says `path: "relay"`): the media server makes the offer, so the page
// takes the server's offer (POST /webrtc/server-offer) and answers it instead.
import type { Api, Schema } from "../api";

/** This page's video connection, and the secret that proves the server's peer is ours
 * (needed to close it and to save this viewer's alignment). */
export interface VideoPeer {
  pc: RTCPeerConnection;
  peerId: string;
  secret: string;
}

/** The server's ICE configuration as RTCPeerConnection takes it. */
export function rtcConfiguration(ice: Schema<"IceConfiguration">): RTCConfiguration {
  return {
    iceServers: ice.ice_servers.map((s) => ({
      urls: s.urls,
      ...(s.username != null ? { username: s.username } : {}),
      ...(s.credential != null ? { credential: s.credential } : {}),
    })),
    iceTransportPolicy: ice.ice_transport_policy,
  };
}

/** How long to wait for ICE candidates before offering (ms): host candidates are enough
 * on a LAN; a TURN server's relay address takes a round trip or two to it. */
export function gatherTimeoutMs(config: RTCConfiguration): number {
  const turn = (config.iceServers ?? []).some((s) => [s.urls].flat().some((u) => u.startsWith("turn")));
  return turn ? 5000 : 2000;
}

export type VideoLayer = "auto" | "full" | "low";
export const VIDEO_LAYERS: readonly VideoLayer[] = ["auto", "full", "low"];

/** The page's `?layer=full|low|auto` (pin the picture on a link known to be good or
 * poor); anything else: "auto". */
export function layerParam(search: string): VideoLayer {
  const asked = new URLSearchParams(search).get("layer") as VideoLayer | null;
  return asked && VIDEO_LAYERS.includes(asked) ? asked : "auto";
}

/** `layer`: "auto" lets the server choose by this page's link; "full" pins the full
 * picture (the calibration page measures pixels in it). */
export async function connectVideo(api: Api, onStream: (stream: MediaStream) => void, layer: VideoLayer = "auto"): Promise<VideoPeer> {
  // Fetched for each peer: TURN credentials are time-limited, and the media server
  // may have come or gone.
  const [ice, status] = await Promise.all([api.request("get", "/api/v1/video/ice"), api.request("get", "/api/v1/video")]);
  if (!status.enabled) throw new NoVideo();
  const config = rtcConfiguration(ice);
  const pc = new RTCPeerConnection(config);
  pc.ontrack = (ev) => {
    lowLatency(ev.receiver);
    onStream(ev.streams[0] ?? new MediaStream([ev.track]));
  };
  const gathered = () =>
    new Promise<void>((resolve) => {
      if (pc.iceGatheringState === "complete") return resolve();
      pc.addEventListener("icegatheringstatechange", () => pc.iceGatheringState === "complete" && resolve());
      setTimeout(resolve, gatherTimeoutMs(config));
    });
  let described: Schema<"PeerDescription"> | undefined;
  try {
    if (status.path === "relay") {
      described = await api.request("post", "/api/v1/webrtc/server-offer");
      await pc.setRemoteDescription({ sdp: described.sdp, type: "offer" });
      await pc.setLocalDescription(await pc.createAnswer());
      await gathered();
      await api.request("post", "/api/v1/webrtc/answer", {
        body: { sdp: pc.localDescription?.sdp ?? "", type: "answer", peer_id: described.peer_id, peer_secret: described.peer_secret },
      });
    } else {
      lowLatency(pc.addTransceiver("video", { direction: "recvonly" }).receiver);
      await pc.setLocalDescription(await pc.createOffer());
      await gathered();
      described = await api.request("post", "/api/v1/webrtc/offer", { body: { sdp: pc.localDescription?.sdp ?? "", type: "offer", layer } });
      await pc.setRemoteDescription({ sdp: described.sdp, type: described.type as RTCSdpType });
    }
  } catch (e) {
    // A failed attempt leaves nothing behind: neither this peer nor the server's.
    if (described) closeVideo(api, { pc, peerId: described.peer_id, secret: described.peer_secret });
    else pc.close();
    throw e;
  }
  const peer = { pc, peerId: described.peer_id, secret: described.peer_secret };
  // Leaving the page frees the server's peer at once, not after ICE gives up.
  const onHide = () => closeVideo(api, peer);
  window.addEventListener("pagehide", onHide);
  // Through the media server, say we still watch: it cannot tell a page that vanished.
  const alive = status.path === "relay" ? setInterval(() => void sayAlive(api, peer), ALIVE_MS) : null;
  onClose.set(peer, () => {
    window.removeEventListener("pagehide", onHide);
    if (alive !== null) clearInterval(alive);
  });
  return peer;
}

/** How often a page watching through the media server says it still does (the server
 * drops a peer after 45 s without: media_server_viewer_timeout_s). */
export const ALIVE_MS = 15_000;

async function sayAlive(api: Api, peer: VideoPeer): Promise<void> {
  await api
    .request("post", "/api/v1/webrtc/{peer_id}/alive", { params: { peer_id: peer.peerId }, headers: { "X-Peer-Secret": peer.secret } })
    .catch(() => undefined); // a lost one is made up by the next; a gone peer is renegotiated
}

/** No jitter buffer beyond what decoding needs: render frames as they arrive. */
function lowLatency(receiver: RTCRtpReceiver): void {
  const r = receiver as RTCRtpReceiver & { jitterBufferTarget?: number; playoutDelayHint?: number };
  r.jitterBufferTarget = 0;
  r.playoutDelayHint = 0;
}

const onClose = new WeakMap<VideoPeer, () => void>();

/** Close our peer here and on the server (which needs its secret); a server that is gone
 * has closed it already. */
export function closeVideo(api: Api, peer: VideoPeer): void {
  onClose.get(peer)?.();
  onClose.delete(peer);
  peer.pc.close();
  api
    .request("delete", "/api/v1/webrtc/{peer_id}", { params: { peer_id: peer.peerId }, keepalive: true, headers: { "X-Peer-Secret": peer.secret } })
    .catch(() => undefined);
}

/** The server sends no video (it was started with video off): no peer is made for it.
 * Making and dropping a peer every few seconds is not free: Chromium tears one down on
 * the page's main thread, which then stalls for 1–3 s (bench.held_control measured it),
 * long enough for the realtime worker to stop the dead-man heartbeats. */
export class NoVideo extends Error {
  constructor() {
    super("this server sends no video (it was started with video off)");
  }
}

/** Delays between attempts: `firstMs`, doubling up to `maxMs`; back to the first on reset. */
export class Backoff {
  private nextMs: number;

  constructor(
    readonly firstMs = 500,
    readonly maxMs = 8000,
  ) {
    this.nextMs = firstMs;
  }

  next(): number {
    const ms = this.nextMs;
    this.nextMs = Math.min(this.maxMs, ms * 2);
    return ms;
  }

  reset(): void {
    this.nextMs = this.firstMs;
  }
}

export interface VideoConnectionOptions {
  /** Each new stream (the first, and one per re-negotiation). */
  onStream: (stream: MediaStream) => void;
  /** Each new peer as it is negotiated (e.g. for the alignment's saves). */
  onPeer?: (peer: Promise<VideoPeer>) => void;
  onError?: (message: string) => void;
  /** Re-negotiate once the video has been stale this long (ms)… */
  staleMs?: number;
  /** …and the newest peer has had this long (ms) to bring its first frame. */
  graceMs?: number;
  backoff?: Backoff;
  /** The video layer asked for (default "auto": the server picks by this page's link). */
  layer?: VideoLayer;
}

/** This page's video, kept up: re-negotiated (a new RTCPeerConnection, the old one closed
 * with its secret) when it fails or stalls, with backoff, until frames flow again. */
export class VideoConnection {
  peer: VideoPeer | null = null;
  /** Peers negotiated after the first. */
  renegotiations = 0;
  private attempting = false;
  /** The server said it sends no video: its status is checked now and then, quietly. */
  noVideo = false;
  private timer: ReturnType<typeof setTimeout> | null = null;
  private attemptAt = -Infinity;
  private readonly backoff: Backoff;
  private readonly staleMs: number;
  private readonly graceMs: number;

  constructor(
    private readonly api: Api,
    private readonly options: VideoConnectionOptions,
  ) {
    this.backoff = options.backoff ?? new Backoff();
    this.staleMs = options.staleMs ?? 1000;
    this.graceMs = options.graceMs ?? 5000;
  }

  /** Negotiate the first peer. */
  start(): Promise<VideoPeer> {
    return this.attempt();
  }

  /** A frame arrived: the video is up; the next failure starts from the shortest delay. */
  frame(): void {
    this.backoff.reset();
  }

  /** How long the video has been stale (ms, null while live): long enough, and the
   * newest peer had its chance, and it is time to try again. */
  stalled(ms: number | null, now = performance.now()): void {
    if (ms === null || ms < this.staleMs || now - this.attemptAt < this.graceMs) return;
    this.retry(`no video for ${Math.round(ms)} ms`);
  }

  /** Try again after the backoff's next delay (one attempt at a time). On a server with
   * no video, only its status is asked again, every `maxMs`, and said once. */
  retry(why: string): void {
    if (this.attempting || this.timer !== null) return;
    const delay = this.noVideo ? this.backoff.maxMs : this.backoff.next();
    if (!this.noVideo) this.options.onError?.(`video: ${why}; reconnecting in ${(delay / 1000).toFixed(1)} s`);
    this.timer = setTimeout(() => {
      this.timer = null;
      this.attempt().catch(() => undefined);
    }, delay);
  }

  private attempt(): Promise<VideoPeer> {
    this.attempting = true;
    this.attemptAt = performance.now();
    const old = this.peer;
    this.peer = null;
    if (old) {
      closeVideo(this.api, old);
      this.renegotiations += 1;
    }
    const next = connectVideo(this.api, (stream) => this.options.onStream(stream), this.options.layer).then((peer) => {
      this.peer = peer;
      this.attemptAt = performance.now(); // its grace starts now
      peer.pc.addEventListener("connectionstatechange", () => {
        if (this.peer === peer && (peer.pc.connectionState === "failed" || peer.pc.connectionState === "closed")) this.retry(`peer ${peer.pc.connectionState}`);
      });
      return peer;
    });
    this.options.onPeer?.(next);
    next
      .then(() => (this.noVideo = false))
      .catch((e: Error) => {
        this.attempting = false;
        if (e instanceof NoVideo && !this.noVideo) this.options.onError?.(`video: ${e.message}`);
        this.noVideo = e instanceof NoVideo;
        this.retry(e.message);
      })
      .then(() => (this.attempting = false))
      .catch(() => undefined);
    return next;
  }
}

/** Save this viewer's shift of the right image on the server, through its own peer. */
export async function saveAlignment(api: Api, peer: VideoPeer, viewer: string, align: Schema<"Alignment">): Promise<void> {
  await api.request("put", "/api/v1/video/alignment", {
    query: { viewer },
    body: align,
    headers: { "X-Peer-Id": peer.peerId, "X-Peer-Secret": peer.secret },
  });
}
