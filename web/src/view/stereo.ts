// The stereo views: mono, side-by-side, cross-eye, anaglyph (colour and Dubois),
// and WebXR immersive-vr where each eye sees its half of the side-by-side video.
// One shader source does it all, so the AR ball and the alignment shift are drawn the
// same way in every view; each mode compiles its own program (the MODE define) because
// a software GPU (SwiftShader, no GPU here) runs every branch of a per-pixel `if`,
// uniform or not: with one program for all modes it drew 5.7–7.4 side-by-side frames/s
// of 2×640×360 video, with one per mode 10.8–11.4, on the same 1.2 cores.
// Frames are rendered as they arrive (requestVideoFrameCallback), but never faster than
// the GPU finishes them (draw-pacer.ts).
// Over the video: the overlay layer (overlay.ts; other modules paint into it, in each
// camera's pixels), the AR ball as a ring (the gripper tip it marks shows through), and,
// when no frame has come for a while, the view dims and says "VIDEO STALE n ms".
// The timecode stripe the simulated cameras draw at the top (drivers/camera/timecode.py)
// is cropped from what is shown; every coordinate stays in full-camera-image pixels.
import * as THREE from "three";
import { DrawPacer, GpuFence } from "./draw-pacer";
import { OverlayCanvas, type Eye, type EyeSize, type OverlayPainter } from "./overlay";
import { FrameWatch } from "./staleness";

export const MODES = ["mono", "side-by-side", "cross-eye", "anaglyph", "anaglyph-dubois"] as const;
export type ViewMode = (typeof MODES)[number];
const MODE_INDEX: Record<ViewMode | "left-only" | "right-only", number> = {
  mono: 0,
  "side-by-side": 1,
  "cross-eye": 2,
  anaglyph: 3,
  "anaglyph-dubois": 4,
  "left-only": 5,
  "right-only": 6,
};

// Dubois' least-squares red/cyan matrices (rows: output R, G, B; columns: input R, G, B).
const DUBOIS_LEFT = new THREE.Matrix3().set(0.456, 0.5, 0.176, -0.04, -0.038, -0.016, -0.015, -0.021, -0.005);
const DUBOIS_RIGHT = new THREE.Matrix3().set(-0.043, -0.088, -0.002, 0.378, 0.734, -0.018, -0.072, -0.113, 1.226);

const FRAGMENT = /* glsl */ `
uniform sampler2D tex;
uniform sampler2D overlay; // both eyes side by side like the video, premultiplied alpha
uniform vec2 eye;       // one eye's size in pixels
uniform float cropTop;  // rows of each eye not shown (the timecode stripe)
uniform float dim;      // 0: the video as it is, 1: black (stale video)
uniform vec2 outSize;   // this quad's size in pixels
uniform vec2 shift;     // right image moved by this many pixels (x right, y down)
// AR balls (one per arm; BALLS of MAX_BALLS drawn): each shown or not, its centre in
// each camera's pixels, its colour.
uniform float showBall[MAX_BALLS];
uniform vec2 ballL[MAX_BALLS];
uniform vec2 ballR[MAX_BALLS];
uniform vec3 ballColor[MAX_BALLS];
uniform float radius;
uniform mat3 duboisL;
uniform mat3 duboisR;
varying vec2 vUv;

// px: a pixel of what is shown of one eye; drawn at the camera's pixel px + (0, cropTop).
vec3 sampleEye(int which, vec2 px) {
  px.y += cropTop;
  if (which == 1) px -= shift;
  if (px.x < 0.0 || px.y < 0.0 || px.x >= eye.x || px.y >= eye.y) return vec3(0.0);
  vec2 uv = vec2((px.x + float(which) * eye.x) / (2.0 * eye.x), 1.0 - px.y / eye.y);
  vec3 c = texture2D(tex, uv).rgb * (1.0 - dim);
  for (int k = 0; k < BALLS; k++) {
    if (showBall[k] > 0.5) {
      // A ring: the tip it marks shows through its middle.
      vec2 b = which == 0 ? ballL[k] : ballR[k];
      float e = abs(distance(px, b) - radius);
      float w = max(1.5, 0.2 * radius);
      if (e < w) c = ballColor[k];
      else if (e < w + 1.5) c = mix(ballColor[k], vec3(0.0), 0.6);
    }
  }
#if OVERLAY
  vec4 o = texture2D(overlay, uv);
  c = c * (1.0 - o.a) + o.rgb;
#endif
  return c;
}

void main() {
  vec2 p = vec2(vUv.x * outSize.x, (1.0 - vUv.y) * outSize.y);
#if MODE == 0 || MODE == 5
  vec3 c = sampleEye(0, p);
#elif MODE == 6
  vec3 c = sampleEye(1, p);
#elif MODE == 1 || MODE == 2
  int half_ = p.x < eye.x ? 0 : 1;
  int which = MODE == 1 ? half_ : 1 - half_;
  vec3 c = sampleEye(which, p - vec2(float(half_) * eye.x, 0.0));
#elif MODE == 3
  vec3 c = vec3(sampleEye(0, p).r, sampleEye(1, p).gb);
#else
  vec3 c = clamp(duboisL * sampleEye(0, p) + duboisR * sampleEye(1, p), 0.0, 1.0);
#endif
  gl_FragColor = vec4(c, 1.0);
}`;

