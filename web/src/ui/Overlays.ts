// The layer toggles and the stats panel, both in the left sidebar: off the
// viewport, so that they never cover the liquid.
// Values are also in data-value attributes (tests read them).
import type { Editor, LayerToggles } from '../core/Editor';
import type { FrameInfo } from '../net/FrameDecoder';
import { Layer } from '@wire';
import { el } from './dom';

/** Checkboxes for the liquid and the stream's optional layers; they act through editor.setLayers. */
export class LayerPanel {
  readonly dom: HTMLElement;

  constructor(editor: Editor) {
    const box = (key: keyof LayerToggles, label: string, swatch: string, title: string) => {
      const input = el('input', { testid: `layer-${key}`, attrs: { type: 'checkbox' } });
      input.checked = editor.layers[key];
      input.addEventListener('change', () => editor.setLayers({ [key]: input.checked }));
      editor.signals.layersChanged.add((l) => (input.checked = l[key]));
      const sw = el('span', { className: 'swatch' });
      sw.style.background = swatch;
      const row = el('label', { className: 'layer', title }, [input, sw, label]);
      // A recorded frame far from any checkpoint comes without these layers (the server does not re-simulate that far).
      const flag = ({ control: Layer.Control, repulsion: Layer.Repulsion, boundary: Layer.Boundary } as Partial<Record<keyof LayerToggles, Layer>>)[key];
      if (flag !== undefined) {
        const update = () => {
          // Only on a replayed frame: a live frame's layered copy may follow its plain one.
          const f = editor.decoder.info;
          const missing = editor.layers[key] && !editor.view.live && f.sessionId === editor.session?.id && (f.layers & flag) === 0;
          if (row.classList.contains('unavailable') === missing) return;
          row.classList.toggle('unavailable', missing);
          row.dataset['available'] = String(!missing);
          row.title = missing ? `${title}. Not on this recorded frame: too far from a checkpoint to re-simulate` : title;
        };
        editor.signals.frameDecoded.add(update);
        editor.signals.sessionView.add(update);
        editor.signals.layersChanged.add(update);
      }
      return row;
    };
    this.dom = el('section', { className: 'panel layers', testid: 'layers' }, [
      el('h2', { text: 'Layers' }),
      box('liquid', 'liquid', '#73b3ff', 'Liquid and temporary particles'),
      box('control', 'control', 'linear-gradient(90deg, #33d94d, #ff59e6)', 'Control particles: green α≈0 (covered by liquid) → magenta α≈1 (uncovered)'),
      box('repulsion', 'repulsion', '#ff3333', 'Repulsion particles'),
      box('boundary', 'boundary', '#8c8c99', 'Boundary (wall and obstacle) particles'),
      box('speed', 'by speed', 'linear-gradient(90deg, #0d1f73, #73b3ff, #fff)', 'Colour the liquid by speed: dark blue at rest → white at the fastest (temporary particles stay orange)'),
    ]);
  }
}

const RATE_WINDOW_MS = 2000;

/** Simulation timings, the rate frames arrive at, particle counts by kind, fidelity per instance, server memory. */
export class StatsOverlay {
  readonly dom: HTMLElement;
  private readonly fields: Record<string, HTMLElement> = {};
  private readonly fidelityList: HTMLElement;
  /** Wall times (ms) of the frames that arrived in the last RATE_WINDOW_MS. */
  private arrivals: number[] = [];
  private idleTimer: ReturnType<typeof setTimeout> | null = null;

