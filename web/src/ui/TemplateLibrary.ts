// The template library (left panel): every template of the server's database
// (GET /api/templates) with its dimension, duration, particle count and a
// thumbnail of its middle frame (GET /api/templates/{name}/preview). Click
// "+" to instance it at the view centre, or drag it onto the viewport to
// instance it where it is dropped (the viewport handles the drop). Templates
// of the other dimension than the open scene's are shown but disabled.
//
// Under them, the recipes that record what is missing (the templates a listed
// scene needs, or any template of the open scene's dimension when there is
// none), each with a Record button; a recording shows its progress and can
// be cancelled, and its templates join the list when it is done.
import type { Editor } from '../core/Editor';
import { jobActive } from '../core/RecipeRecorder';
import type { RecipeInfo, RecipeJob, TemplateInfo } from '../net/types';
import { el } from './dom';

/** The drag-and-drop data type carrying a template name. */
export const TEMPLATE_DRAG_TYPE = 'application/x-flowclip-template';

const THUMB_W = 96, THUMB_H = 64;

export class TemplateLibrary {
  readonly dom: HTMLElement;
  private readonly list: HTMLElement;
  private readonly recipeBox: HTMLElement;
  /** Rows of the recipes shown, by name (a job's progress updates its row in place). */
  private readonly recipeRows = new Map<string, HTMLElement>();
  /** Thumbnails drawn once per template name and file size (a re-listing does not refetch). */
  private readonly thumbs = new Map<string, HTMLCanvasElement>();

  constructor(private readonly editor: Editor) {
    this.list = el('div', { className: 'library-list', testid: 'library-list' });
    const refresh = el('button', { text: '⟳', title: 'Re-read the template database and the recipes', attrs: { type: 'button' } });
    refresh.addEventListener('click', () => {
      void editor.loadTemplates();
      void editor.recipes.load();
    });
    this.recipeBox = el('div', { className: 'library-recipes', testid: 'library-recipes' });
    this.dom = el('section', { className: 'panel library', testid: 'library' }, [
      el('h2', {}, ['Templates ', refresh]),
      this.list,
      this.recipeBox,
    ]);
    editor.signals.templatesChanged.add((t) => this.render(t));
    editor.signals.sessionChanged.add(() => this.render(editor.templates));
    editor.signals.scenesChanged.add(() => this.renderRecipes());
    editor.signals.recipesChanged.add(() => this.render(editor.templates)); // the empty hint mentions them too
    editor.signals.recipeJobChanged.add((job) => this.updateJob(job));
  }

  private render(templates: TemplateInfo[]) {
    const dim = this.editor.session?.dimension ?? null;
    this.list.replaceChildren();
    // None of the open scene's dimension: say how to get one (templates are recorded from recipes).
    const usable = templates.filter((t) => !t.error && (dim === null || t.dimension === dim));
    if (usable.length === 0) {
      const what = dim === null ? 'No templates on the server.' : `No ${dim}D template on the server.`;
      const recordable = this.editor.recipes.recipes.some((r) => !r.error && (dim === null || r.dimension === dim));
      const hint = el('div', { className: 'empty library-hint', testid: 'library-empty' }, [
        `${what} ${recordable ? 'Record one below, or' : 'Record one'} from a recipe on the server machine, e.g. `,
        el('code', { text: `flowclip record templates/recipes/${dim === 3 ? 'hand3d' : 'drop2d'}.json` }),
        ' (the recipes are in templates/recipes/), then ',
        el('button', { text: '⟳ re-read', attrs: { type: 'button' }, title: 'Re-read the template database' }),
      ]);
      hint.querySelector('button')!.addEventListener('click', () => void this.editor.loadTemplates());
      this.list.append(hint);
    }
    for (const t of templates) this.list.append(this.item(t, dim));
    this.renderRecipes();
  }

  /** The recipes worth offering: they record a template a scene lacks, or fill an empty library, or are recording. */
  private offeredRecipes(): { recipe: RecipeInfo; neededBy: string[] }[] {
    const dim = this.editor.session?.dimension ?? null;
    const neededBy = new Map<string, string[]>();
    for (const s of this.editor.scenes)
      for (const t of s.missing_templates ?? []) neededBy.set(t, [...(neededBy.get(t) ?? []), s.name]);
    const empty = !this.editor.templates.some((t) => !t.error && (dim === null || t.dimension === dim));
    const out: { recipe: RecipeInfo; neededBy: string[] }[] = [];
    for (const r of this.editor.recipes.recipes) {
      if (r.error) continue;
      const scenes = [...new Set((r.templates ?? []).filter((t) => !t.recorded).flatMap((t) => neededBy.get(t.name) ?? []))];
      const fills = empty && !r.recorded && (dim === null || r.dimension === dim);
      const job = this.editor.recipes.jobs.get(r.name);
      if (scenes.length > 0 || fills || jobActive(job) || job?.state === 'failed') out.push({ recipe: r, neededBy: scenes });
    }
    return out;
  }