const VERTEX = /* glsl */ `
varying vec2 vUv;
void main() { vUv = uv; gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0); }`;

export interface Ball {
  left: [number, number] | null;
  right: [number, number] | null;
}

/** The most AR balls drawn (one per arm); a program draws as many as the arms (BALLS). */
export const MAX_BALLS = 4;

/** Rows at the top of each camera image that the view does not show: the simulated
 * cameras' timecode stripe (drivers/camera/timecode.py: blocks of 16 px at y 8, a 4 px
 * black guard around them), which the page reads from the decoded frames itself. */
export const TIMECODE_ROWS = 28;
/** No new frame for this long: the view dims and says so. */
export const STALE_MS = 300;

/** What the dimmed view says: the stall in ms for its first 2 s (it changes at every
 * check, 20 times a second), then in whole seconds (once a second). */
export function staleText(ms: number): string {
  return ms < 2000 ? `VIDEO STALE ${Math.round(ms)} ms` : `VIDEO STALE ${Math.floor(ms / 1000)} s`;
}

export type { Eye, EyeSize, OverlayPainter };

interface Size {
  width: number;
  height: number;
}

/** The drawing buffer for a picture of `camera` pixels shown in a box `shown` CSS pixels
 * large, on a screen of `ratio` device pixels to a CSS pixel: no more pixels than the
 * screen shows, and never more than the camera's own. Every pixel drawn is shaded, and a
 * software GPU (SwiftShader, where there is no graphics hardware) shades them on the
 * CPU: 2×1280×720 side by side in a 640 px box is 16 pixels drawn for each one seen, and
 * the page drew 7–9 frames a second of 28 decoded (docs/PERFORMANCE.md). Null `shown`
 * (not laid out yet): the camera's size. */
export function drawingBufferSize(camera: Size, shown: Size | null, ratio: number): Size {
  const fit = shown ? Math.min(1, (shown.width * ratio) / camera.width, (shown.height * ratio) / camera.height) : 1;
  const scale = fit > 0 ? fit : 1;
  return { width: Math.max(1, Math.round(camera.width * scale)), height: Math.max(1, Math.round(camera.height * scale)) };
}

export class StereoView {
  readonly renderer: THREE.WebGLRenderer;
  private readonly scene = new THREE.Scene();
  private readonly camera = new THREE.OrthographicCamera(-0.5, 0.5, 0.5, -0.5, 0, 10);
  private readonly texture: THREE.VideoTexture;
  private readonly material: THREE.ShaderMaterial;
  private readonly xrMaterials: THREE.ShaderMaterial[] = [];
  private readonly xrGroup = new THREE.Group();
  mode: ViewMode = "side-by-side";
  frames = 0;
  /** Times the view was drawn (each costs the main thread a WebGL frame). */
  renders = 0;
  /** Video frames drawn once the GPU had done the draw before (`pacer.waited`), and
   * not drawn at all, a newer one having come meanwhile (`pacer.skipped`). */
  readonly pacer: DrawPacer;
  private readonly fence = new GpuFence(() => this.gl2());
  onFrame: ((metadata: VideoFrameCallbackMetadata) => void) | null = null;
  /** Each XR frame, before it is drawn: read the controllers here. */
  onXRFrame: ((frame: XRFrame, space: XRReferenceSpace) => void) | null = null;
  xrFrames = 0;
  /** Watches frame arrival: stale once no frame has come for STALE_MS. */
  readonly watch = new FrameWatch(STALE_MS, () => performance.now());
  /** How long the video has been stale (ms), or null while frames come. */
  staleMs: number | null = null;
  /** The last time the view turned stale: when the last frame had come, and when it said so (performance.now()). */
  lastStale: { lastFrameAt: number; reportedAt: number } | null = null;
  /** Told on every check (every ~frame interval) how long the video has been stale, or null. */
  onStale: ((ms: number | null) => void) | null = null;
  private readonly overlay = new OverlayCanvas();
  private readonly overlayTexture: THREE.CanvasTexture;
  private readonly xrQuads: THREE.Mesh[] = [];
  private cropTop = TIMECODE_ROWS;
  private container: HTMLElement | null = null;
  /** The box the picture is shown in (CSS pixels), once laid out. */
  private shown: Size | null = null;
  /** The picture in camera pixels (see layout()). */
  private output: Size = { width: 2560, height: 720 };
  /** Draw every camera pixel, whatever the box shows: for a test reading the canvas at
   * camera coordinates (tests/support/browser.py sets `telerobotDrawAtCameraPixels`). */
  drawAtCameraPixels = (globalThis as { telerobotDrawAtCameraPixels?: boolean }).telerobotDrawAtCameraPixels === true;

