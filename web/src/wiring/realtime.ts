// The real-time channel: STATE and FORCE into the page's arms, EVENTs into the log, the
// header and the control watch, and each new session's checks (WELCOME).
import { TOKEN_KEY, saveToken, tokenVerdict } from "../api";
import { RealtimeLink } from "../transport/link";
import { EventKind } from "../transport/messages";
import { parseAutonomy } from "../ui/autonomy";
import { ControlWatch } from "../ui/control-alert";
import { $ } from "../ui/dom";
import { controllerIn, namedUrl } from "../ui/operator-name";
import { showConnection } from "../ui/panels";
import { RecordingPanel } from "../ui/recording";
import type { PageContext } from "./context";
import { readAutonomy } from "./supervision";

export interface RealtimeHandle {
  link: RealtimeLink;
  /** Control lost, said over the video. */
  control: ControlWatch;
  /** The header's REC indicator for every viewer, the operator's panel. */
  recording: RecordingPanel;
}

export function setupRealtime(ctx: PageContext): RealtimeHandle {
  const { api, log, arms } = ctx;
  const control = new ControlWatch();
  let welcomed = false;
  const recording = new RecordingPanel({ api, log, operator: () => link.operator });
  const url = namedUrl(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`, ctx.pageName);
  const link: RealtimeLink = new RealtimeLink(url, ctx.token, {
    state: (s) => {
      const a = arms.report(s, performance.now());
      if (!a || a !== arms.list[0]) return; // the lease's flags are every arm's: said once a tick
      const { supervision, tasks } = ctx.late;
      if (supervision?.active) supervision.refresh();
      if (!tasks?.handedOver) control.state(s.flags, performance.now(), link.timerLateMs, link.pageStallMs);
    },
    forces: (samples, index) => arms.force(samples, index),
    arms: (announced) => {
      // The server's arms (its ARM messages): others than those drawn are read again.
      if (announced.map((x) => x.name).join() !== arms.list.map((x) => x.entry.name).join()) void ctx.late.reloader?.reload();
    },
    event: (text, kind) => {
      if (kind === EventKind.AUTONOMY) {
        const s = parseAutonomy(text);
        if (s) {
          ctx.late.supervision?.update(s);
          log.add(`autonomy ${s.mode.toUpperCase()}: ${s.cause}`);
        }
        return;
      }
      log.add(text);
      const who = controllerIn(text);
      if (who !== undefined) ctx.controller = who;
      control.event(text, performance.now());
      recording.event(text);
    },
    error: (text, _seq, code) => {
      if (!control.quiet(code, performance.now())) log.add(text, true);
    },
    connection: (up, why) => {
      showConnection(up, why);
      control.connection(up);
    },
    welcome: (operator) => {
      // A new session after the first: the server may have restarted with another arm.
      void readAutonomy(ctx);
      if (welcomed) {
        void ctx.late.reloader?.reload();
        api
          .request("get", "/api/v1/safety")
          .then((s) => (ctx.controller = s.controller ?? null))
          .catch(() => undefined);
      }
      welcomed = true;
      control.welcome(operator);
      // Remembered only once accepted: a wrong token never replaces a good one.
      const verdict = tokenVerdict(ctx.token, operator, localStorage.getItem(TOKEN_KEY));
      if (verdict) log.add(verdict, true);
      else if (operator) saveToken(localStorage, ctx.token);
      $("token-status").textContent = verdict ?? "";
    },
  });
  link.connect();
  return { link, control, recording };
}
