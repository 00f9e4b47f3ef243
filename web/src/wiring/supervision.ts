// Supervising a learned policy from the page: the header's badge and buttons (and the
// headset's line), wired to the input loop and the link.
import { parseAutonomy, Supervision } from "../ui/autonomy";
import { $ } from "../ui/dom";
import type { InputLoop } from "../input/loop";
import type { RealtimeLink } from "../transport/link";
import { StateFlags } from "../transport/messages";
import type { PageContext } from "./context";

/** The headset's supervision line, coloured as the header's badge (style.css). */
const XR_BADGE_COLOURS: Record<string, string> = { autonomous: "#1d5fa8", paused: "#9a7a10", correcting: "#2e7d32" };

/** Who drives while a policy is connected (GET /autonomy): at each new session, as
 * events may have been missed while the link was down. */
export async function readAutonomy(ctx: PageContext): Promise<void> {
  try {
    ctx.late.supervision?.update(parseAutonomy(JSON.stringify(await ctx.api.request("get", "/api/v1/autonomy"))));
  } catch {
    // the server said nothing: the next EVENT autonomy says it
  }
}

/** `givingUp`: this page lets control go (the control watch says so, not as a loss). */
export function setupSupervision(ctx: PageContext, loop: InputLoop, link: RealtimeLink, givingUp: () => void): Supervision {
  const youHaveControl = (): boolean => ((ctx.arms.combined?.flags ?? 0) & StateFlags.YOU_HAVE_CONTROL) !== 0;
  const lease = (action: number): void => {
    if (youHaveControl()) givingUp(); // pausing or resuming from a correction hands control back
    link.lease(action);
  };
  const s = new Supervision({
    take: () => loop.take(),
    release: () => loop.release(),
    lease,
    youHaveControl,
    say: (text) => ctx.log.add(text, true),
  });
  const badge = $("autonomy");
  // Every STATE (50 a second) refreshes the view; what it shows is drawn again only when
  // it changed: the header's layout, and the headset's line, a 2D canvas (issue 27 found
  // a software GPU's 2D canvases holding the page's main thread for seconds).
  let shown = "";
  s.onChange = (v) => {
    const now = JSON.stringify([v, s.state?.mode ?? "off", link.operator]);
    if (now === shown) return;
    shown = now;
    badge.hidden = v.badge === "";
    badge.textContent = v.badge;
    badge.dataset.mode = s.state?.mode ?? "off";
    const operator = link.operator;
    $("pause-policy").hidden = !(operator && v.pause);
    $("resume-policy").hidden = !(operator && v.resume);
    $("hand-back").hidden = !(operator && v.handBack);
    $("take").textContent = v.takeLabel;
    ctx.view.setXRBadge(v.badge, XR_BADGE_COLOURS[s.state?.mode ?? "off"] ?? "#444");
  };
  $("pause-policy").onclick = () => s.pause();
  $("resume-policy").onclick = () => s.handBack();
  $("hand-back").onclick = () => s.handBack();
  ctx.late.supervision = s;
  void readAutonomy(ctx);
  return s;
}