  constructor(
    readonly canvas: HTMLCanvasElement,
    readonly video: HTMLVideoElement,
  ) {
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
    this.renderer.outputColorSpace = THREE.LinearSRGBColorSpace; // pixels pass through untouched
    this.renderer.xr.enabled = true;
    this.texture = new THREE.VideoTexture(video);
    this.texture.colorSpace = THREE.NoColorSpace;
    this.texture.minFilter = THREE.NearestFilter;
    this.texture.magFilter = THREE.NearestFilter;
    this.overlayTexture = new THREE.CanvasTexture(this.overlay.canvas);
    this.overlayTexture.colorSpace = THREE.NoColorSpace;
    this.overlayTexture.premultiplyAlpha = true;
    this.overlayTexture.generateMipmaps = false;
    this.overlayTexture.minFilter = THREE.LinearFilter;
    this.overlayTexture.magFilter = THREE.LinearFilter;
    this.overlay.top = { paint: (ctx, eye, size) => this.paintStale(ctx, eye, size) };
    this.material = this.makeMaterial();
    this.scene.add(new THREE.Mesh(new THREE.PlaneGeometry(1, 1), this.material));
    this.camera.position.z = 1;
    // WebXR: one quad per eye, 2 m ahead; three.js shows layer 1 to the left eye, 2 to the right.
    for (const [eye, layer] of [["left-only", 1], ["right-only", 2]] as const) {
      const m = this.makeMaterial(MODE_INDEX[eye]);
      this.xrMaterials.push(m);
      const quad = new THREE.Mesh(new THREE.PlaneGeometry(1.6 * (16 / 9), 1.6), m);
      quad.position.set(0, 1.6, -2);
      quad.layers.set(layer);
      this.xrQuads.push(quad);
      this.xrGroup.add(quad);
    }
    this.xrGroup.add(this.xrBadge);
    this.xrBadge.position.set(0, 1.6 + 0.8 + 0.08, -2); // above the picture, seen by both eyes
    this.xrBadge.visible = false;
    this.xrGroup.visible = false;
    this.scene.add(this.xrGroup);
    this.renderer.xr.addEventListener("sessionstart", () => this.setXR(true));
    this.renderer.xr.addEventListener("sessionend", () => this.setXR(false));
    // In XR the headset's frame loop draws (the page's own frames pause there); input
    // from the XR controllers is read in the same frame, before drawing.
    this.renderer.setAnimationLoop((_time, frame) => {
      if (!this.renderer.xr.isPresenting) return;
      const space = this.renderer.xr.getReferenceSpace();
      if (frame && space) this.onXRFrame?.(frame, space);
      this.xrFrames += 1;
      this.render();
    });
    this.pacer = new DrawPacer(
      () => this.fence.busy(),
      () => {
        if (!this.renderer.xr.isPresenting) this.render();
      },
    );
    this.scheduleFrame();
    // Checked about once per frame interval; frames arriving do not need it.
    setInterval(() => this.checkStale(), 50);
  }

  /** Draw `painter` over the video (both eyes, every mode, WebXR); see overlay.ts. */
  addOverlay(painter: OverlayPainter): void {
    this.overlay.add(painter);
    this.overlayChanged();
  }

