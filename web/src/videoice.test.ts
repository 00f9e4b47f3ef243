// The page's video peer takes its ICE servers and policy from the server (TURN, relay-only).
import { afterEach, describe, expect, it, vi } from "vitest";
import type { Api, Schema } from "./api";
import { connectVideo, gatherTimeoutMs, layerParam, rtcConfiguration } from "./transport/video";

const RELAY: Schema<"IceConfiguration"> = {
  ice_servers: [
    { urls: ["stun:turn.example.org:3478"], username: null, credential: null },
    { urls: ["turn:turn.example.org:3478?transport=udp", "turn:turn.example.org:3478?transport=tcp"], username: "1800000000:telerobot-viewer", credential: "c2VjcmV0" },
  ],
  ice_transport_policy: "relay",
  expires_at: 1800000000,
};

describe("rtcConfiguration", () => {
  it("hands the server's servers, minted TURN credentials and relay-only policy to RTCPeerConnection", () => {
    expect(rtcConfiguration(RELAY)).toEqual({
      iceServers: [
        { urls: ["stun:turn.example.org:3478"] },
        { urls: ["turn:turn.example.org:3478?transport=udp", "turn:turn.example.org:3478?transport=tcp"], username: "1800000000:telerobot-viewer", credential: "c2VjcmV0" },
      ],
      iceTransportPolicy: "relay",
    });
    expect(rtcConfiguration({ ice_servers: [], ice_transport_policy: "all" })).toEqual({ iceServers: [], iceTransportPolicy: "all" });
  });

  it("waits longer for candidates when a TURN server must hand out a relay address", () => {
    expect(gatherTimeoutMs(rtcConfiguration(RELAY))).toBe(5000);
    expect(gatherTimeoutMs({ iceServers: [{ urls: "stun:stun.example.org" }] })).toBe(2000);
    expect(gatherTimeoutMs({})).toBe(2000);
  });
});

describe("connectVideo", () => {
  afterEach(() => vi.unstubAllGlobals());

  it("asks for the ICE configuration first, for each new peer", async () => {
    const asked: string[] = [];
    const made: RTCConfiguration[] = [];
    const api = {
      request: (method: string, path: string) => {
        asked.push(`${method} ${path}`);
        return Promise.resolve(path === "/api/v1/video" ? { path: "direct", enabled: true } : RELAY);
      },
    } as unknown as Api;
    vi.stubGlobal(
      "RTCPeerConnection",
      class {
        constructor(config: RTCConfiguration) {
          made.push(config);
          throw new Error("no WebRTC here");
        }
      },
    );
    await expect(connectVideo(api, () => undefined)).rejects.toThrow("no WebRTC here");
    await expect(connectVideo(api, () => undefined)).rejects.toThrow("no WebRTC here");
    expect(asked).toEqual(["get /api/v1/video/ice", "get /api/v1/video", "get /api/v1/video/ice", "get /api/v1/video"]);
    expect(made).toEqual([rtcConfiguration(RELAY), rtcConfiguration(RELAY)]);
    expect(made[0]?.iceTransportPolicy).toBe("relay");
  });
});

