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
        return Promise.resolve(RELAY);
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
    expect(asked).toEqual(["get /api/v1/video/ice", "get /api/v1/video/ice"]);
    expect(made).toEqual([rtcConfiguration(RELAY), rtcConfiguration(RELAY)]);
    expect(made[0]?.iceTransportPolicy).toBe("relay");
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