  /** Painters are called again before the next frame is drawn. */
  overlayChanged(): void {
    this.overlay.dirty = true;
  }

  /** Scale the canvas (CSS, aspect kept) to fill `container`, now and whenever it resizes. */
  fitInto(container: HTMLElement): void {
    this.container = container;
    new ResizeObserver(() => this.fitBox()).observe(container);
    this.fitBox();
  }

  private fitBox(): void {
    const box = this.container;
    if (!box || this.renderer.xr.isPresenting) return;
    const style = getComputedStyle(box);
    const w = box.clientWidth - parseFloat(style.paddingLeft) - parseFloat(style.paddingRight);
    const h = box.clientHeight - parseFloat(style.paddingTop) - parseFloat(style.paddingBottom);
    const { width, height } = this.output;
    const scale = Math.min(w / width, h / height);
    if (!(scale > 0)) return;
    this.shown = { width: Math.floor(width * scale), height: Math.floor(height * scale) };
    this.canvas.style.width = `${this.shown.width}px`;
    this.canvas.style.height = `${this.shown.height}px`;
    this.sizeBuffer();
  }

  /** The drawing buffer for the picture as shown (drawingBufferSize); the shader works in
   * camera pixels (outSize) whatever the buffer's size. */
  private sizeBuffer(): void {
    if (this.renderer.xr.isPresenting) return; // (in XR the session's layer sizes it)
    const shown = this.drawAtCameraPixels ? null : this.shown;
    const { width, height } = drawingBufferSize(this.output, shown, window.devicePixelRatio || 1);
    if (this.canvas.width !== width || this.canvas.height !== height) this.renderer.setSize(width, height, false);
  }

  /** Rows of each camera image not shown at the top: a shown pixel (x, y) is the
   * camera's pixel (x, y + croppedRows). */
  get croppedRows(): number {
    return this.cropTop;
  }

  /** Rows of each camera image not shown at the top (default: the timecode stripe). */
  setCropTop(rows: number): void {
    this.cropTop = rows;
    this.render();
  }

  private paintStale(ctx: CanvasRenderingContext2D, _eye: Eye, size: EyeSize): void {
    if (this.staleMs === null) return;
    const text = staleText(this.staleMs);
    const px = Math.max(12, Math.round(size.height / 10));
    ctx.font = `bold ${px}px system-ui, sans-serif`;
    ctx.textAlign = "center";
    ctx.textBaseline = "middle";
    const x = size.width / 2;
    const y = size.height / 2;
    const w = ctx.measureText(text).width + px;
    ctx.fillStyle = "rgba(0, 0, 0, 0.6)";
    ctx.fillRect(x - w / 2, y - px * 0.8, w, px * 1.6);
    ctx.fillStyle = "#ffb020";
    ctx.fillText(text, x, y);
  }

  /** Stale or not: dim and say so (the text updated as it grows), or clear both. */
  private checkStale(): void {
    const now = performance.now();
    const ms = this.watch.stale(now);
    const was = this.staleMs;
    if (ms === null && was === null) return this.onStale?.(null);
    if (ms !== null && was === null) this.lastStale = { lastFrameAt: this.watch.lastFrameAt, reportedAt: now };
    this.staleMs = ms;
    // Drawn again only when what it says changes: a long stall (a server with no video)
    // is redrawn once a second, not 20 times (each redraw of the view costs a software
    // GPU's main thread dearly, and a stalled page misses its dead-man heartbeats).
    if (ms === null || was === null || staleText(ms) !== staleText(was)) {
      this.overlayChanged();
      for (const m of this.all()) m.uniforms.dim!.value = ms === null ? 0 : 0.6;
      if (!this.renderer.xr.isPresenting) this.pacer.request();
    }
    this.onStale?.(ms);
  }

