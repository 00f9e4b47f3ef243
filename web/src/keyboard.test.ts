import { describe, expect, it } from "vitest";
import { KeyboardInput, takesText } from "./input/keyboard";

describe("which focused element keeps the driving keys", () => {
  it("text fields keep them", () => {
    expect(takesText({ tagName: "INPUT", type: "password" } as unknown as EventTarget)).toBe(true);
    expect(takesText({ tagName: "INPUT", type: "text" } as unknown as EventTarget)).toBe(true);
    expect(takesText({ tagName: "INPUT", type: "number" } as unknown as EventTarget)).toBe(true);
    expect(takesText({ tagName: "TEXTAREA" } as unknown as EventTarget)).toBe(true);
    expect(takesText({ tagName: "DIV", isContentEditable: true } as unknown as EventTarget)).toBe(true);
  });
  it("controls a person touched do not", () => {
    for (const type of ["checkbox", "range", "color", "button"]) {
      expect(takesText({ tagName: "INPUT", type } as unknown as EventTarget)).toBe(false);
    }
    expect(takesText({ tagName: "BUTTON" } as unknown as EventTarget)).toBe(false);
    expect(takesText({ tagName: "CANVAS" } as unknown as EventTarget)).toBe(false);
    expect(takesText(null)).toBe(false);
  });
});

describe("keys held when control is lost", () => {
  const press = (t: EventTarget, type: string, code: string) => t.dispatchEvent(Object.assign(new Event(type), { code, repeat: false }));
  it("drive nothing until released and pressed again", () => {
    const target = new EventTarget();
    const keys = new KeyboardInput(target as unknown as Window);
    press(target, "keydown", "Space");
    press(target, "keydown", "KeyW");
    expect(keys.read()).toMatchObject({ deadman: true, linear: [1, 0, 0] });
    keys.latch();
    expect(keys.read()).toMatchObject({ deadman: false, linear: [0, 0, 0] });
    press(target, "keydown", "KeyW"); // auto-repeat while still held
    expect(keys.read().linear).toEqual([0, 0, 0]);
    press(target, "keyup", "Space");
    press(target, "keydown", "Space"); // pressed again: the dead-man is back, W still latched
    expect(keys.read()).toMatchObject({ deadman: true, linear: [0, 0, 0] });
    press(target, "keyup", "KeyW");
    press(target, "keydown", "KeyW");
    expect(keys.read()).toMatchObject({ deadman: true, linear: [1, 0, 0] });
  });
});