describe("connectVideo through a media server", () => {
  afterEach(() => vi.unstubAllGlobals());

  it("takes the server's offer and answers it when its path is the relay", async () => {
    const asked: { call: string; body?: unknown }[] = [];
    const api = {
      request: (method: string, path: string, options?: { body?: unknown }) => {
        asked.push({ call: `${method} ${path}`, body: options?.body });
        if (path === "/api/v1/video/ice") return Promise.resolve({ ice_servers: [], ice_transport_policy: "all" });
        if (path === "/api/v1/video") return Promise.resolve({ path: "relay", enabled: true });
        if (path === "/api/v1/webrtc/server-offer") return Promise.resolve({ peer_id: "relay-abc", peer_secret: "s3cret", sdp: "v=0 janus", type: "offer" });
        return Promise.resolve({ peer_id: "relay-abc" });
      },
    } as unknown as Api;
    const remote: RTCSessionDescriptionInit[] = [];
    let transceivers = 0;
    vi.stubGlobal(
      "RTCPeerConnection",
      class {
        iceGatheringState = "complete";
        localDescription: RTCSessionDescriptionInit | null = null;
        addTransceiver() {
          transceivers += 1;
        }
        addEventListener() {}
        setRemoteDescription(d: RTCSessionDescriptionInit) {
          remote.push(d);
          return Promise.resolve();
        }
        createAnswer() {
          return Promise.resolve({ type: "answer", sdp: "v=0 ours" });
        }
        setLocalDescription(d: RTCSessionDescriptionInit) {
          this.localDescription = d;
          return Promise.resolve();
        }
      },
    );
    vi.stubGlobal("window", { addEventListener: () => undefined, removeEventListener: () => undefined });
    const peer = await connectVideo(api, () => undefined);
    expect(asked.map((a) => a.call)).toEqual(["get /api/v1/video/ice", "get /api/v1/video", "post /api/v1/webrtc/server-offer", "post /api/v1/webrtc/answer"]);
    expect(remote).toEqual([{ sdp: "v=0 janus", type: "offer" }]);
    expect(asked[3]?.body).toEqual({ sdp: "v=0 ours", type: "answer", peer_id: "relay-abc", peer_secret: "s3cret" });
    expect(transceivers).toBe(0); // the media server's offer has the video in it
    expect(peer.peerId).toBe("relay-abc");
    expect(peer.secret).toBe("s3cret");
  });

  it("says it is alive every 15 s, and a failed answer leaves no peer behind", async () => {
    vi.useFakeTimers();
    const asked: string[] = [];
    let failAnswer = false;
    let closed = 0;
    const api = {
      request: (method: string, path: string) => {
        asked.push(`${method} ${path}`);
        if (path === "/api/v1/video/ice") return Promise.resolve({ ice_servers: [], ice_transport_policy: "all" });
        if (path === "/api/v1/video") return Promise.resolve({ path: "relay", enabled: true });
        if (path === "/api/v1/webrtc/server-offer") return Promise.resolve({ peer_id: "relay-abc", peer_secret: "s3cret", sdp: "v=0", type: "offer" });
        if (path === "/api/v1/webrtc/answer" && failAnswer) return Promise.reject(new Error("503 relay_full"));
        return Promise.resolve({});
      },
    } as unknown as Api;
    vi.stubGlobal(
      "RTCPeerConnection",
      class {
        iceGatheringState = "complete";
        localDescription = { type: "answer", sdp: "v=0" };
        addEventListener() {}
        setRemoteDescription = () => Promise.resolve();
        createAnswer = () => Promise.resolve({ type: "answer", sdp: "v=0" });
        setLocalDescription = () => Promise.resolve();
        close() {
          closed += 1;
        }
      },
    );
    vi.stubGlobal("window", { addEventListener: () => undefined, removeEventListener: () => undefined });
    await connectVideo(api, () => undefined);
    asked.length = 0;
    await vi.advanceTimersByTimeAsync(31_000);
    expect(asked).toEqual(["post /api/v1/webrtc/{peer_id}/alive", "post /api/v1/webrtc/{peer_id}/alive"]);
    failAnswer = true;
    asked.length = 0;
    await expect(connectVideo(api, () => undefined)).rejects.toThrow("relay_full");
    expect(closed).toBe(1);
    expect(asked).toContain("delete /api/v1/webrtc/{peer_id}"); // the server's half, freed
    vi.useRealTimers();
  });
});

describe("the page's video layer", () => {
  it("is pinned by ?layer=full or low, else the server chooses", () => {
    expect(layerParam("?layer=low")).toBe("low");
    expect(layerParam("?token=x&layer=full")).toBe("full");
    expect(layerParam("")).toBe("auto");
    expect(layerParam("?layer=huge")).toBe("auto");
  });
});