  private renderRecipes() {
    const offered = this.offeredRecipes();
    this.recipeRows.clear();
    this.recipeBox.replaceChildren();
    if (offered.length === 0) return;
    this.recipeBox.append(el('h3', { text: 'Record from a recipe' }));
    for (const { recipe, neededBy } of offered) {
      const row = this.recipeRow(recipe, neededBy);
      this.recipeRows.set(recipe.name, row);
      this.recipeBox.append(row);
    }
  }

  private recipeRow(r: RecipeInfo, neededBy: string[]): HTMLElement {
    const names = (r.templates ?? []).map((t) => t.name).join(', ');
    const cost = `${r.frames ?? '?'} frames${r.last_seconds !== undefined ? `, last took ${fmt(r.last_seconds, 1)} s` : ''}`;
    const why = neededBy.length ? `needed by ${neededBy.join(', ')}` : `records ${names}`;
    const record = el('button', {
      text: 'Record', testid: `recipe-record-${r.name}`, attrs: { type: 'button' },
      title: `Simulate recipe ${r.name} on the server and add ${names} to the database (${cost})`,
    });
    record.addEventListener('click', () => void this.editor.recipes.record(r.name));
    const cancel = el('button', { text: '✕', testid: `recipe-cancel-${r.name}`, title: 'Cancel the recording (nothing is written)', attrs: { type: 'button' } });
    cancel.addEventListener('click', () => void this.editor.recipes.cancel(r.name));
    const bar = el('progress', { className: 'recipe-progress', testid: `recipe-progress-${r.name}`, attrs: { max: '1', value: '0' } });
    const status = el('div', { className: 'library-meta recipe-status', testid: `recipe-status-${r.name}` });
    const row = el('div', { className: 'library-item recipe-item', testid: `recipe-${r.name}` }, [
      el('div', { className: 'library-text' }, [
        el('div', { className: 'library-name', text: `${r.name} (${r.dimension}D)` }),
        el('div', { className: 'library-meta', text: `${why} · ${cost}`, title: `${why}; records ${names}; ${cost}` }),
        bar,
        status,
      ]),
      record,
      cancel,
    ]);
    row.dataset['templates'] = names;
    this.showJob(row, this.editor.recipes.jobs.get(r.name));
    return row;
  }

  private updateJob(job: RecipeJob) {
    const row = this.recipeRows.get(job.recipe);
    if (row) this.showJob(row, job);
    else if (jobActive(job) || job.state === 'failed') this.renderRecipes();
  }

  /** A row's Record / progress / Cancel for its job's state. */
  private showJob(row: HTMLElement, job: RecipeJob | undefined) {
    const active = jobActive(job);
    const record = row.querySelector<HTMLButtonElement>('[data-testid^="recipe-record-"]')!;
    const cancel = row.querySelector<HTMLButtonElement>('[data-testid^="recipe-cancel-"]')!;
    const bar = row.querySelector<HTMLProgressElement>('progress')!;
    const status = row.querySelector<HTMLElement>('.recipe-status')!;
    record.hidden = active;
    cancel.hidden = !active;
    cancel.disabled = job?.cancel_requested ?? false;
    bar.hidden = !active;
    bar.value = job?.progress ?? 0;
    row.dataset['state'] = job?.state ?? '';
    row.dataset['framesDone'] = String(job?.frames_done ?? 0);
    status.classList.toggle('error', job?.state === 'failed');
    status.textContent = !job ? ''
      : job.state === 'queued' ? 'queued (one recording at a time)'
      : job.state === 'running' ? `${job.cancel_requested ? 'cancelling… ' : ''}frame ${job.frames_done}/${job.frames} · ${fmt(job.elapsed_s, 1)} s`
      : job.state === 'failed' ? `failed: ${job.error ?? ''}`
      : job.state === 'cancelled' ? 'cancelled, nothing written'
      : `recorded in ${fmt(job.elapsed_s, 1)} s`;
  }

