// Stereo video over WebRTC: one POST with our offer, the server's answer back.
import type { Api, Schema } from "../api";

/** This page's video connection, and the secret that proves the server's peer is ours
 * (needed to close it and to save this viewer's alignment). */
export interface VideoPeer {
  pc: RTCPeerConnection;
  peerId: string;
  secret: string;
}

export async function connectVideo(api: Api, onStream: (stream: MediaStream) => void): Promise<VideoPeer> {
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
  const answer = await api.request("post", "/api/v1/webrtc/offer", { body: { sdp: pc.localDescription?.sdp ?? "", type: "offer" } });
  await pc.setRemoteDescription({ sdp: answer.sdp, type: answer.type as RTCSdpType });
  const peer = { pc, peerId: answer.peer_id, secret: answer.peer_secret };
  // Leaving the page frees the server's peer at once, not after ICE gives up.
  window.addEventListener("pagehide", () => {
    pc.close();
    api
      .request("delete", "/api/v1/webrtc/{peer_id}", { params: { peer_id: peer.peerId }, keepalive: true, headers: { "X-Peer-Secret": peer.secret } })
      .catch(() => undefined);
  });
  return peer;
}

/** Save this viewer's shift of the right image on the server, through its own peer. */
export async function saveAlignment(api: Api, peer: VideoPeer, viewer: string, align: Schema<"Alignment">): Promise<void> {
  await api.request("put", "/api/v1/video/alignment", {
    query: { viewer },
    body: align,
    headers: { "X-Peer-Id": peer.peerId, "X-Peer-Secret": peer.secret },
  });
}
