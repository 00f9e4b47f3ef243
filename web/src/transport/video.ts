// Stereo video over WebRTC: one POST with our offer, the server's answer back.
export async function connectVideo(base: string, onStream: (stream: MediaStream) => void): Promise<RTCPeerConnection> {
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
  const body = await response.json();
  if (!response.ok) throw new Error(body.detail ?? `video offer refused (${response.status})`);
  await pc.setRemoteDescription({ sdp: body.sdp, type: body.type });
  // Leaving the page frees the server's peer at once, not after ICE gives up.
  window.addEventListener("pagehide", () => {
    pc.close();
    void fetch(`${base}api/v1/webrtc/${body.peer_id}`, { method: "DELETE", keepalive: true });
  });
  return pc;
}
