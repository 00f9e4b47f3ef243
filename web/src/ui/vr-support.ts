// "Enter VR" where VR cannot start says what is needed, not the browser's words ("The
// specified session configuration is not supported" told a new user nothing): WebXR is
// offered only to secure pages (https, or localhost), and an immersive session needs a
// headset — the headset's own browser, or on a desktop the WebXR emulator extension.

export const VR_NEEDS_HEADSET =
  "VR needs a WebXR headset: open this page in the headset's browser (e.g. the Meta Quest Browser), " +
  "or on a desktop add the WebXR emulator (the Immersive Web Emulator extension for Chrome or Edge) and reload";
export const VR_NEEDS_SECURE_PAGE =
  "VR needs this page over https (or on localhost): browsers offer WebXR only to secure pages. " +
  "Serve it with TLS, or open it on the machine that runs the server";

/** What the page can tell before asking for a session. */
export interface XRSupport {
  /** window.isSecureContext */
  secure: boolean;
  /** navigator.xr exists */
  xr: boolean;
  /** navigator.xr.isSessionSupported("immersive-vr"); null: not asked or it failed */
  immersive: boolean | null;
}

/** Why VR cannot start here, or null when it may. */
export function vrUnavailable(s: XRSupport): string | null {
  if (!s.secure) return VR_NEEDS_SECURE_PAGE;
  if (!s.xr || s.immersive === false) return VR_NEEDS_HEADSET;
  return null;
}

/** The message for a failed "Enter VR": the browser's refusals said as what is needed. */
export function vrFailureText(error: { name?: string; message?: string }, s: XRSupport): string {
  const why = vrUnavailable(s);
  if (why) return why;
  if (error.name === "NotSupportedError" || /not supported/i.test(error.message ?? "")) return VR_NEEDS_HEADSET;
  if (error.name === "SecurityError") return VR_NEEDS_SECURE_PAGE;
  return `VR did not start: ${error.message ?? String(error)}`;
}

type XRSystemLike = { isSessionSupported?(mode: string): Promise<boolean> };

/** Ask the browser (never throws). */
export async function readXRSupport(win: { isSecureContext: boolean; navigator: Navigator }): Promise<XRSupport> {
  const xr = (win.navigator as Navigator & { xr?: XRSystemLike }).xr;
  let immersive: boolean | null = null;
  try {
    if (xr?.isSessionSupported) immersive = await xr.isSessionSupported("immersive-vr");
  } catch {
    immersive = null; // e.g. blocked by a permissions policy: the session request will say
  }
  return { secure: win.isSecureContext, xr: xr !== undefined, immersive };
}
