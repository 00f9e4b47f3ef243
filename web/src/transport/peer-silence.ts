// When a stalled picture is worth a new video peer. The page re-negotiated after one
// second without a frame; on a lossy link that made things worse: after bench.wan's
// 1.5 s outage on `mobile` the peer was alive (its packets came again within a round
// trip, the server sent a key frame on the decoder's request) but the page had already
// thrown it away, and the new one (offer, ICE and DTLS over a 300 ms round trip, then
// a key frame) froze the picture for 2.4 s more: frozen 2.7 % before the outage, 22 %
// over the leg. A peer is only as dead as its packets say.

/** No packet (RTP or RTCP) for this long: the server's side of the peer is gone (a
 * restarted server, a dropped peer) or the link is; a new peer is the way back. Longer
 * than an outage a lease survives (its grace is 2 s) plus a bad link's round trip. */
export const SILENT_PEER_MS = 3000;
/** Packets arrive but no picture for this long: the decoder waits for a repair (its
 * key-frame request is answered within round trips) that never comes: a new peer. */
export const STALLED_PICTURE_MS = 6000;

/** The counters that say packets still arrive, from the peer's getStats. */
export function packetsIn(stats: Iterable<{ type: string; kind?: string; packetsReceived?: number; bytesReceived?: number }>): number {
  let n = 0;
  for (const r of stats) {
    if (r.type === "inbound-rtp" && r.kind === "video") n += r.packetsReceived ?? 0;
    if (r.type === "transport") n += r.bytesReceived ?? 0; // RTCP too (the sender's reports)
  }
  return n;
}

/** Watches one peer's packet counters (`sample`, whenever read) and says, for a picture
 * stale `staleMs`, whether to re-negotiate. Times on the page's clock (ms). */
export class PeerSilence {
  private count: number | null = null;
  private changedAt: number;

  constructor(now: number) {
    this.changedAt = now;
  }

  /** The counters now (`packetsIn`); a new peer's start again from its first read. */
  sample(count: number, now: number): void {
    if (this.count === null || count !== this.count) this.changedAt = now;
    this.count = count;
  }

  /** A new peer: silent from now on only once its counters stop. */
  reset(now: number): void {
    this.count = null;
    this.changedAt = now;
  }

  silentMs(now: number): number {
    return now - this.changedAt;
  }

  /** Whether a picture stale `staleMs` (null: live) should get a new peer now. */
  renegotiate(staleMs: number | null, now: number): boolean {
    if (staleMs === null) return false;
    return this.silentMs(now) >= SILENT_PEER_MS || staleMs >= STALLED_PICTURE_MS;
  }
}
