// Render final dialog (toolbar "Render final…"): the session's current scene
// run again as a batch on the server's render workers (POST /api/jobs,
// docs/batch.md) at a finer particle radius, for a duration, with surfaces
// and an optional wedge of one key path (one task per value). The job's
// progress is the jobs panel's (JobsPanel). A refusal is shown here, on the
// field its `error.path` names. Listens to the editor's signals; acts only
// through the editor.
import type { Editor } from '../core/Editor';
import { instanceValue, type RenderJobRequest } from '../net/types';
import { el } from './dom';
import { FormatChecks } from './FormatChecks';

const DEFAULT_FORMATS = new Set(['ply']);
/** Resolution multipliers: the particle radius is divided by it. */
const RESOLUTIONS = [1, 2, 4];
const MAX_WEDGE_VALUES = 64;
const NUMBER = /^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$/;

/** Comma-separated numbers of a wedge, or why they are not. */
export function parseWedgeValues(text: string): { values: number[] } | { error: string } {
  const tokens = text.split(',').map((t) => t.trim());
  if (tokens.length === 1 && tokens[0] === '') return { error: 'wedge values: give at least one number (comma-separated, e.g. 0, 0.1)' };
  const values: number[] = [];
  for (const [i, t] of tokens.entries()) {
    if (t === '') return { error: `wedge values: value ${i + 1} is empty (numbers separated by commas)` };
    const v = Number(t);
    if (!NUMBER.test(t) || !Number.isFinite(v)) return { error: `wedge values: "${t}" is not a number` };
    if (values.includes(v)) return { error: `wedge values: ${t} is given twice (each value is one task)` };
    values.push(v);
  }
  if (values.length > MAX_WEDGE_VALUES) return { error: `wedge values: at most ${MAX_WEDGE_VALUES} (one task each), not ${values.length}` };
  return { values };
}

/** A radius in metres without float noise (0.004 / 3 → "0.001333"). */
function metres(r: number): string {
  return `${Number(r.toPrecision(4))} m`;
}

export class RenderDialog {
  readonly dom: HTMLDialogElement;
  private readonly name: HTMLInputElement;
  private readonly resolution: HTMLSelectElement;
  private readonly radius: HTMLElement;
  private readonly seconds: HTMLInputElement;
  private readonly frames: HTMLElement;
  private readonly formats: FormatChecks;
  private readonly framesExport: HTMLInputElement;
  private readonly wedgePick: HTMLSelectElement;
  private readonly wedgeKey: HTMLInputElement;
  private readonly wedgeValues: HTMLInputElement;
  private readonly error: HTMLElement;
  private readonly submitButton: HTMLButtonElement;
  private submitting = false;