  private makeMaterial(mode = MODE_INDEX["side-by-side"]): THREE.ShaderMaterial {
    return new THREE.ShaderMaterial({
      vertexShader: VERTEX,
      fragmentShader: FRAGMENT,
      defines: { MODE: mode, OVERLAY: 1, BALLS: 1, MAX_BALLS },
      uniforms: {
        tex: { value: this.texture },
        overlay: { value: this.overlayTexture },
        cropTop: { value: TIMECODE_ROWS },
        dim: { value: 0 },
        eye: { value: new THREE.Vector2(1280, 720) },
        outSize: { value: new THREE.Vector2(2560, 720) },
        shift: { value: new THREE.Vector2(0, 0) },
        showBall: { value: Array.from({ length: MAX_BALLS }, () => 0) },
        ballL: { value: Array.from({ length: MAX_BALLS }, () => new THREE.Vector2(-1000, -1000)) },
        ballR: { value: Array.from({ length: MAX_BALLS }, () => new THREE.Vector2(-1000, -1000)) },
        radius: { value: 10 },
        ballColor: { value: Array.from({ length: MAX_BALLS }, () => new THREE.Color(0x00ff66)) },
        duboisL: { value: DUBOIS_LEFT },
        duboisR: { value: DUBOIS_RIGHT },
      },
    });
  }

  /** A line above the picture in the headset (a policy's supervision: who drives); an
   * empty text hides it. The header is not seen there. */
  setXRBadge(text: string, colour: string): void {
    this.xrBadge.visible = text !== "";
    if (!text) return;
    const canvas = this.xrBadgeCanvas;
    const g = canvas.getContext("2d");
    if (!g) return;
    g.clearRect(0, 0, canvas.width, canvas.height);
    g.fillStyle = colour;
    g.fillRect(0, 0, canvas.width, canvas.height);
    g.fillStyle = "#fff";
    g.font = "bold 40px sans-serif";
    g.textBaseline = "middle";
    g.fillText(text, 16, canvas.height / 2, canvas.width - 32);
    (this.xrBadge.material as THREE.MeshBasicMaterial).map!.needsUpdate = true;
  }

  private readonly xrBadgeCanvas = Object.assign(document.createElement("canvas"), { width: 1024, height: 64 });
  private readonly xrBadge = new THREE.Mesh(
    new THREE.PlaneGeometry(1.6, 0.1),
    new THREE.MeshBasicMaterial({ map: new THREE.CanvasTexture(this.xrBadgeCanvas), transparent: true }),
  );

  private setXR(on: boolean): void {
    this.xrGroup.visible = on;
    this.scene.children[0]!.visible = !on;
  }

  private all(): THREE.ShaderMaterial[] {
    return [this.material, ...this.xrMaterials];
  }

  setAlignment(dx: number, dy: number): void {
    for (const m of this.all()) (m.uniforms.shift!.value as THREE.Vector2).set(dx, dy);
    this.render();
  }

  /** Draw the AR ball of arm `k` (0 for the only one; under MAX_BALLS). */
  setBall(ball: Ball, show: boolean, colour: string, radius: number, k = 0): void {
    if (k < 0 || k >= MAX_BALLS) return;
    for (const m of this.all()) {
      (m.uniforms.showBall!.value as number[])[k] = show && ball.left !== null ? 1 : 0;
      if (ball.left) (m.uniforms.ballL!.value as THREE.Vector2[])[k]!.set(...ball.left);
      if (ball.right) (m.uniforms.ballR!.value as THREE.Vector2[])[k]!.set(...ball.right);
      // Our pixels bypass colour management, so the picked colour is used as it is.
      (m.uniforms.ballColor!.value as THREE.Color[])[k]!.setStyle(colour, THREE.LinearSRGBColorSpace);
      m.uniforms.radius!.value = radius;
    }
  }

  /** How many AR balls the programs draw (one per arm, at most MAX_BALLS): each mode's
   * program is built again for it; one, as with one arm, until told. */
  setBallCount(n: number): void {
    const balls = Math.max(1, Math.min(MAX_BALLS, n));
    for (const m of this.all()) {
      if (m.defines.BALLS === balls) continue;
      m.defines.BALLS = balls;
      m.needsUpdate = true;
    }
    for (let k = balls; k < MAX_BALLS; k++) for (const m of this.all()) (m.uniforms.showBall!.value as number[])[k] = 0;
  }