  private item(t: TemplateInfo, dim: 2 | 3 | null): HTMLElement {
    const usable = !t.error && (dim === null || t.dimension === dim);
    const meta = t.error
      ? `unreadable: ${t.error}`
      : `${t.dimension}D · ${fmt(t.duration, 2)} s · ${Math.round(t.avg_particles ?? 0).toLocaleString('en-US')} particles`;
    const add = el('button', {
      text: '+', testid: `library-add-${t.name}`, attrs: { type: 'button' },
      title: usable ? `Instance ${t.name} at the view centre (or drag it onto the viewport)` : `Needs a ${t.dimension}D scene`,
    });
    add.disabled = !usable || dim === null;
    add.addEventListener('click', () => void this.editor.addInstance(t.name));
    const row = el('div', { className: `library-item${usable ? '' : ' disabled'}`, testid: `library-item-${t.name}` }, [
      this.thumbnail(t),
      el('div', { className: 'library-text' }, [
        el('div', { className: 'library-name', text: t.name }),
        el('div', { className: 'library-meta', text: meta, title: meta }),
      ]),
      add,
    ]);
    row.dataset['dimension'] = String(t.dimension ?? '');
    row.dataset['duration'] = String(t.duration ?? '');
    row.dataset['particles'] = String(Math.round(t.avg_particles ?? 0));
    if (usable) {
      row.draggable = true;
      row.addEventListener('dragstart', (e) => {
        e.dataTransfer?.setData(TEMPLATE_DRAG_TYPE, t.name);
        e.dataTransfer?.setData('text/plain', t.name);
        if (e.dataTransfer) e.dataTransfer.effectAllowed = 'copy';
      });
    }
    return row;
  }

  private thumbnail(t: TemplateInfo): HTMLCanvasElement {
    const key = `${t.name}:${t.bytes ?? 0}`;
    const cached = this.thumbs.get(key);
    if (cached) return cached;
    const c = el('canvas', { className: 'library-thumb', testid: `library-thumb-${t.name}` });
    c.width = THUMB_W;
    c.height = THUMB_H;
    this.thumbs.set(key, c);
    if (!t.error) void this.drawPreview(t.name, c);
    return c;
  }

  /** The middle frame's particles, fitted into the region box (3D: an oblique x-y view with z receding). */
  private async drawPreview(name: string, c: HTMLCanvasElement) {
    const ctx = c.getContext('2d');
    if (!ctx) return;
    ctx.fillStyle = '#101317';
    ctx.fillRect(0, 0, c.width, c.height);
    let p;
    try {
      p = await this.editor.api.templatePreview(name, 1500);
    } catch (e) {
      c.dataset['points'] = '0';
      c.title = `no preview: ${e instanceof Error ? e.message : String(e)}`;
      ctx.fillStyle = '#ff6b6b';
      ctx.fillText('no preview', 6, c.height / 2);
      this.editor.reportError(e, `preview of template ${name}`);
      return;
    }
    const d = p.dimension, mn = p.region_min, mx = p.region_max;
    const oblique = d === 3 ? 0.35 : 0;
    const sx = (x: number, z: number) => x + oblique * z;
    const sy = (y: number, z: number) => y + oblique * z;
    const zr = d === 3 ? mx[2]! - mn[2]! : 0;
    const w = mx[0]! - mn[0]! + oblique * zr, h = mx[1]! - mn[1]! + oblique * zr;
    const s = Math.min((c.width - 6) / (w || 1), (c.height - 6) / (h || 1));
    const ox = (c.width - s * w) / 2, oy = (c.height - s * h) / 2;
    ctx.fillStyle = '#73b3ff';
    const n = p.positions.length / d;
    for (let i = 0; i < n; i++) {
      const x = p.positions[d * i]! - mn[0]!, y = p.positions[d * i + 1]! - mn[1]!;
      const z = d === 3 ? p.positions[d * i + 2]! - mn[2]! : 0;
      ctx.fillRect(ox + s * sx(x, z) - 0.75, c.height - (oy + s * sy(y, z)) - 0.75, 1.5, 1.5);
    }
    ctx.strokeStyle = '#5d6673';
    ctx.strokeRect(ox + 0.5, oy + 0.5, s * w - 1, s * h - 1);
    c.dataset['points'] = String(n);
    c.title = `${name}: frame ${p.frame} of ${p.frames} (t = ${p.time.toFixed(2)} s), ${p.particles} particles`;
  }
}

function fmt(v: number | undefined, digits: number): string {
  return typeof v === 'number' ? v.toFixed(digits) : '?';
}
