// Top bar: scene picker, save (on the server) and download of the current
// scene, the Export and Render final dialogs, transport (play, pause, step, reset, back to live), undo/redo.
// Listens to the editor's signals; acts only through the editor.
import type { Editor } from '../core/Editor';
import { el } from './dom';

export class Toolbar {
  readonly dom: HTMLElement;
  private readonly picker: HTMLSelectElement;
  private readonly buttons: Record<'play' | 'pause' | 'step' | 'reset' | 'live' | 'undo' | 'redo' | 'save' | 'download' | 'export' | 'render', HTMLButtonElement>;
  private readonly saveName: HTMLInputElement;

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
      play: button('play', '▶ Play', 'Play to the end of the play range (Space): recorded frames replay, the rest is simulated', () => void editor.play()),
      pause: button('pause', '❚❚ Pause', 'Pause (Space)', () => void editor.pause()),
      step: button('step', 'Step', 'Simulate one frame', () => void editor.transport('step', { frames: 1 })),
      reset: button('reset', 'Reset', 'Back to frame 0 (history cleared)', () => void editor.transport('reset')),
      live: button('live', 'Live', 'Show the newest simulated frame (leave the replay)', () =>
        void editor.transport('seek', { frame: editor.view.frame })),
      save: button('save-scene', 'Save', 'Save the current scene (every accepted edit) on the server as NAME.json (Ctrl+S)', () => void this.save()),
      download: button('download-scene', 'Download', 'Download the current scene as JSON', () => void this.download()),
      export: button('export-open', 'Export…', 'Mesh the recorded frames into OpenVDB, PLY, OBJ or USD files for Houdini and Blender', () =>
        editor.signals.exportRequested.dispatch()),
      render: button('render-open', 'Render final…', '', () => editor.signals.renderRequested.dispatch()),
      undo: button('undo', '↶', 'Undo (Ctrl+Z)', () => void editor.undo()),
      redo: button('redo', '↷', 'Redo (Ctrl+Shift+Z)', () => void editor.redo()),
    };
    const b = this.buttons;
    this.saveName = el('input', { testid: 'scene-save-name', title: 'Name to save the scene as ([A-Za-z0-9_-])', attrs: { type: 'text', size: '12', spellcheck: 'false' } });
    this.saveName.addEventListener('keydown', (e) => {
      if (e.key === 'Enter') void this.save();
    });
    this.dom = el('header', { className: 'toolbar', testid: 'toolbar' }, [
      el('span', { className: 'brand', text: 'FlowClip' }),
      this.picker,
      el('span', { className: 'group' }, [this.saveName, b.save, b.download, b.export, b.render]),
      el('span', { className: 'group' }, [b.play, b.pause, b.step, b.reset, b.live]),
      el('span', { className: 'group' }, [b.undo, b.redo]),
    ]);

    editor.signals.scenesChanged.add((scenes) => {
      const current = editor.session?.scene ?? '';
      this.picker.replaceChildren(el('option', { text: 'Open scene…', attrs: { value: '' } }));
      for (const s of scenes) {
        const missing = s.missing_templates ?? [];
        const label = s.error
          ? `${s.name} (unreadable)`
          : `${s.name} (${s.dimension}D)${missing.length ? ` ⚠ missing template${missing.length > 1 ? 's' : ''} ${missing.join(', ')}` : ''}`;
        const o = el('option', { text: label, attrs: { value: s.name } });
        if (s.error) {
          o.disabled = true;
          o.title = s.error;
        }
        if (missing.length) {
          o.dataset['missing'] = missing.join(',');
          o.title = `Its instances need template${missing.length > 1 ? 's' : ''} ${missing.join(', ')}, not in the server's database: ` +
            `record ${missing.length > 1 ? 'them' : 'it'} from the template library (Record) or with \`flowclip record templates/recipes/NAME.json\``;
        }
        this.picker.append(o);
      }
      this.picker.value = current;
    });
    editor.signals.sessionChanged.add((s) => {
      this.picker.value = s?.scene ?? '';
      this.saveName.value = s ? `${s.scene}_edit` : '';
      this.update();
    });
    editor.signals.sessionView.add(() => this.update());
    editor.signals.historyChanged.add(() => this.update());
    editor.signals.playbackChanged.add(() => this.update());
    editor.signals.playheadChanged.add(() => this.update()); // Live also leaves a frame nothing is recorded at
    editor.signals.renderAvailabilityChanged.add(() => this.update());
    editor.signals.saveRequested.add(() => void this.save());
    this.update();
  }

  private update() {
    const e = this.editor, v = e.view, open = e.session !== null;
    const running = v.status === 'playing' || v.status === 'stepping' || e.looping;
    this.buttons.play.disabled = !open || e.isPlaying() || v.status === 'error';
    this.buttons.pause.disabled = !open || !running;
    this.buttons.step.disabled = !open || running || v.status === 'error';
    this.buttons.reset.disabled = !open;
    this.buttons.live.disabled = !open || (v.live && !e.offRecord) || v.status === 'error';
    this.buttons.save.disabled = !open;
    this.buttons.download.disabled = !open;
    this.buttons.export.disabled = !open;
    // Render final: a session, and a server that runs render jobs (GET /api/jobs); the tooltip says which is missing.
    const jobs = e.renderAvailability;
    this.buttons.render.disabled = !open || !jobs.available;
    const renderTitle = !open
      ? 'Render final: open a scene first'
      : !jobs.available
        ? `Render final: ${jobs.reason}`
        : `Run this scene again at a final resolution (a wedge, surfaces, particles) on the render workers: ${jobs.where}`;
    if (this.buttons.render.title !== renderTitle) this.buttons.render.title = renderTitle;
    this.buttons.undo.disabled = !e.history.canUndo;
    this.buttons.redo.disabled = !e.history.canRedo;
    // The buttons name what they undo and redo.
    const undo = e.history.undoEntries.at(-1)?.name, redo = e.history.redoEntries.at(-1)?.name;
    this.name(this.buttons.undo, '↶', undo, 'Undo', 'Ctrl+Z');
    this.name(this.buttons.redo, '↷', redo, 'Redo', 'Ctrl+Shift+Z');
  }

  private name(b: HTMLButtonElement, icon: string, what: string | undefined, verb: string, keys: string) {
    const text = what ? `${icon} ${what}` : icon;
    if (b.textContent !== text) b.textContent = text;
    b.title = what ? `${verb} ${what} (${keys})` : `Nothing to ${verb.toLowerCase()}`;
    b.setAttribute('aria-label', what ? `${verb} ${what}` : verb);
    b.dataset['name'] = what ?? '';
  }

  /** Saves on the server; an existing name asks before overwriting. */
  private async save() {
    const name = this.saveName.value.trim();
    if (!/^[A-Za-z0-9_-]{1,64}$/.test(name)) {
      this.editor.message('error', `save: "${name}" is not a scene name (letters, digits, _ and -, at most 64)`);
      return;
    }
    const exists = this.editor.scenes.some((s) => s.name === name);
    if (exists && !window.confirm(`Scene ${name} exists on the server. Overwrite it?`)) return;
    await this.editor.saveScene(name, exists);
  }

  /** The current scene as a JSON file (name: the save field's). */
  private async download() {
    const scene = await this.editor.currentSceneJson();
    if (!scene) return;
    const name = this.saveName.value.trim() || this.editor.session?.scene || 'scene';
    const blob = new Blob([JSON.stringify({ ...scene, name }, null, 1) + '\n'], { type: 'application/json' });
    const a = el('a', { attrs: { href: URL.createObjectURL(blob), download: `${name}.json` } });
    document.body.append(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 10_000);
  }
}
