// The header stays one line (style.css): the texts that give way to it (who drives, the
// supervision's badge) are cut with an ellipsis, so each keeps its whole text in its
// title, where a pointer finds it.
export function titleFollowsText(elements: readonly HTMLElement[]): void {
  for (const el of elements) {
    const sync = () => {
      const text = el.textContent ?? "";
      if (el.title !== text) el.title = text;
    };
    sync();
    new MutationObserver(sync).observe(el, { childList: true, characterData: true, subtree: true });
  }
}