  constructor(editor: Editor) {
    const row = (id: string, label: string, title: string) => {
      const value = el('span', { className: 'value', testid: `stats-${id}`, text: '–', attrs: { 'data-value': '' } });
      this.fields[id] = value;
      return el('div', { className: 'row', title }, [el('span', { className: 'label', text: label }), value]);
    };
    this.fidelityList = el('div', { className: 'fidelity', testid: 'stats-fidelity' });
    this.dom = el('section', { className: 'panel stats', testid: 'stats' }, [
      el('h2', { text: 'Simulation' }),
      row('sim-ms', 'sim ms/frame', 'Wall time of the frame on the server (control included)'),
      row('control-ms', 'control ms', 'Template control part of it'),
      row('fps', 'frames/s', 'Frames arriving per wall second (over the last 2 s; the stream sends at most 30 per second)'),
      row('liquid', 'liquid', 'Liquid particles (temporary ones excluded)'),
      row('temporary', 'temporary', 'Temporary particles seeded by template control'),
      row('boundary', 'boundary', 'Boundary particles'),
      row('memory', 'server MB', 'Resident memory of the server (GET /api/health, every 2 s)'),
      this.fidelityList,
    ]);
    editor.signals.frameDecoded.add((f) => this.onFrame(f));
    editor.signals.serverMemory.add((mb) => this.set('memory', mb.toFixed(0), String(mb)));
    editor.signals.sessionChanged.add(() => {
      this.arrivals = [];
      for (const k of Object.keys(this.fields)) if (k !== 'memory') this.set(k, '–', '');
      this.fidelityList.replaceChildren();
    });
  }

  /** Frames per second over the arrivals still in the window (0 with fewer than two). */
  private rate(now: number): number {
    this.arrivals = this.arrivals.filter((t) => now - t <= RATE_WINDOW_MS);
    const a = this.arrivals;
    if (a.length < 2) return 0;
    return ((a.length - 1) * 1000) / Math.max(1, a[a.length - 1]! - a[0]!);
  }

  private showRate() {
    const fps = this.rate(performance.now());
    this.set('fps', fps > 0 ? fps.toFixed(1) : '–', String(fps));
  }

  private onFrame(f: FrameInfo) {
    const now = performance.now();
    this.arrivals.push(now);
    this.showRate();
    // Frames stopped: the readout falls to – once the window is empty (one timer, no loop).
    if (this.idleTimer) clearTimeout(this.idleTimer);
    this.idleTimer = setTimeout(() => {
      this.idleTimer = null;
      this.showRate();
    }, RATE_WINDOW_MS + 50);
    this.set('sim-ms', f.wallMs.toFixed(1), String(f.wallMs));
    this.set('control-ms', f.controlMs.toFixed(1), String(f.controlMs));
    this.set('liquid', f.liquid.toLocaleString('en-US'), String(f.liquid));
    this.set('temporary', f.temporary.toLocaleString('en-US'), String(f.temporary));
    this.set('boundary', f.boundary.toLocaleString('en-US'), String(f.boundary));
    const list = this.fidelityList;
    while (list.children.length > f.instanceCount) list.lastChild!.remove();
    for (let k = 0; k < f.instanceCount; k++) {
      const inst = f.instances[k]!;
      let row = list.children[k] as HTMLElement | undefined;
      if (!row) {
        row = el('div', { className: 'row' }, [el('span', { className: 'label' }), el('span', { className: 'value' })]);
        list.append(row);
      }
      const measured = inst.fidelity >= 0;
      const label = row.firstChild as HTMLElement, value = row.lastChild as HTMLElement;
      const lt = `fidelity ${inst.name}`, vt = measured ? inst.fidelity.toFixed(3) : '–';
      if (label.textContent !== lt) label.textContent = lt;
      if (value.textContent !== vt) value.textContent = vt;
      row.dataset['testid'] = `stats-fidelity-${inst.name}`;
      row.dataset['value'] = measured ? String(inst.fidelity) : '';
      row.title = 'Occupancy IoU with the template frame, [0, 1] (– : not measured, e.g. inactive)';
    }
  }

  private set(id: string, text: string, value: string) {
    const e = this.fields[id]!;
    if (e.textContent !== text) e.textContent = text;
    e.dataset['value'] = value;
  }
}
