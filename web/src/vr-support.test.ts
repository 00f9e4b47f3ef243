import { describe, expect, it } from "vitest";
import { VR_NEEDS_HEADSET, VR_NEEDS_SECURE_PAGE, readXRSupport, vrFailureText, vrUnavailable } from "./ui/vr-support";

const desktop = { secure: true, xr: true, immersive: false }; // Chromium with no headset

describe("Enter VR where VR cannot start", () => {
  it("says a headset's browser or the WebXR emulator is needed, not the browser's words", () => {
    expect(vrUnavailable(desktop)).toBe(VR_NEEDS_HEADSET);
    expect(vrUnavailable({ secure: true, xr: false, immersive: null })).toBe(VR_NEEDS_HEADSET);
    expect(VR_NEEDS_HEADSET).toMatch(/headset's browser/);
    expect(VR_NEEDS_HEADSET).toMatch(/WebXR emulator/);
    const refused = { name: "NotSupportedError", message: "The specified session configuration is not supported." };
    expect(vrFailureText(refused, { ...desktop, immersive: null })).toBe(VR_NEEDS_HEADSET);
  });

  it("says https is needed on a page that is not secure (WebXR is not offered there)", () => {
    expect(vrUnavailable({ secure: false, xr: false, immersive: null })).toBe(VR_NEEDS_SECURE_PAGE);
    expect(vrFailureText({ name: "SecurityError", message: "x" }, { secure: true, xr: true, immersive: null })).toBe(VR_NEEDS_SECURE_PAGE);
  });

  it("lets a headset (or the emulator) try, and passes on any other failure with its message", () => {
    const headset = { secure: true, xr: true, immersive: true };
    expect(vrUnavailable(headset)).toBeNull();
    expect(vrFailureText({ name: "InvalidStateError", message: "a session is already active" }, headset)).toBe("VR did not start: a session is already active");
  });

  it("reads the browser's support without throwing", async () => {
    const nav = (xr: unknown) => ({ isSecureContext: true, navigator: { xr } as unknown as Navigator });
    expect(await readXRSupport(nav(undefined))).toEqual({ secure: true, xr: false, immersive: null });
    expect(await readXRSupport(nav({ isSessionSupported: () => Promise.resolve(true) }))).toEqual({ secure: true, xr: true, immersive: true });
    expect(await readXRSupport(nav({ isSessionSupported: () => Promise.reject(new Error("policy")) }))).toEqual({ secure: true, xr: true, immersive: null });
  });
});
