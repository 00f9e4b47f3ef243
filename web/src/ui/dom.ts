// The pages' elements by id (each page's HTML has them).
export const $ = <T extends HTMLElement = HTMLElement>(id: string): T => document.getElementById(id) as T;

/** The number in an <input> (a range, a number field). */
export const numberIn = (id: string): number => Number($<HTMLInputElement>(id).value);
