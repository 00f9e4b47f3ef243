// The stereo views: mono, side-by-side, cross-eye, anaglyph (colour and Dubois),
// and WebXR immersive-vr where each eye sees its half of the side-by-side video.
// One shader source does it all, so the AR ball and the alignment shift are drawn the
// same way in every view; each mode compiles its own program (the MODE define) because
// a software GPU (SwiftShader, no GPU here) runs every branch of a per-pixel `if`,
// uniform or not: with one program for all modes it drew 5.7–7.4 side-by-side frames/s
// of 2×640×360 video, with one per mode 10.8–11.4, on the same 1.2 cores.
// Frames are rendered as they arrive (requestVideoFrameCallback).
import * as THREE from "three";

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
uniform vec2 eye;       // one eye's size in pixels
uniform vec2 outSize;   // this quad's size in pixels
uniform vec2 shift;     // right image moved by this many pixels (x right, y down)
uniform bool showBall;
uniform vec2 ballL;     // AR ball centre in each camera's pixels
uniform vec2 ballR;
uniform float radius;
uniform vec3 ballColor;
uniform mat3 duboisL;
uniform mat3 duboisR;
varying vec2 vUv;

vec3 sampleEye(int which, vec2 px) {
  if (which == 1) px -= shift;
  if (px.x < 0.0 || px.y < 0.0 || px.x >= eye.x || px.y >= eye.y) return vec3(0.0);
  vec2 uv = vec2((px.x + float(which) * eye.x) / (2.0 * eye.x), 1.0 - px.y / eye.y);
  vec3 c = texture2D(tex, uv).rgb;
  if (showBall) {
    vec2 b = which == 0 ? ballL : ballR;
    float d = distance(px, b);
    if (d < radius) c = ballColor;
    else if (d < radius + 1.5) c = mix(ballColor, vec3(0.0), 0.6);
  }
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
  onFrame: ((metadata: VideoFrameCallbackMetadata) => void) | null = null;
  /** Each XR frame, before it is drawn: read the controllers here. */
  onXRFrame: ((frame: XRFrame, space: XRReferenceSpace) => void) | null = null;
  xrFrames = 0;

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
      this.xrGroup.add(quad);
    }
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
    this.scheduleFrame();
  }

  private makeMaterial(mode = MODE_INDEX["side-by-side"]): THREE.ShaderMaterial {
    return new THREE.ShaderMaterial({
      vertexShader: VERTEX,
      fragmentShader: FRAGMENT,
      defines: { MODE: mode },
      uniforms: {
        tex: { value: this.texture },
        eye: { value: new THREE.Vector2(1280, 720) },
        outSize: { value: new THREE.Vector2(2560, 720) },
        shift: { value: new THREE.Vector2(0, 0) },
        showBall: { value: true },
        ballL: { value: new THREE.Vector2(-1000, -1000) },
        ballR: { value: new THREE.Vector2(-1000, -1000) },
        radius: { value: 10 },
        ballColor: { value: new THREE.Color(0x00ff66) },
        duboisL: { value: DUBOIS_LEFT },
        duboisR: { value: DUBOIS_RIGHT },
      },
    });
  }

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

  setBall(ball: Ball, show: boolean, colour: string, radius: number): void {
    for (const m of this.all()) {
      m.uniforms.showBall!.value = show && ball.left !== null;
      if (ball.left) (m.uniforms.ballL!.value as THREE.Vector2).set(...ball.left);
      if (ball.right) (m.uniforms.ballR!.value as THREE.Vector2).set(...ball.right);
      // Our pixels bypass colour management, so the picked colour is used as it is.
      (m.uniforms.ballColor!.value as THREE.Color).setStyle(colour, THREE.LinearSRGBColorSpace);
      m.uniforms.radius!.value = radius;
    }
  }

  setMode(mode: ViewMode): void {
    this.mode = mode;
    this.render();
  }

  /** Output in video pixels: one eye wide for mono/anaglyph, two for side-by-side. */
  private layout(): void {
    const eyeW = this.video.videoWidth / 2 || 1280;
    const eyeH = this.video.videoHeight || 720;
    const wide = this.mode === "side-by-side" || this.mode === "cross-eye";
    const w = wide ? 2 * eyeW : eyeW;
    // (In XR the session's layer sizes the canvas.)
    if (!this.renderer.xr.isPresenting && (this.canvas.width !== w || this.canvas.height !== eyeH)) {
      this.renderer.setSize(w, eyeH, false);
    }
    if (this.material.defines.MODE !== MODE_INDEX[this.mode]) {
      this.material.defines.MODE = MODE_INDEX[this.mode];
      this.material.needsUpdate = true; // another program (three.js keeps each one built)
    }
    (this.material.uniforms.eye!.value as THREE.Vector2).set(eyeW, eyeH);
    (this.material.uniforms.outSize!.value as THREE.Vector2).set(w, eyeH);
    for (const m of this.xrMaterials) {
      (m.uniforms.eye!.value as THREE.Vector2).set(eyeW, eyeH);
      (m.uniforms.outSize!.value as THREE.Vector2).set(eyeW, eyeH);
    }
  }

  /** Upload the video's current frame and draw it now (e.g. after pausing). */
  redraw(): void {
    this.texture.needsUpdate = true;
    this.render();
  }

  render(): void {
    this.layout();
    this.renderer.render(this.scene, this.camera);
  }

  private scheduleFrame(): void {
    this.video.requestVideoFrameCallback((_now, metadata) => {
      this.frames += 1;
      this.texture.needsUpdate = true;
      if (!this.renderer.xr.isPresenting) this.render();
      this.onFrame?.(metadata);
      this.scheduleFrame();
    });
  }

  async enterXR(): Promise<void> {
    const xr = (navigator as Navigator & { xr?: { requestSession(mode: string, init?: object): Promise<XRSession> } }).xr;
    if (!xr) throw new Error("WebXR is not available in this browser");
    const session = await xr.requestSession("immersive-vr", { optionalFeatures: ["local-floor"] });
    await this.renderer.xr.setSession(session);
  }
}
