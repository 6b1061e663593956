// The template library (left panel): every template of the server's database
// (GET /api/templates) with its dimension, duration, particle count and a
// thumbnail of its middle frame (GET /api/templates/{name}/preview). Click
// "+" to instance it at the view centre, or drag it onto the viewport to
// instance it where it is dropped (the viewport handles the drop). Templates
// of the other dimension than the open scene's are shown but disabled.
import type { Editor } from '../core/Editor';
import type { TemplateInfo } from '../net/types';
import { el } from './dom';

/** The drag-and-drop data type carrying a template name. */
export const TEMPLATE_DRAG_TYPE = 'application/x-flowclip-template';

const THUMB_W = 96, THUMB_H = 64;

export class TemplateLibrary {
  readonly dom: HTMLElement;
  private readonly list: HTMLElement;
  /** Thumbnails drawn once per template name and file size (a re-listing does not refetch). */
  private readonly thumbs = new Map<string, HTMLCanvasElement>();

  constructor(private readonly editor: Editor) {
    this.list = el('div', { className: 'library-list', testid: 'library-list' });
    const refresh = el('button', { text: '⟳', title: 'Re-read the template database', attrs: { type: 'button' } });
    refresh.addEventListener('click', () => void editor.loadTemplates());
    this.dom = el('section', { className: 'panel library', testid: 'library' }, [
      el('h2', {}, ['Templates ', refresh]),
      this.list,
    ]);
    editor.signals.templatesChanged.add((t) => this.render(t));
    editor.signals.sessionChanged.add(() => this.render(editor.templates));
  }

  private render(templates: TemplateInfo[]) {
    const dim = this.editor.session?.dimension ?? null;
    this.list.replaceChildren();
    // None of the open scene's dimension: say how to get one (templates are recorded from recipes).
    const usable = templates.filter((t) => !t.error && (dim === null || t.dimension === dim));
    if (usable.length === 0) {
      const what = dim === null ? 'No templates on the server.' : `No ${dim}D template on the server.`;
      const hint = el('div', { className: 'empty library-hint', testid: 'library-empty' }, [
        `${what} Record one from a recipe on the server machine, e.g. `,
        el('code', { text: `flowclip record templates/recipes/${dim === 3 ? 'hand3d' : 'drop2d'}.json` }),
        ' (the recipes are in templates/recipes/), then ',
        el('button', { text: '⟳ re-read', attrs: { type: 'button' }, title: 'Re-read the template database' }),
      ]);
      hint.querySelector('button')!.addEventListener('click', () => void this.editor.loadTemplates());
      this.list.append(hint);
    }
    for (const t of templates) this.list.append(this.item(t, dim));
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