  constructor(private readonly editor: Editor) {
    this.name = el('input', { testid: 'render-name', title: 'Job name: its folder on the server is EXPORTS/jobs/ID/ either way', attrs: { type: 'text', size: '16', spellcheck: 'false' } });
    this.resolution = el('select', { testid: 'render-resolution', title: "The session's particle radius divided by this: ×2 is about 2^dimension times the particles, and more, smaller steps" });
    for (const m of RESOLUTIONS) this.resolution.append(el('option', { text: `×${m}`, attrs: { value: String(m) } }));
    this.radius = el('span', { testid: 'render-radius', className: 'hint' });
    this.seconds = el('input', { testid: 'render-seconds', title: 'Simulated seconds of each task (default: the scene\'s duration)', attrs: { type: 'number', min: '0.001', max: '36000', step: 'any' } });
    this.frames = el('span', { testid: 'render-frames', className: 'hint' });
    this.formats = new FormatChecks(editor, 'render', DEFAULT_FORMATS);
    this.framesExport = el('input', { testid: 'render-frames-export', attrs: { type: 'checkbox' } });
    this.framesExport.checked = true;
    this.wedgePick = el('select', { testid: 'render-wedge-pick', title: 'A key path of this scene to wedge (or type any path beside)' });
    this.wedgeKey = el('input', { testid: 'render-wedge-key', title: 'The scene key path each task sets to one of the values: a.b, list[NAME].key, list[3].key', attrs: { type: 'text', size: '22', spellcheck: 'false', placeholder: 'no wedge' } });
    this.wedgeValues = el('input', { testid: 'render-wedge-values', title: 'One task per value, comma-separated numbers', attrs: { type: 'text', size: '22', spellcheck: 'false', placeholder: 'e.g. 0, 0.1, 0.2' } });
    this.error = el('p', { testid: 'render-error', className: 'render-error' });
    this.submitButton = el('button', { testid: 'render-submit', text: 'Submit', title: 'Queue the job on the render workers (the jobs panel follows it)', attrs: { type: 'button' } });
    const close = el('button', { testid: 'render-close', text: 'Close', attrs: { type: 'button' } });
    this.dom = el('dialog', { className: 'export-dialog render-dialog', testid: 'render-dialog' }, [
      el('h3', { text: 'Render final' }),
      el('p', { className: 'hint', text: "This session's scene, every accepted edit included, simulated again from frame 0 on the render workers: finer, longer, as files." }),
      el('label', { text: 'Name ' }, [this.name]),
      el('label', { text: 'Resolution ' }, [this.resolution, ' ', this.radius]),
      el('label', { text: 'Duration (s) ' }, [this.seconds, ' ', this.frames]),
      el('div', { className: 'hint', text: 'Surfaces' }),
      this.formats.dom,
      el('label', { title: "Each task's particles as frames.h5 (flowclip export): re-mesh or inspect them later" }, [this.framesExport, ' particle export (frames.h5)']),
      el('fieldset', { className: 'render-wedge' }, [
        el('legend', { text: 'Wedge of one parameter (optional)' }),
        el('label', { text: 'Key ' }, [this.wedgePick, ' ', this.wedgeKey]),
        el('label', { text: 'Values ' }, [this.wedgeValues]),
      ]),
      this.error,
      el('div', { className: 'export-buttons' }, [this.submitButton, close]),
    ]);
    this.resolution.addEventListener('change', () => this.updateRadius());
    this.seconds.addEventListener('input', () => this.updateFrames());
    this.wedgePick.addEventListener('change', () => {
      if (this.wedgePick.value === 'custom') this.wedgeKey.focus();
      else this.wedgeKey.value = this.wedgePick.value;
      this.updateWedgeHint();
    });
    this.wedgeKey.addEventListener('input', () => {
      this.wedgePick.value = [...this.wedgePick.options].some((o) => o.value === this.wedgeKey.value) ? this.wedgeKey.value : 'custom';
      this.updateWedgeHint();
    });
    for (const input of [this.name, this.resolution, this.seconds, this.wedgeKey, this.wedgeValues]) {
      input.addEventListener('input', () => input.classList.remove('invalid'));
    }
    this.formats.dom.addEventListener('change', () => this.formats.dom.classList.remove('invalid'));
    this.submitButton.addEventListener('click', () => void this.submit());
    close.addEventListener('click', () => this.dom.close());
    editor.signals.sessionChanged.add(() => this.reset());
    editor.signals.sceneChanged.add(() => {
      this.updateRadius();
      this.renderWedgeKeys();
    });
    editor.signals.instancesChanged.add(() => this.renderWedgeKeys());
    editor.signals.renderAvailabilityChanged.add(() => this.updateSubmit());
    editor.signals.renderRequested.add(() => this.open());
    this.reset();
  }

  open() {
    if (this.dom.open) return;
    this.renderWedgeKeys();
    this.updateRadius();
    this.updateSubmit();
    this.dom.showModal();
  }

  /** Another session: the fields take its defaults (name, duration, no wedge). */
  private reset() {
    const s = this.editor.session;
    this.name.value = s ? `${s.scene}_final` : '';
    const d = s?.sceneJson?.duration;
    this.seconds.value = typeof d === 'number' && d > 0 ? String(d) : '';
    this.resolution.value = '1';
    this.wedgeKey.value = '';
    this.wedgeValues.value = '';
    this.showError('', null);
    this.renderWedgeKeys();
    this.updateRadius();
    this.updateFrames();
    this.updateSubmit();
  }

  private sceneRadius(): number | null {
    const r = this.editor.session?.sceneJson?.particle_radius;
    return typeof r === 'number' && r > 0 ? r : null;
  }

  private updateRadius() {
    const r = this.sceneRadius(), m = Number(this.resolution.value) || 1;
    const dim = this.editor.session?.dimension ?? 2;
    this.resolution.disabled = r === null;
    this.radius.dataset['value'] = r === null ? '' : String(r / m);
    this.radius.textContent = r === null
      ? "particle radius: the scene's"
      : `particle radius ${metres(r / m)}${m > 1 ? ` (scene ${metres(r)}; about ${m ** dim}× the particles)` : ''}`;
  }

