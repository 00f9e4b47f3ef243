// Stereo video over WebRTC: one POST with our offer, the server's answer back.

/** This page's video connection, and the secret that proves the server's peer is ours
 * (needed to close it and to save this viewer's alignment). */
export interface VideoPeer {
  pc: RTCPeerConnection;
  peerId: string;
  secret: string;
}

export async function connectVideo(base: string, onStream: (stream: MediaStream) => void): Promise<VideoPeer> {
  const pc = new RTCPeerConnection();
  const transceiver = pc.addTransceiver("video", { direction: "recvonly" });
  // No jitter buffer beyond what decoding needs: render frames as they arrive.
  const receiver = transceiver.receiver as RTCRtpReceiver & { jitterBufferTarget?: number; playoutDelayHint?: number };
  receiver.jitterBufferTarget = 0;
  receiver.playoutDelayHint = 0;
  pc.ontrack = (ev) => onStream(ev.streams[0] ?? new MediaStream([ev.track]));
  await pc.setLocalDescription(await pc.createOffer());
  await new Promise<void>((resolve) => {
    if (pc.iceGatheringState === "complete") return resolve();
    pc.addEventListener("icegatheringstatechange", () => pc.iceGatheringState === "complete" && resolve());
    setTimeout(resolve, 2000); // host candidates are enough on a LAN
  });
  const response = await fetch(`${base}api/v1/webrtc/offer`, {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ sdp: pc.localDescription?.sdp, type: "offer" }),
  });
  const body = (await response.json()) as { peer_id: string; peer_secret: string; sdp: string; type: RTCSdpType; detail?: string };
  if (!response.ok) throw new Error(body.detail ?? `video offer refused (${response.status})`);
  await pc.setRemoteDescription({ sdp: body.sdp, type: body.type });
  const peer = { pc, peerId: body.peer_id, secret: body.peer_secret };
  // Leaving the page frees the server's peer at once, not after ICE gives up.
  window.addEventListener("pagehide", () => {
    pc.close();
    void fetch(`${base}api/v1/webrtc/${encodeURIComponent(peer.peerId)}`, {
      method: "DELETE",
      keepalive: true,
      headers: { "Content-Type": "application/json", "X-Peer-Secret": peer.secret },
    });
  });
  return peer;
}

/** Save this viewer's shift of the right image on the server, through its own peer. */
export async function saveAlignment(base: string, peer: VideoPeer, viewer: string, align: { dx: number; dy: number }): Promise<void> {
  const response = await fetch(`${base}api/v1/video/alignment?viewer=${encodeURIComponent(viewer)}`, {
    method: "PUT",
    headers: { "Content-Type": "application/json", "X-Peer-Id": peer.peerId, "X-Peer-Secret": peer.secret },
    body: JSON.stringify(align),
  });
  if (!response.ok) {
    const body = (await response.json().catch(() => ({}))) as { detail?: string };
    throw new Error(body.detail ?? `alignment not saved (${response.status})`);
  }
}
