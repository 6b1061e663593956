// Bottom bar: session, status, frame and time, particle counts, connection.
// Values are also in data-value attributes (tests read them).
import type { Editor } from '../core/Editor';
import type { FrameInfo } from '../net/FrameDecoder';
import { el } from './dom';

export class StatusBar {
  readonly dom: HTMLElement;
  private readonly fields: Record<string, HTMLElement> = {};

  constructor(editor: Editor) {
    const field = (id: string, label: string, title: string) => {
      const value = el('span', { className: 'value', testid: id, text: '–', attrs: { 'data-value': '' } });
      this.fields[id] = value;
      return el('span', { className: 'field', title }, [el('span', { className: 'label', text: label }), value]);
    };
    this.dom = el('footer', { className: 'statusbar', testid: 'statusbar' }, [
      field('session', 'session', 'Session id on the server'),
      field('session-status', 'status', 'Paused, playing, stepping or error'),
      field('frame', 'frame', 'Frame shown (1-based; 0: the initial state)'),
      field('time', 'time', 'Scene time of the frame shown, s'),
      field('particle-count', 'particles', 'Liquid particles (temporary ones included)'),
      field('temporary-count', 'temporary', 'Temporary particles seeded by template control'),
      field('sim-ms', 'ms/frame', 'Wall time of the frame on the server (control included)'),
      field('connection', 'stream', 'WebSocket stream'),
    ]);

    editor.signals.frameDecoded.add((f) => this.onFrame(f));
    editor.signals.sessionView.add((v) => {
      this.set('session-status', v.live ? v.status : `${v.status} (replay)`, v.status);
    });
    editor.signals.sessionChanged.add((s) => {
      this.set('session', s ? `${s.id} · ${s.scene}` : '–', s?.id ?? '');
      if (!s) for (const k of ['frame', 'time', 'particle-count', 'temporary-count', 'sim-ms']) this.set(k, '–', '');
    });
    editor.signals.connection.add((c) => {
      const text = c.status === 'reconnecting' && c.retryInMs > 0 ? `reconnecting in ${(c.retryInMs / 1000).toFixed(1)} s` : c.status;
      this.set('connection', text, c.status);
    });
  }

  private onFrame(f: FrameInfo) {
    this.set('frame', String(f.frame), String(f.frame));
    this.set('time', `${f.time.toFixed(3)} s`, String(f.time));
    const n = f.liquid + f.temporary;
    this.set('particle-count', n.toLocaleString('en-US'), String(n));
    this.set('temporary-count', f.temporary.toLocaleString('en-US'), String(f.temporary));
    this.set('sim-ms', f.wallMs.toFixed(1), String(f.wallMs));
  }

  private set(id: string, text: string, value: string) {
    const e = this.fields[id]!;
    if (e.textContent !== text) e.textContent = text;
    e.dataset['value'] = value;
  }
}
