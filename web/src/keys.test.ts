import { describe, expect, it } from "vitest";
import { helpKeyAction } from "./ui/help";
import { closeOpenDialog, pageDialogs, routeKey, type KeyEventLike, type KeyTargets } from "./ui/keys";

const press = (key: string, more: Partial<KeyEventLike> = {}): KeyEventLike => ({ key, repeat: false, altKey: false, ctrlKey: false, metaKey: false, ...more });

/** The page's key targets, recording what each was given; the help as the page has it
 * (`?` toggles, its own Escape rule). */
function page(opts: { otherDialogOpen?: boolean } = {}) {
  const calls: string[] = [];
  const help = {
    open: false,
    close() {
      this.open = false;
      calls.push("help closed");
    },
    key(key: string) {
      const action = helpKeyAction(key, this.open);
      if (action === "toggle") this.open = !this.open;
      else if (action === "close") this.close();
    },
  };
  const other = { open: opts.otherDialogOpen ?? false, close: () => ((other.open = false), calls.push("other closed")) };
  const targets: KeyTargets = {
    dialogs: () => [help, other],
    help,
    loop: { key: (code) => calls.push(code === "Escape" ? "E-STOP" : `loop ${code}`) },
    alignment: { key: (code) => calls.push(`align ${code}`) },
    fullscreen: () => calls.push("fullscreen"),
    deadmanHeld: () => false,
  };
  return { calls, help, other, key: (code: string, e = press(code)) => routeKey(targets, code, e) };
}

describe("Escape", () => {
  it("with the help open closes it and only that: no e-stop", () => {
    const p = page();
    p.key("Slash", press("?"));
    expect(p.help.open).toBe(true);
    p.calls.length = 0;
    p.key("Escape", press("Escape"));
    expect(p.help.open).toBe(false);
    expect(p.calls).toEqual(["help closed"]);
  });

  it("with nothing open is the e-stop", () => {
    const p = page();
    p.key("Escape", press("Escape"));
    expect(p.calls).toContain("E-STOP");
  });

  it("pressed again once the help is closed is the e-stop", () => {
    const p = page();
    p.key("Slash", press("?"));
    p.key("Escape", press("Escape"));
    p.key("Escape", press("Escape"));
    expect(p.calls.filter((c) => c === "E-STOP")).toHaveLength(1);
  });

  it("closes any other open dialog the same way, the last opened first", () => {
    const p = page({ otherDialogOpen: true });
    p.key("Slash", press("?")); // both open now
    p.key("Escape", press("Escape"));
    expect(p.calls.slice(-1)).toEqual(["other closed"]);
    expect(p.help.open).toBe(true);
    p.key("Escape", press("Escape"));
    expect(p.calls.slice(-1)).toEqual(["help closed"]);
    expect(p.calls).not.toContain("E-STOP");
  });
});

describe("other keys", () => {
  it("still reach the input loop with the help open (the dead-man and the driving keys)", () => {
    const p = page();
    p.key("Slash", press("?"));
    p.key("KeyW", press("w"));
    p.key("Digit2", press("2"));
    expect(p.calls).toEqual(["loop Slash", "align Slash", "loop KeyW", "align KeyW", "loop Digit2", "align Digit2"]);
    expect(p.help.open).toBe(true);
  });

  it("F toggles fullscreen unless Space is held or a modifier is down", () => {
    const p = page();
    p.key("KeyF", press("f"));
    p.key("KeyF", press("f", { ctrlKey: true }));
    p.key("KeyF", press("f", { repeat: true }));
    expect(p.calls.filter((c) => c === "fullscreen")).toHaveLength(1);
  });
});

describe("the page's dialogs", () => {
  it("are the open <dialog>s and the role=dialog elements not hidden, each closed its own way", () => {
    const help = { tagName: "DIV", hidden: false };
    const native = { tagName: "DIALOG", hidden: false, open: true, close() {
      this.open = false;
    } };
    const found = pageDialogs({ querySelectorAll: (sel: string) => (expect(sel).toBe("dialog[open], [role=dialog]:not([hidden])"), [help, native]) });
    expect(found.map((d) => d.open)).toEqual([true, true]);
    expect(closeOpenDialog(found)).toBe(true); // the last one: the native dialog
    expect(native.open).toBe(false);
    expect(help.hidden).toBe(false);
    found[0]!.close();
    expect(help.hidden).toBe(true);
    expect(found[0]!.open).toBe(false);
    expect(closeOpenDialog([])).toBe(false);
  });
});
