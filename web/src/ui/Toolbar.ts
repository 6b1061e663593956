// Top bar: scene picker, transport (play, pause, step, reset), undo/redo.
// Listens to the editor's signals; acts only through the editor.
import type { Editor } from '../core/Editor';
import { el } from './dom';

export class Toolbar {
  readonly dom: HTMLElement;
  private readonly picker: HTMLSelectElement;
  private readonly buttons: Record<'play' | 'pause' | 'step' | 'reset' | 'undo' | 'redo', HTMLButtonElement>;

  constructor(private readonly editor: Editor) {
    this.picker = el('select', { testid: 'scene-picker', title: 'Open a scene (a new session on the server)' });
    this.picker.append(el('option', { text: 'Open scene…', attrs: { value: '' } }));
    this.picker.addEventListener('change', () => {
      const name = this.picker.value;
      if (name) void editor.openScene(name);
    });

    const button = (id: string, text: string, title: string, onClick: () => void) => {
      const b = el('button', { testid: id, text, title, attrs: { type: 'button' } });
      b.addEventListener('click', onClick);
      return b;
    };
    this.buttons = {
      play: button('play', '▶ Play', 'Play (simulate frames at the playback speed)', () => void editor.transport('play')),
      pause: button('pause', '❚❚ Pause', 'Pause', () => void editor.transport('pause')),
      step: button('step', 'Step', 'Simulate one frame', () => void editor.transport('step', { frames: 1 })),
      reset: button('reset', 'Reset', 'Back to frame 0 (history cleared)', () => void editor.transport('reset')),
      undo: button('undo', '↶', 'Undo (Ctrl+Z)', () => void editor.undo()),
      redo: button('redo', '↷', 'Redo (Ctrl+Shift+Z)', () => void editor.redo()),
    };
    const b = this.buttons;
    this.dom = el('header', { className: 'toolbar', testid: 'toolbar' }, [
      el('span', { className: 'brand', text: 'FlowClip' }),
      this.picker,
      el('span', { className: 'group' }, [b.play, b.pause, b.step, b.reset]),
      el('span', { className: 'group' }, [b.undo, b.redo]),
    ]);

    editor.signals.scenesChanged.add((scenes) => {
      const current = editor.session?.scene ?? '';
      this.picker.replaceChildren(el('option', { text: 'Open scene…', attrs: { value: '' } }));
      for (const s of scenes) {
        const label = s.error ? `${s.name} (unreadable)` : `${s.name} (${s.dimension}D)`;
        const o = el('option', { text: label, attrs: { value: s.name } });
        if (s.error) o.disabled = true;
        this.picker.append(o);
      }
      this.picker.value = current;
    });
    editor.signals.sessionChanged.add((s) => {
      this.picker.value = s?.scene ?? '';
      this.update();
    });
    editor.signals.sessionView.add(() => this.update());
    editor.signals.historyChanged.add(() => this.update());
    this.update();
  }

  private update() {
    const e = this.editor, v = e.view, open = e.session !== null;
    const running = v.status === 'playing' || v.status === 'stepping';
    this.buttons.play.disabled = !open || v.status === 'playing' || v.status === 'error';
    this.buttons.pause.disabled = !open || !running;
    this.buttons.step.disabled = !open || running || v.status === 'error';
    this.buttons.reset.disabled = !open;
    this.buttons.undo.disabled = !e.history.canUndo;
    this.buttons.redo.disabled = !e.history.canRedo;
  }
}
