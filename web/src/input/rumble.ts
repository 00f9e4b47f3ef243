// Rumble proportional to the contact force, on a gamepad (vibrationActuator) and on
// XR controllers (hapticActuators). Each pulse is short and renewed every PERIOD_MS
// while the force lasts, so the rumble ends within one period of leaving the contact.
export const RUMBLE_PERIOD_MS = 50;
const PULSE_MS = 60; // a little longer than the period: no gaps while the force lasts
const FLOOR = 0.02; // below 2 % of the force limit: sensor noise, not contact

/** 0…1 of the force limit; 0 under the noise floor or for a reading that is not a number. */
export function rumbleStrength(forceN: number, limitN: number): number {
  if (!(limitN > 0) || !Number.isFinite(forceN)) return 0;
  const s = Math.min(1, Math.abs(forceN) / limitN);
  return s > FLOOR ? s : 0;
}

type Vibrating = { vibrationActuator?: { playEffect(type: string, params: object): Promise<unknown> } | null };
type Haptic = { hapticActuators?: readonly { pulse(value: number, duration: number): Promise<boolean> }[] };

/** Paces the pulses: at most one every RUMBLE_PERIOD_MS. */
export class Rumble {
  private next = 0;
  enabled = true;

  /** Pulse ``pads`` (gamepads or XR controllers' gamepads) at ``strength`` if one is due;
   * ``weak``: a gamepad's other motor (the right grip's; an XR controller has one). */
  drive(now: number, strength: number, pads: readonly (Gamepad | null | undefined)[], weak = 0): void {
    if (!this.enabled || (strength <= 0 && weak <= 0) || now < this.next) return;
    this.next = now + RUMBLE_PERIOD_MS;
    for (const pad of pads) {
      // An XR controller's gamepad pulses (WebXR Gamepads Module); a gamepad plays an
      // effect (Gamepad API). Some expose both names for one motor: use one, never both.
      const h = (pad as (Gamepad & Haptic) | null | undefined)?.hapticActuators?.[0];
      const v = (pad as (Gamepad & Vibrating) | null | undefined)?.vibrationActuator;
      if (typeof h?.pulse === "function") void h.pulse(Math.max(strength, weak), PULSE_MS);
      else if (typeof v?.playEffect === "function") {
        void v.playEffect("dual-rumble", { duration: PULSE_MS, strongMagnitude: strength, weakMagnitude: weak });
      }
    }
  }
}

/** The contact force as rumble on the gamepad and on the XR controllers, each paced on
 * its own; `strength(arm)` (an index into the page's arms) is read when a pulse may be
 * due. With two arms each hand feels its own arm: the left XR controller the left arm's
 * force and the right the right's; the gamepad's left motor (strong, in the left grip)
 * the left arm's and its right motor (weak) the right's, or, driving one arm alone, its
 * left motor that arm's. */
export class ContactRumble {
  readonly pad = new Rumble();
  /** The controller that drives (one arm), or the right hand's. */
  readonly xr = new Rumble();
  readonly xrLeft = new Rumble();

  constructor(private readonly strength: (arm: number) => number) {}

  set enabled(on: boolean) {
    this.pad.enabled = this.xr.enabled = this.xrLeft.enabled = on;
  }

  /** `arms`: whose force each motor gives (null: none); by default the first arm's on
   * the left motor, as with one arm. */
  drivePad(now: number, pad: Gamepad | null, arms: { strong: number | null; weak: number | null } = { strong: 0, weak: null }): void {
    const of = (arm: number | null) => (arm === null ? 0 : this.strength(arm));
    this.pad.drive(now, of(arms.strong), [pad], of(arms.weak));
  }

  /** The controller of `hand` (one arm: the one that drives, "right") with `arm`'s force. */
  driveXR(now: number, gamepad: Gamepad, arm = 0, hand: "left" | "right" = "right"): void {
    (hand === "left" ? this.xrLeft : this.xr).drive(now, this.strength(arm), [gamepad]);
  }
}
