// When a stalled picture gets a new video peer (transport/peer-silence.ts): only a peer
// whose packets stopped, or a picture that waited too long for its repair.
import { describe, expect, it } from "vitest";
import { PeerSilence, SILENT_PEER_MS, STALLED_PICTURE_MS, packetsIn } from "./transport/peer-silence";

describe("PeerSilence", () => {
  it("keeps a peer whose packets come again after an outage shorter than its limit", () => {
    const s = new PeerSilence(0);
    s.sample(100, 300); // the stall noticed: counters read
    s.sample(100, 1800); // the link down 1.5 s: nothing came
    expect(s.renegotiate(1800, 1800)).toBe(false); // the old rule re-negotiated at 1 s
    s.sample(140, 2100); // packets again (the server's key frame on the way)
    expect(s.renegotiate(2100, 3200)).toBe(false);
    expect(s.silentMs(3200)).toBe(1100);
  });

  it("re-negotiates a peer silent for SILENT_PEER_MS (a dropped peer, a restarted server)", () => {
    const s = new PeerSilence(0);
    s.sample(50, 300);
    s.sample(50, 300 + SILENT_PEER_MS - 1);
    expect(s.renegotiate(SILENT_PEER_MS, 300 + SILENT_PEER_MS - 1)).toBe(false);
    expect(s.renegotiate(SILENT_PEER_MS + 300, 300 + SILENT_PEER_MS)).toBe(true);
  });

  it("re-negotiates a picture stale STALLED_PICTURE_MS though packets arrive", () => {
    const s = new PeerSilence(0);
    for (let t = 300; t < STALLED_PICTURE_MS; t += 250) s.sample(t, t); // always arriving
    expect(s.renegotiate(STALLED_PICTURE_MS - 1, STALLED_PICTURE_MS - 1)).toBe(false);
    expect(s.renegotiate(STALLED_PICTURE_MS, STALLED_PICTURE_MS)).toBe(true);
    expect(s.renegotiate(null, STALLED_PICTURE_MS)).toBe(false); // live: never
  });

  it("counts a new peer's silence from its reset, not from the old one's", () => {
    const s = new PeerSilence(0);
    s.sample(10, 100);
    s.reset(5000);
    expect(s.silentMs(5500)).toBe(500);
    s.sample(0, 5600); // a new peer's counters start at zero: that is a change
    expect(s.silentMs(5600)).toBe(0);
  });

  it("counts video packets and the transport's bytes, nothing else", () => {
    const stats = [
      { type: "inbound-rtp", kind: "video", packetsReceived: 7 },
      { type: "inbound-rtp", kind: "audio", packetsReceived: 100 },
      { type: "transport", bytesReceived: 1000 },
      { type: "candidate-pair", bytesReceived: 5 },
    ];
    expect(packetsIn(stats)).toBe(1007);
  });
});
