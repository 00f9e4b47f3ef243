// Where a key pressed on the operator page goes. Escape closes an open dialog (the `?`
// help, or any <dialog> the page opens) and only that: a key pressed to close a window
// must not also latch the arm's e-stop. With nothing open Escape is the e-stop key, and
// the E-STOP button works whatever is open (the header stays above every dialog).
// Every other key reaches the help, the input loop, the stereo alignment and the
// fullscreen toggle as before (a dialog never swallows the driving keys).

/** A dialog Escape can close. */
export interface Closable {
  readonly open: boolean;
  close(): void;
}

/** Close the last open dialog of `dialogs` (the one opened on top); true when one was. */
export function closeOpenDialog(dialogs: readonly Closable[]): boolean {
  const top = dialogs.filter((d) => d.open).at(-1);
  top?.close();
  return top !== undefined;
}

/** What a key event carries that the routing reads (KeyboardEvent's fields). */
export interface KeyEventLike {
  key: string;
  repeat: boolean;
  altKey: boolean;
  ctrlKey: boolean;
  metaKey: boolean;
}

export interface KeyTargets {
  /** The page's dialogs now, open or not (read at each key). */
  dialogs(): readonly Closable[];
  /** The help overlay: `?` toggles it (KeyboardEvent.key). */
  help: { key(key: string): void };
  /** The input loop: Escape e-stops, digits pick the driving frame (KeyboardEvent.code). */
  loop: { key(code: string): void };
  /** Alt+arrows shift the right image. */
  alignment: { key(code: string, e: { altKey: boolean }): unknown };
  fullscreen(): void;
  /** Space, the dead-man, is held (then F drives down, not fullscreen). */
  deadmanHeld(): boolean;
}

/** Route one key that went down (`code`: KeyboardEvent.code). */
export function routeKey(t: KeyTargets, code: string, e: KeyEventLike): void {
  if (code === "Escape" && closeOpenDialog(t.dialogs())) return; // closing a dialog, nothing else
  t.help.key(e.key);
  t.loop.key(code);
  t.alignment.key(code, e);
  if (code === "KeyF" && !e.repeat && !e.altKey && !e.ctrlKey && !e.metaKey && !t.deadmanHeld()) t.fullscreen();
}

/** What the DOM part reads of an element (duck-typed, so the rule is tested without a DOM). */
interface DialogElement {
  tagName: string;
  hidden: boolean;
  readonly open?: boolean;
  close?: () => void;
}

/** The page's dialogs in document order: every <dialog open> (closed with close()), and
 * every element with role="dialog" not hidden (closed by hiding it, as the help is). */
export function pageDialogs(root: { querySelectorAll(selector: string): Iterable<DialogElement> }): Closable[] {
  return [...root.querySelectorAll("dialog[open], [role=dialog]:not([hidden])")].map((el) =>
    el.tagName === "DIALOG" && el.close
      ? { open: el.open ?? true, close: () => el.close!() }
      : {
          get open() {
            return !el.hidden;
          },
          close: () => (el.hidden = true),
        },
  );
}
