import { describe, expect, it } from "vitest";
import { takesText } from "./input/keyboard";

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
