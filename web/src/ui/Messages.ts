// The message area: server errors, lost connections, refused edits. Errors
// stay until dismissed; information fades after a few seconds. Every message
// is also logged to the console.
import type { Editor, UserMessage } from '../core/Editor';
import { el } from './dom';

const MAX_SHOWN = 6;

export class Messages {
  readonly dom: HTMLElement;

  constructor(editor: Editor) {
    this.dom = el('div', { className: 'messages', testid: 'messages', attrs: { role: 'log', 'aria-live': 'polite' } });
    editor.signals.message.add((m) => this.show(m));
  }

  show(m: UserMessage) {
    (m.level === 'error' ? console.error : m.level === 'warning' ? console.warn : console.info)(`[flowclip] ${m.text}`);
    const close = el('button', { className: 'close', text: '×', title: 'Dismiss', attrs: { type: 'button' } });
    const item = el('div', { className: `message ${m.level}`, testid: `message-${m.level}` }, [
      el('span', { className: 'text', text: m.text }),
      close,
    ]);
    close.addEventListener('click', () => item.remove());
    this.dom.append(item);
    while (this.dom.children.length > MAX_SHOWN) this.dom.firstElementChild!.remove();
    if (m.level !== 'error') setTimeout(() => item.remove(), m.level === 'warning' ? 8000 : 4000);
  }
}