  /** What the view draws now, as a test reads it (wiring/test-view.ts): the AR balls its
   * programs draw and which are shown, whether a headset shows it (and the supervision
   * line there), and whether the overlay is drawn for CPU reads (no GPU read-back). */
  get drawn(): {
    ballSlots: number;
    ballsShown: number[];
    xrPresenting: boolean;
    xrBadgeVisible: boolean;
    overlayOnCpu: boolean;
    /** Where camera pixels land on the canvas: each eye's width, the rows cropped, the
     * right eye's alignment shift, and the canvas's height. */
    layout: { eyeWidth: number; cropTop: number; shift: [number, number]; outHeight: number };
  } {
    const u = this.material.uniforms;
    const shift = u.shift!.value as THREE.Vector2;
    return {
      layout: {
        eyeWidth: (u.eye!.value as THREE.Vector2).x,
        cropTop: Number(u.cropTop!.value),
        shift: [shift.x, shift.y],
        outHeight: (u.outSize!.value as THREE.Vector2).y,
      },
      ballSlots: Number(this.material.defines.BALLS),
      ballsShown: Array.from(this.material.uniforms.showBall!.value as number[]),
      xrPresenting: this.renderer.xr.isPresenting,
      xrBadgeVisible: this.xrBadge.visible,
      overlayOnCpu: this.overlay.canvas.getContext("2d")?.getContextAttributes().willReadFrequently === true,
    };
  }

  setMode(mode: ViewMode): void {
    this.mode = mode;
    this.render();
  }

  /** One eye's size in the camera's own pixels (GET /api/v1/video's width × height),
   * which the calibration, the AR and the timecode crop are in. A smaller picture (the
   * server's low video layer, on a poor link) is stretched to it, so the drawing stays
   * registered whichever layer arrives. Null: the picture's own size. */
  nativeSize: { width: number; height: number } | null = null;

  /** Output in camera pixels: one eye wide for mono/anaglyph, two for side-by-side;
   * each eye's rows below the cropped ones. */
  private layout(): void {
    const eyeW = this.nativeSize?.width ?? (this.video.videoWidth / 2 || 1280);
    const eyeH = this.nativeSize?.height ?? (this.video.videoHeight || 720);
    const wide = this.mode === "side-by-side" || this.mode === "cross-eye";
    const w = wide ? 2 * eyeW : eyeW;
    const crop = Math.min(this.cropTop, eyeH - 1);
    const h = eyeH - crop;
    if (this.output.width !== w || this.output.height !== h) {
      this.output = { width: w, height: h };
      this.fitBox(); // the box's aspect follows the picture's
    }
    this.sizeBuffer();
    for (const q of this.xrQuads) q.scale.x = eyeW / h / (16 / 9);
    if (this.overlay.resize({ width: eyeW, height: eyeH })) this.overlayTexture.dispose(); // a new size: a new texture
    if (this.overlay.dirty) {
      this.overlay.paint();
      this.overlayTexture.needsUpdate = true;
    }
    if (this.material.defines.MODE !== MODE_INDEX[this.mode]) {
      this.material.defines.MODE = MODE_INDEX[this.mode];
      this.material.needsUpdate = true; // another program (three.js keeps each one built)
    }
    for (const m of this.all()) {
      (m.uniforms.eye!.value as THREE.Vector2).set(eyeW, eyeH);
      m.uniforms.cropTop!.value = crop;
    }
    (this.material.uniforms.outSize!.value as THREE.Vector2).set(w, h);
    for (const m of this.xrMaterials) (m.uniforms.outSize!.value as THREE.Vector2).set(eyeW, h);
  }

  /** Upload the video's current frame and draw it now (e.g. after pausing). */
  redraw(): void {
    this.texture.needsUpdate = true;
    this.render();
  }

  render(): void {
    this.renders += 1;
    this.layout();
    this.renderer.render(this.scene, this.camera);
    if (!this.renderer.xr.isPresenting) this.fence.drew();
  }

  private gl2(): WebGL2RenderingContext | null {
    const gl = this.renderer.getContext();
    return typeof WebGL2RenderingContext !== "undefined" && gl instanceof WebGL2RenderingContext ? gl : null;
  }

  private scheduleFrame(): void {
    this.video.requestVideoFrameCallback((_now, metadata) => {
      this.frames += 1;
      this.watch.frame(performance.now());
      if (this.staleMs !== null) this.checkStale(); // fresh again: undim before drawing
      this.texture.needsUpdate = true;
      if (!this.renderer.xr.isPresenting) this.pacer.request();
      this.onFrame?.(metadata);
      this.scheduleFrame();
    });
  }

  async enterXR(): Promise<void> {
    const xr = (navigator as Navigator & { xr?: { requestSession(mode: string, init?: object): Promise<XRSession> } }).xr;
    if (!xr) throw new Error("WebXR is not available in this browser");
    const session = await xr.requestSession("immersive-vr", { optionalFeatures: ["local-floor", "hand-tracking"] });
    await this.renderer.xr.setSession(session);
  }
}