  private updateFrames() {
    const s = Number(this.seconds.value);
    this.frames.textContent = this.seconds.value !== '' && Number.isFinite(s) && s > 0
      ? `= ${Math.max(1, Math.round(s * this.editor.frameRate()))} frames at ${this.editor.frameRate()} fps`
      : '';
  }

  /** Key paths worth wedging in this scene: each instance's speed and start, the particle radius. */
  private renderWedgeKeys() {
    const current = this.wedgeKey.value;
    const option = (value: string, text: string) => el('option', { text, attrs: { value } });
    const options = [option('', 'no wedge')];
    for (const name of this.editor.instances.keys()) {
      options.push(option(`instances[${name}].speed`, `${name} speed`), option(`instances[${name}].start`, `${name} start`));
    }
    if (this.sceneRadius() !== null) options.push(option('particle_radius', 'particle radius'));
    options.push(option('custom', 'other key path…'));
    this.wedgePick.replaceChildren(...options);
    this.wedgePick.value = options.some((o) => o.value === current) ? current : 'custom';
    this.updateWedgeHint();
  }

  /** The key's current value as the values' placeholder (the wedge's values replace it). */
  private updateWedgeHint() {
    const key = this.wedgeKey.value.trim();
    const m = /^instances\[([^\]]+)\]\.(\w+)$/.exec(key);
    let now: unknown;
    if (m) {
      const inst = this.editor.instances.get(m[1]!);
      if (inst) now = instanceValue(inst, m[2]!);
    } else if (key === 'particle_radius') {
      now = this.sceneRadius();
    }
    this.wedgeValues.placeholder = typeof now === 'number' ? `e.g. ${now}, … (now ${now})` : 'e.g. 0, 0.1, 0.2';
    this.wedgeValues.disabled = key === '';
  }

  private updateSubmit() {
    const a = this.editor.renderAvailability;
    const open = this.editor.session !== null;
    this.submitButton.disabled = this.submitting || !open || !a.available;
    this.submitButton.title = !open ? 'Open a scene first' : !a.available ? a.reason : `Queue the job on the render workers: ${a.where}`;
  }

  /** Shows why the job was refused; `path` (the request's key) marks its field. */
  private showError(text: string, path: string | null) {
    this.error.textContent = text;
    this.error.dataset['path'] = path ?? '';
    for (const f of [this.name, this.resolution, this.seconds, this.wedgeKey, this.wedgeValues, this.formats.dom]) f.classList.remove('invalid');
    if (!path) return;
    const field = path.startsWith('wedge.values') ? this.wedgeValues
      : path.startsWith('wedge') ? this.wedgeKey
        : path.startsWith('particle_radius') ? this.resolution
          : path.startsWith('seconds') || path.startsWith('frames') ? this.seconds
            : path.startsWith('formats') ? this.formats.dom
              : path.startsWith('name') ? this.name
                : null;
    field?.classList.add('invalid');
  }

  /** The request from the fields, or why not (nothing is sent then). */
  private request(): { body: Omit<RenderJobRequest, 'session'> } | { error: string; path: string } {
    const name = this.name.value.trim();
    if (!/^[A-Za-z0-9_-]{1,64}$/.test(name)) return { error: `name: "${name}" is not a name (letters, digits, _ and -, at most 64)`, path: 'name' };
    const seconds = Number(this.seconds.value);
    if (this.seconds.value.trim() === '' || !Number.isFinite(seconds) || seconds < 0.001 || seconds > 36000) {
      return { error: `duration: "${this.seconds.value}" is not a number of seconds in [0.001, 36000]`, path: 'seconds' };
    }
    const body: Omit<RenderJobRequest, 'session'> = { name, seconds, formats: this.formats.checked(), frames_export: this.framesExport.checked };
    const r = this.sceneRadius();
    if (r !== null) body.particle_radius = r / (Number(this.resolution.value) || 1);
    const key = this.wedgeKey.value.trim();
    // No key: no wedge (the values field is disabled and its text ignored).
    if (key !== '') {
      const parsed = parseWedgeValues(this.wedgeValues.value);
      if ('error' in parsed) return { error: parsed.error, path: 'wedge.values' };
      body.wedge = { key, values: parsed.values };
    }
    return { body };
  }

  private async submit() {
    const r = this.request();
    if ('error' in r) {
      this.showError(r.error, r.path);
      return;
    }
    this.showError('', null);
    this.submitting = true;
    this.updateSubmit();
    const result = await this.editor.submitRender(r.body);
    this.submitting = false;
    this.updateSubmit();
    if ('error' in result) {
      this.showError(result.error, result.path);
      return;
    }
    this.dom.close();
  }
}
