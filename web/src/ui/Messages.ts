// The message area: server errors, lost connections, refused edits. At most
// a few show at once (the oldest go), a message repeated while shown is
// counted on the one already there instead of piling up, and opening another
// scene clears them. Errors stay until dismissed; information fades after a
// few seconds. Every message is also logged to the console.
import type { Editor, UserMessage } from '../core/Editor';
import { el } from './dom';

const MAX_SHOWN = 3;

export class Messages {
  readonly dom: HTMLElement;

  constructor(editor: Editor) {
    this.dom = el('div', { className: 'messages', testid: 'messages', attrs: { role: 'log', 'aria-live': 'polite' } });
    editor.signals.message.add((m) => this.show(m));
    editor.signals.sceneOpening.add(() => this.dom.replaceChildren());
  }

  show(m: UserMessage) {
    (m.level === 'error' ? console.error : m.level === 'warning' ? console.warn : console.info)(`[flowclip] ${m.text}`);
    const same = [...this.dom.children].find(
      (c) => (c as HTMLElement).dataset['level'] === m.level && (c as HTMLElement).dataset['text'] === m.text,
    ) as HTMLElement | undefined;
    if (same) {
      const n = Number(same.dataset['count'] ?? '1') + 1;
      same.dataset['count'] = String(n);
      same.querySelector('.count')!.textContent = `×${n}`;
      this.dom.append(same); // newest last
      this.fade(same, m);
      return;
    }
    const close = el('button', { className: 'close', text: '×', title: 'Dismiss', attrs: { type: 'button' } });
    const item = el('div', { className: `message ${m.level}`, testid: `message-${m.level}` }, [
      el('span', { className: 'text', text: m.text }),
      el('span', { className: 'count' }),
      close,
    ]);
    item.dataset['level'] = m.level;
    item.dataset['text'] = m.text;
    close.addEventListener('click', () => item.remove());
    this.dom.append(item);
    while (this.dom.children.length > MAX_SHOWN) this.dom.firstElementChild!.remove();
    this.fade(item, m);
  }

  private fade(item: HTMLElement, m: UserMessage) {
    if (m.level === 'error') return;
    const token = String(Number(item.dataset['fade'] ?? '0') + 1);
    item.dataset['fade'] = token;
    setTimeout(() => {
      if (item.dataset['fade'] === token) item.remove();
    }, m.level === 'warning' ? 8000 : 4000);
  }
}
