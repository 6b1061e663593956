// The timeline (under the viewport), laid out like a DCC's: a ruler in
// frames or seconds (a toggle) with frame-aligned ticks, the play range's
// start and end markers and the scene's end; under it the cache bar (frames
// recorded and valid, stale after an edit, being re-simulated); a playhead
// that goes anywhere in [0, end frame]; and one track per instance (scene
// order) over the scene time it is active, with its transform keys as
// diamonds. Tracks select their instance, move (body) and crop (ends); a
// key diamond drags in time; the ruler scrubs (recorded frames are seeks,
// others are drawn by the client). Wheel zooms around the cursor,
// Shift+wheel or dragging the empty background pans.
//
// It listens to the hub's signals and acts only through it: edits are
// Commands (one history entry per drag), the playhead is
// editor.setPlayhead. It renders on demand (one animation frame after
// something changed), never in a loop. Plain DOM: tests find the parts by
// data-testid and read data-* values.
// One widget: ruler, cache bar, playhead and tracks share one frame↔pixel mapping.
import './timeline.css';
import type { Editor } from '../core/Editor';
import { instanceValue, type InstanceJson, type TemplateInfo } from '../net/types';
import { SetInstanceValuesCommand, type InstanceValues } from '../commands/SetInstanceValuesCommand';
import { SetInstanceTransformCommand } from '../commands/SetInstanceTransformCommand';
import { moveKey } from '../core/TransformTrack';
import type { TransformKey } from '../net/types';
import { el } from './dom';
import { dragValues, frameTickStep, keysOf, sceneEnd, timingOf, withValues, type DragPart, type Timing } from './TimelineModel';

export type TimeUnits = 'frames' | 'seconds';
/** Pixels a pointer moves before a press becomes a drag (a click selects only). */
const DRAG_THRESHOLD_PX = 3;
const MIN_PX_PER_SECOND = 4;
const MAX_PX_PER_SECOND = 20_000;

/** One track's elements, kept across renders (a drag must not lose the element it started on). */
interface TrackDom {
  row: HTMLElement;
  body: HTMLElement;
  label: HTMLElement;
  left: HTMLElement;
  right: HTMLElement;
  keys: HTMLElement[];
}

type Drag =
  | {
      kind: 'edit';
      part: DragPart;
      instance: string;
      pointerId: number;
      x0: number;
      moved: boolean;
      timing0: Timing;
      /** The instance's values of the edited keys when the drag began (undo restores them). */
      old: InstanceValues;
      /** Unique to the drag: its commands merge into one history entry. */
      dragId: string;
    }
  | { kind: 'pan'; pointerId: number; x0: number; viewStart0: number; moved: boolean }
  | { kind: 'scrub'; pointerId: number }
  | { kind: 'range'; end: 'start' | 'end'; pointerId: number }
  | {
      kind: 'key';
      pointerId: number;
      instance: string;
      index: number;
      x0: number;
      moved: boolean;
      /** The track when the drag began (every command of the drag is built from it). */
      track0: TransformKey[];
      time0: number;
      dragId: string;
    };

/** A key drag on its way to the server: the diamond shows `time` at once; at most one PATCH in flight. */
interface KeyFlight {
  instance: string;
  index: number;
  time: number;
  dragId: string;
  pending: TransformKey[] | null;
  running: boolean;
  released: boolean;
}

/** An edit drag's values on their way to the server: at most one PATCH in flight, the latest values win. */
interface EditFlight {
  instance: string;
  old: InstanceValues;
  dragId: string;
  name: string;
  /** What the user sees while the drag's PATCHes land (the server's answers lag behind the pointer). */
  preview: InstanceValues;
  pending: InstanceValues | null;
  sent: InstanceValues | null;
  running: boolean;
  /** A command of this drag has run (so the history's top entry is the drag's, and a newer command merges into it). */
  landed: boolean;
  /** The final command, issued when the pointer was released. */
  final: Promise<void> | null;
  /** The pointer was released: drop the preview once the last PATCH landed. */
  released: boolean;
}

let dragCount = 0;

export class Timeline {
  readonly dom: HTMLElement;
  private readonly ruler: HTMLElement;
  private readonly ticks: HTMLElement;
  private readonly simulated: HTMLElement;
  private readonly cache: HTMLElement;
  private readonly rangeStart: HTMLElement;
  private readonly rangeEnd: HTMLElement;
  private readonly outsideBefore: HTMLElement;
  private readonly outsideAfter: HTMLElement;
  private readonly endMark: HTMLElement;
  private readonly tracks: HTMLElement;
  private readonly playhead: HTMLElement;
  private readonly readout: HTMLElement;
  private readonly hint: HTMLElement;
  private readonly unitsButton: HTMLButtonElement;
  private readonly loopButton: HTMLButtonElement;
  private readonly autoKeyButton: HTMLButtonElement;
  private readonly trackDoms = new Map<string, TrackDom>();
  private units: TimeUnits = readUnits();

  /** Scene time at the left edge, s, and the zoom. */
  private viewStart = 0;
  private pxPerSecond = 100;
  /** Fit the view to the content at the next render that can (set when a session opens). */
  private fitPending = true;
  private width = 0;

  private drag: Drag | null = null;
  private flight: EditFlight | null = null;
  private keyFlight: KeyFlight | null = null;
  /** The recorded range last drawn (a frame growing it redraws the bars only). */
  private drawnRecorded = '';

  private templatesListed = false;
  private renderScheduled = false;
  /** Something besides the playhead changed since the last render. */
  private layoutDirty = true;
  /** Renders so far, also in data-renders (tests check that nothing renders while nothing changes). */
  renders = 0;

  constructor(private readonly editor: Editor) {
    this.ticks = el('div', { className: 'ticks' });
    this.simulated = el('div', {
      className: 'simulated', testid: 'timeline-simulated',
      title: 'Recorded frames (the replay history on the server): drag here to scrub',
    });
    this.rangeStart = el('div', { className: 'range-mark start', testid: 'timeline-range-start', attrs: { 'data-range': 'start' }, title: 'Play range start: drag to move' });
    this.rangeEnd = el('div', { className: 'range-mark end', testid: 'timeline-range-end', attrs: { 'data-range': 'end' }, title: 'Play range end (playback stops or loops here): drag to move' });
    this.endMark = el('div', { className: 'scene-end', testid: 'timeline-scene-end', title: "The scene's end (its duration)" });
    this.cache = el('div', {
      className: 'cache', testid: 'timeline-cache',
      title: 'Cache: blue frames are recorded and valid, orange ones are stale (an edit changed them; re-simulated by the server), the striped part is being simulated',
    });
    this.readout = el('span', { className: 'readout', testid: 'timeline-readout' });
    const button = (testid: string, text: string, title: string, onClick: () => void) => {
      const b = el('button', { testid, text, title, attrs: { type: 'button' } });
      b.addEventListener('click', onClick);
      return b;
    };
    const fit = button('timeline-fit', 'fit', 'Fit the view to the scene, the instances and the recorded frames', () => this.fitView());
    fit.classList.add('fit');
    this.unitsButton = button('timeline-units', '', 'Ruler and readout in frames or in seconds', () => {
      this.units = this.units === 'frames' ? 'seconds' : 'frames';
      try {
        localStorage.setItem('flowclip-time-units', this.units);
      } catch {
        // Storage refused (private mode): the toggle still works for this page.
      }
      this.requestRender();
    });
    this.loopButton = button('timeline-loop', '⟲', 'Loop the play range (off: playback stops at its end)', () =>
      editor.setPlayRange({ loop: !editor.playRange.loop }));
    this.autoKeyButton = button('timeline-autokey', '●', '', () => editor.setAutoKey(!editor.autoKey));
    const prevKey = button('timeline-prev-key', '◆◀', 'Previous key (Down arrow): of the selected instance, else of any', () => editor.jumpToKey(-1));
    const nextKey = button('timeline-next-key', '▶◆', 'Next key (Up arrow): of the selected instance, else of any', () => editor.jumpToKey(1));
    this.ruler = el('div', {
      className: 'ruler', testid: 'timeline-ruler',
      title: 'Press or drag to move the playhead: a recorded frame is shown from the server, any other from the tracks',
    }, [this.simulated, this.ticks, this.endMark, this.rangeStart, this.rangeEnd]);
    this.tracks = el('div', { className: 'tracks', testid: 'timeline-tracks' });
    this.outsideBefore = el('div', { className: 'outside-range' });
    this.outsideAfter = el('div', { className: 'outside-range' });
    this.hint = el('div', { className: 'hint', text: 'open a scene to see its instances' });
    this.playhead = el('div', { className: 'playhead', testid: 'timeline-playhead', attrs: { 'data-value': '0' } });
    this.dom = el('div', { className: 'timeline', testid: 'timeline', attrs: { 'data-pending': 'false' } }, [
      this.ruler, this.cache, this.tracks, this.outsideBefore, this.outsideAfter, this.hint, this.playhead,
      el('div', { className: 'corner' }, [this.readout, prevKey, nextKey, this.autoKeyButton, this.loopButton, this.unitsButton, fit]),
    ]);

    this.dom.addEventListener('pointerdown', (e) => this.onPointerDown(e));
    this.dom.addEventListener('pointermove', (e) => this.onPointerMove(e));
    this.dom.addEventListener('pointerup', (e) => this.onPointerUp(e));
    this.dom.addEventListener('pointercancel', (e) => this.onPointerUp(e));
    this.dom.addEventListener('wheel', (e) => this.onWheel(e), { passive: false });
    new ResizeObserver(() => this.requestRender()).observe(this.dom);

    const s = editor.signals;
    s.instancesChanged.add(() => this.requestRender());
    s.templatesChanged.add(() => {
      this.templatesListed = true;
      this.requestRender();
    });
    s.selectionChanged.add(() => this.requestRender());
    s.sceneChanged.add(() => this.requestRender()); // the frame rate may have changed
    s.sessionChanged.add((info) => {
      this.drag = null;
      this.flight = null;
      this.keyFlight = null;
      this.updatePending();
      this.fitPending = info !== null;
      this.requestRender();
    });
    s.sessionView.add(() => this.requestRender());
    s.issuesChanged.add(() => this.requestRender());
    s.playRangeChanged.add(() => this.requestRender());
    s.autoKeyChanged.add(() => this.requestRender());
    s.playbackChanged.add(() => {
      this.updatePending();
      this.requestRender('playhead');
    });
    s.playheadChanged.add(() => this.requestRender('playhead'));
    s.frameDecoded.add((f) => {
      // While playing, StateChange messages are rare: the frames grow the recorded range.
      if (f.sessionId !== this.editor.session?.id) return;
      if (this.recordedKey() !== this.drawnRecorded) this.requestRender('playhead');
    });
  }

  // -------------------------------------------------------------- state ---

  private recordedKey(): string {
    const [a, b] = this.editor.recordedRange();
    return `${a}:${b}`;
  }

  private sceneFrameRate(): number {
    return this.editor.frameRate();
  }

  private template(inst: InstanceJson): TemplateInfo | undefined {
    return this.editor.templateInfo(inst.template);
  }

  /** The timing the track shows: the drag's preview while one is on its way to the server. */
  private timing(inst: InstanceJson): Timing | null {
    const t = timingOf(inst, this.template(inst));
    if (t && this.flight && this.flight.instance === inst.name) return withValues(t, this.flight.preview);
    return t;
  }

  private x(time: number): number {
    return (time - this.viewStart) * this.pxPerSecond;
  }

  private timeAt(clientX: number): number {
    const r = this.dom.getBoundingClientRect();
    return this.viewStart + (clientX - r.left) / this.pxPerSecond;
  }

  // ------------------------------------------------------------ view ---

  /** 0 to the latest of the instances' ends, the simulated time and the scene's duration, plus a margin. */
  private fitView() {
    let end = this.editor.lastFrame() / this.sceneFrameRate();
    const sceneDuration = this.editor.session?.sceneJson?.duration;
    if (typeof sceneDuration === 'number' && sceneDuration > 0) end = Math.max(end, sceneDuration);
    for (const inst of this.editor.instances.values()) {
      const t = this.timing(inst);
      if (t) end = Math.max(end, sceneEnd(t));
    }
    const span = Math.max(end, 0.5) * 1.1;
    const width = this.dom.clientWidth;
    if (width <= 0) return;
    this.pxPerSecond = clamp(width / span, MIN_PX_PER_SECOND, MAX_PX_PER_SECOND);
    // A little room left of 0, so that a track starting at 0 keeps a grabbable left end.
    this.viewStart = -8 / this.pxPerSecond;
    this.requestRender();
  }

  private zoomAround(clientX: number, factor: number) {
    const t = this.timeAt(clientX);
    const r = this.dom.getBoundingClientRect();
    this.pxPerSecond = clamp(this.pxPerSecond * factor, MIN_PX_PER_SECOND, MAX_PX_PER_SECOND);
    this.viewStart = t - (clientX - r.left) / this.pxPerSecond;
    this.fitPending = false;
    this.requestRender();
  }

  private panBy(dxPixels: number) {
    this.viewStart += dxPixels / this.pxPerSecond;
    this.fitPending = false;
    this.requestRender();
  }

  private onWheel(e: WheelEvent) {
    if (this.drag) return;
    e.preventDefault();
    const unit = e.deltaMode === WheelEvent.DOM_DELTA_LINE ? 16 : e.deltaMode === WheelEvent.DOM_DELTA_PAGE ? this.width : 1;
    const dx = e.deltaX * unit, dy = e.deltaY * unit;
    if (e.shiftKey || Math.abs(dx) > Math.abs(dy)) {
      this.panBy(Math.abs(dx) > Math.abs(dy) ? dx : dy);
    } else {
      // Plain wheel and Ctrl+wheel (a trackpad pinch) zoom; up zooms in.
      this.zoomAround(e.clientX, Math.exp(-dy * 0.002));
    }
  }

  // ------------------------------------------------------------ pointer ---

  private onPointerDown(e: PointerEvent) {
    if (e.button !== 0 || this.drag) return;
    const target = e.target as HTMLElement;
    if (target.closest('.corner')) return; // the fit button
    const session = this.editor.session;
    const part = target.closest<HTMLElement>('[data-part]');
    const mark = target.closest<HTMLElement>('[data-range]');
    if (mark && session) {
      e.preventDefault();
      this.dom.setPointerCapture(e.pointerId);
      this.drag = { kind: 'range', end: mark.dataset['range'] === 'start' ? 'start' : 'end', pointerId: e.pointerId };
      return;
    }
    if (target.closest('.ruler') || target.closest('.cache')) {
      if (!session) return;
      e.preventDefault();
      this.dom.setPointerCapture(e.pointerId);
      this.drag = { kind: 'scrub', pointerId: e.pointerId };
      this.scrubTo(e.clientX);
      return;
    }
    const instanceName = part?.dataset['instance'];
    const inst = instanceName !== undefined ? this.editor.instances.get(instanceName) : undefined;
    if (part && inst) {
      e.preventDefault();
      this.editor.select(inst.name);
      const partName = part.dataset['part'];
      if (partName === 'key') {
        // A key diamond drags in time (the previous key drag lands first: its track is this one's start).
        const index = Number(part.dataset['index']);
        const track0 = structuredClone(inst.transform ?? []);
        if (this.keyFlight || !track0[index]) return;
        this.dom.setPointerCapture(e.pointerId);
        this.drag = {
          kind: 'key', pointerId: e.pointerId, instance: inst.name, index, x0: e.clientX, moved: false,
          track0, time0: track0[index]!.time ?? 0, dragId: `key-${++dragCount}`,
        };
        return;
      }
      const timing0 = this.timing(inst);
      // No length to drag while the template is unknown; and the previous
      // drag's last PATCH lands first (its values are this drag's old values,
      // and one flight at a time keeps them in order).
      if (!timing0 || this.flight) return;
      const dragPart: DragPart = partName === 'left' ? 'left' : partName === 'right' ? 'right' : 'body';
      const old: InstanceValues = {};
      for (const k of keysOf(dragPart, timing0.reverse)) old[k] = instanceValue(inst, k);
      this.dom.setPointerCapture(e.pointerId);
      this.drag = {
        kind: 'edit', part: dragPart, instance: inst.name, pointerId: e.pointerId, x0: e.clientX, moved: false,
        timing0, old, dragId: `timeline-${dragPart}-${++dragCount}`,
      };
      return;
    }
    // The empty background: a drag pans, a click clears the selection.
    e.preventDefault();
    this.dom.setPointerCapture(e.pointerId);
    this.drag = { kind: 'pan', pointerId: e.pointerId, x0: e.clientX, viewStart0: this.viewStart, moved: false };
  }

  private onPointerMove(e: PointerEvent) {
    const d = this.drag;
    if (!d || d.pointerId !== e.pointerId) return;
    if (d.kind === 'scrub') {
      this.scrubTo(e.clientX);
      return;
    }
    if (d.kind === 'range') {
      const frame = Math.round(this.timeAt(e.clientX) * this.sceneFrameRate());
      const { start, end } = this.editor.rangeFrames();
      const last = this.editor.lastFrame();
      if (d.end === 'start') this.editor.setPlayRange({ start: Math.max(0, Math.min(frame, end - 1)) });
      else this.editor.setPlayRange({ end: Math.min(last, Math.max(frame, start + 1)) });
      return;
    }
    if (!d.moved && Math.abs(e.clientX - d.x0) < DRAG_THRESHOLD_PX) return;
    d.moved = true;
    if (d.kind === 'key') {
      const fr = this.sceneFrameRate();
      const t = Math.round((d.time0 + (e.clientX - d.x0) / this.pxPerSecond) * fr) / fr;
      this.sendKey(d, t);
      return;
    }
    if (d.kind === 'pan') {
      this.viewStart = d.viewStart0 - (e.clientX - d.x0) / this.pxPerSecond;
      this.fitPending = false;
      this.requestRender();
      return;
    }
    const values = dragValues(d.part, d.timing0, (e.clientX - d.x0) / this.pxPerSecond, this.sceneFrameRate());
    this.sendEdit(d, values);
  }

  private onPointerUp(e: PointerEvent) {
    const d = this.drag;
    if (!d || d.pointerId !== e.pointerId) return;
    this.drag = null;
    if (this.dom.hasPointerCapture(e.pointerId)) this.dom.releasePointerCapture(e.pointerId);
    if (d.kind === 'pan' && !d.moved) this.editor.select(null);
    const k = this.keyFlight;
    if (d.kind === 'key' && k && k.dragId === d.dragId) {
      k.released = true;
      // The release's track joins the history's queue now (an undo right after undoes the whole drag).
      if (k.running && k.pending) void this.pumpKey(k, true);
      if (!k.running) this.endKeyFlight(k);
    }
    const f = this.flight;
    if (d.kind === 'edit' && f && f.dragId === d.dragId) {
      f.released = true;
      // The release's values go into the history's queue now, not after the
      // PATCH in flight: an undo pressed right after the release (a slow
      // server) then undoes the whole drag instead of running between its
      // last two PATCHes. Only once a command of the drag has run, else the
      // final one would not merge with it (History decides when issued).
      if (f.running && f.pending && f.landed) {
        const values = f.pending;
        f.pending = null;
        if (this.changesSomething(f, values)) f.final = this.issueEdit(f, values);
      }
      if (!f.running) this.endFlight(f);
    }
  }

  // -------------------------------------------------------------- edits ---

  /** Shows `values` at once and sends them; while a PATCH is in flight only the newest values wait. */
  private sendEdit(d: Extract<Drag, { kind: 'edit' }>, values: InstanceValues) {
    let f = this.flight;
    if (!f || f.dragId !== d.dragId) {
      const name = d.part === 'body' ? `Move ${d.instance}` : `Crop ${d.instance} (${d.part} end)`;
      f = { instance: d.instance, old: d.old, dragId: d.dragId, name, preview: { ...d.old }, pending: null, sent: null, running: false, landed: false, final: null, released: false };
      this.flight = f;
      this.updatePending();
    }
    f.preview = values;
    f.pending = values;
    this.requestRender();
    if (!f.running) void this.pumpEdits(f);
  }

  /** data-pending on the timeline: a drag's PATCHes or a scrub's seeks are still on their way (tests wait for it). */
  private updatePending() {
    this.dom.dataset['pending'] = String(this.flight !== null || this.keyFlight !== null || this.editor.seeking);
  }

  /** Shows key `d.index` at `time` at once and sends the track (one PATCH in flight, the newest track waits). */
  private sendKey(d: Extract<Drag, { kind: 'key' }>, time: number) {
    const gap = 1 / this.sceneFrameRate();
    const track = moveKey(d.track0, d.index, time, gap);
    let k = this.keyFlight;
    if (!k || k.dragId !== d.dragId) {
      k = { instance: d.instance, index: d.index, time: d.time0, dragId: d.dragId, pending: null, running: false, released: false };
      this.keyFlight = k;
      this.updatePending();
    }
    const t = track[d.index]!.time ?? 0;
    if (t === k.time && !k.pending) return;
    k.time = t;
    k.pending = track;
    this.requestRender();
    if (!k.running) void this.pumpKey(k);
  }

  private async pumpKey(k: KeyFlight, release = false) {
    if (release) {
      // Issued behind the PATCH in flight (it merges with it: same drag).
      const track = k.pending!;
      k.pending = null;
      await this.issueKey(k, track);
      return;
    }
    k.running = true;
    while (k.pending && this.keyFlight === k) {
      const track = k.pending;
      k.pending = null;
      await this.issueKey(k, track);
    }
    k.running = false;
    if (k.released) this.endKeyFlight(k);
  }

  private issueKey(k: KeyFlight, track: TransformKey[]): Promise<void> {
    const name = `Move key ${k.index} of ${k.instance}`;
    return this.editor.execute(new SetInstanceTransformCommand(this.editor, k.instance, track, undefined, k.dragId, { name }));
  }

  private endKeyFlight(k: KeyFlight) {
    if (this.keyFlight !== k) return;
    this.keyFlight = null;
    this.updatePending();
    this.requestRender();
  }

  private async pumpEdits(f: EditFlight) {
    f.running = true;
    // One PATCH at a time: a history entry merges only with the entry that
    // has landed, and the server's edit queue is not flooded by pointer moves.
    while (f.pending && this.flight === f) {
      const values = f.pending;
      f.pending = null;
      if (this.changesSomething(f, values)) await this.issueEdit(f, values);
    }
    if (f.final) await f.final;
    f.running = false;
    if (f.released) this.endFlight(f);
  }

  private changesSomething(f: EditFlight, values: InstanceValues): boolean {
    const last = f.sent ?? f.old;
    return Object.keys(values).some((k) => last[k] !== values[k]);
  }

  /** One command of the drag (its failure is reported by the history; the drag goes on). */
  private issueEdit(f: EditFlight, values: InstanceValues): Promise<void> {
    f.sent = values;
    const cmd = new SetInstanceValuesCommand(this.editor, f.instance, values, f.old, { name: f.name, drag: f.dragId });
    return this.editor.execute(cmd).then(() => {
      f.landed = true;
    });
  }

  /** The drag's PATCHes have landed (or failed: the history reported it): show the server's values again. */
  private endFlight(f: EditFlight) {
    if (this.flight !== f) return;
    this.flight = null;
    this.updatePending();
    this.requestRender();
  }

  // ----------------------------------------------------------- scrubbing ---

  /** Moves the playhead to the frame under the pointer (the hub seeks recorded frames). */
  private scrubTo(clientX: number) {
    this.editor.setPlayhead(Math.round(this.timeAt(clientX) * this.sceneFrameRate()));
    this.updatePending();
  }

  // ------------------------------------------------------------ render ---

  /** 'playhead': only the playhead and the simulated range moved (a frame arrived while playing). */
  private requestRender(what: 'all' | 'playhead' = 'all') {
    if (what === 'all') this.layoutDirty = true;
    if (this.renderScheduled) return;
    this.renderScheduled = true;
    requestAnimationFrame(() => {
      this.renderScheduled = false;
      this.render();
    });
  }

  private render() {
    this.renders++;
    this.dom.dataset['renders'] = String(this.renders);
    if (!this.layoutDirty) {
      this.renderSimulated();
      this.renderPlayhead();
      return;
    }
    this.renderButtons();
    this.layoutDirty = false;
    this.width = this.dom.clientWidth;
    if (this.fitPending && this.width > 0 && this.editor.session && this.contentKnown()) {
      this.fitPending = false;
      this.fitView();
    }
    this.dom.dataset['viewStart'] = String(this.viewStart);
    this.dom.dataset['pxPerSecond'] = String(this.pxPerSecond);
    this.hint.hidden = this.editor.session !== null;
    this.renderRuler();
    this.renderTracks();
    this.renderPlayhead();
  }

  /** The template list has arrived (the fit needs the instances' lengths; a failed listing was reported and fits without them). */
  private contentKnown(): boolean {
    return this.templatesListed || this.editor.templates.length > 0;
  }

  private renderButtons() {
    const e = this.editor;
    this.unitsButton.textContent = this.units === 'frames' ? 'frames' : 'sec';
    this.unitsButton.dataset['value'] = this.units;
    this.loopButton.classList.toggle('on', e.playRange.loop);
    this.loopButton.setAttribute('aria-pressed', String(e.playRange.loop));
    this.loopButton.dataset['value'] = String(e.playRange.loop);
    this.autoKeyButton.classList.toggle('on', e.autoKey);
    this.autoKeyButton.setAttribute('aria-pressed', String(e.autoKey));
    this.autoKeyButton.dataset['value'] = String(e.autoKey);
    this.autoKeyButton.title = e.autoKey
      ? 'Auto-key on: an edit of an animated transform keys it at the playhead'
      : 'Auto-key off: an edit of an animated transform moves its whole track (turn on to key at the playhead)';
  }

  /** Ticks at whole frames: labelled in frames, or in seconds at steps that are whole frames too. */
  private renderRuler() {
    const fr = this.sceneFrameRate();
    const { major, minor } = frameTickStep(this.pxPerSecond / fr, fr, 64, this.units);
    const f0 = this.viewStart * fr, f1 = (this.viewStart + this.width / this.pxPerSecond) * fr;
    const nodes: HTMLElement[] = [];
    const decimals = Math.min(3, Math.max(0, Math.ceil(-Math.log10(major / fr) - 1e-9)));
    for (let i = Math.ceil(f0 / minor); i * minor <= f1; i++) {
      const frame = i * minor;
      const isMajor = frame % major === 0;
      const tick = el('div', { className: isMajor ? 'tick major' : 'tick' });
      tick.style.left = `${this.x(frame / fr)}px`;
      if (isMajor) {
        tick.dataset['frame'] = String(frame);
        tick.append(el('span', { text: this.units === 'frames' ? String(frame) : `${(frame / fr).toFixed(decimals)}s` }));
      }
      nodes.push(tick);
    }
    this.ticks.replaceChildren(...nodes);
    this.ticks.dataset['major'] = String(major);
    this.renderSimulated();
  }

  /** The recorded range, the cache bar, the play range and the scene's end. */
  private renderSimulated() {
    const e = this.editor, fr = this.sceneFrameRate();
    const hasSession = e.session !== null;
    this.drawnRecorded = this.recordedKey();
    for (const n of [this.simulated, this.cache, this.rangeStart, this.rangeEnd, this.endMark, this.outsideBefore, this.outsideAfter]) n.hidden = !hasSession;
    if (!hasSession) return;
    const [first, last] = e.recordedRange();
    const span = (n: HTMLElement, a: number, b: number) => {
      const xa = this.x(a / fr), xb = this.x(b / fr);
      n.style.left = `${xa}px`;
      n.style.width = `${Math.max(2, xb - xa)}px`;
    };
    span(this.simulated, first, last);
    this.simulated.dataset['first'] = String(first);
    this.simulated.dataset['last'] = String(last);

    // Cache bar: valid (the newest live frames extend the last valid range), stale, simulating.
    const c = e.view.cache;
    const valid = c.valid.map(([a, b]) => [a, b] as [number, number]);
    const newest = e.recordedRange()[1];
    const top = valid[valid.length - 1];
    const inStale = c.stale.some(([a, b]) => newest >= a && newest <= b);
    if (!inStale && !c.simulating) {
      if (top && newest > top[1]) top[1] = newest;
      else if (!top && newest > first) valid.push([first, newest]);
    }
    const segments: HTMLElement[] = [];
    const seg = (kind: string, k: number, a: number, b: number, title: string) => {
      // A range [a, b] of frames covers the times of frames a..b: from (a − ½) to (b + ½) frames, at least a pixel.
      const n = el('div', { className: `segment ${kind}`, testid: `timeline-cache-${kind}-${k}`, title });
      const xa = this.x((a - 0.5) / fr), xb = this.x((b + 0.5) / fr);
      n.style.left = `${xa}px`;
      n.style.width = `${Math.max(2, xb - xa)}px`;
      n.dataset['first'] = String(a);
      n.dataset['last'] = String(b);
      segments.push(n);
    };
    valid.forEach(([a, b], k) => seg('valid', k, a, b, `frames ${a}–${b}: recorded, valid`));
    c.stale.forEach(([a, b], k) => seg('stale', k, a, b, `frames ${a}–${b}: stale (an edit changed them); viewable until re-simulated`));
    if (c.simulating) {
      const sim = c.simulating;
      seg('simulating', 0, sim.from, Math.max(sim.from, sim.frame), `re-simulating frames ${sim.from}–${sim.to}: at ${sim.frame}`);
    }
    for (const f of c.checkpoints) {
      const n = el('div', { className: 'checkpoint', title: `checkpoint at frame ${f}` });
      n.style.left = `${this.x(f / fr)}px`;
      segments.push(n);
    }
    this.cache.replaceChildren(...segments);
    this.cache.dataset['valid'] = valid.map(([a, b]) => `${a}-${b}`).join(',');
    this.cache.dataset['stale'] = c.stale.map(([a, b]) => `${a}-${b}`).join(',');
    this.cache.dataset['simulating'] = c.simulating ? `${c.simulating.from}-${c.simulating.to}@${c.simulating.frame}` : '';
    this.cache.dataset['reported'] = String(c.reported);

    // Play range and scene end.
    const { start, end } = e.rangeFrames();
    this.rangeStart.style.left = `${this.x(start / fr)}px`;
    this.rangeEnd.style.left = `${this.x(end / fr)}px`;
    this.rangeStart.dataset['value'] = String(start);
    this.rangeEnd.dataset['value'] = String(end);
    this.endMark.style.left = `${this.x(e.view.endFrame / fr)}px`;
    this.endMark.dataset['value'] = String(e.view.endFrame);
    const xs = this.x(start / fr), xe = this.x(end / fr);
    this.outsideBefore.style.left = '0px';
    this.outsideBefore.style.width = `${Math.max(0, xs)}px`;
    this.outsideAfter.style.left = `${Math.max(0, xe)}px`;
    this.outsideAfter.style.right = '0px';
  }

  private renderTracks() {
    const seen = new Set<string>();
    let index = 0;
    for (const inst of this.editor.instances.values()) {
      seen.add(inst.name);
      const dom = this.trackDom(inst.name);
      // Scene order: move the row when the document's order changed.
      if (this.tracks.children[index] !== dom.row) this.tracks.insertBefore(dom.row, this.tracks.children[index] ?? null);
      index++;
      this.renderTrack(inst, dom);
    }
    for (const [name, dom] of this.trackDoms) {
      if (seen.has(name)) continue;
      dom.row.remove();
      this.trackDoms.delete(name);
    }
  }

  private trackDom(name: string): TrackDom {
    let dom = this.trackDoms.get(name);
    if (dom) return dom;
    const part = (p: string) => ({ 'data-part': p, 'data-instance': name });
    const label = el('span', { className: 'label' });
    const left = el('div', { className: 'handle left', testid: `timeline-begin-${name}`, attrs: part('left'), title: 'Drag: crop where it starts (its end stays)' });
    const right = el('div', { className: 'handle right', testid: `timeline-end-${name}`, attrs: part('right'), title: 'Drag: crop where it ends (its start stays)' });
    const body = el('div', { className: 'track', testid: `timeline-track-${name}`, attrs: part('body') }, [label, left, right]);
    const row = el('div', { className: 'row' }, [body]);
    dom = { row, body, label, left, right, keys: [] };
    this.trackDoms.set(name, dom);
    return dom;
  }

  private renderTrack(inst: InstanceJson, dom: TrackDom) {
    const t = this.timing(inst);
    const body = dom.body;
    body.classList.toggle('selected', this.editor.selected === inst.name);
    body.classList.toggle('reverse', t?.reverse ?? false);
    body.classList.toggle('unknown', t === null);
    body.dataset['selected'] = String(this.editor.selected === inst.name);
    const arrow = t?.reverse ? '◀ ' : '';
    const issue = this.editor.issues.get(inst.name) ?? null;
    body.classList.toggle('warning', issue !== null);
    if (issue) body.dataset['warning'] = issue;
    else delete body.dataset['warning'];
    const text = `${issue ? '⚠ ' : ''}${arrow}${inst.name}`;
    if (dom.label.textContent !== text) dom.label.textContent = text;
    if (!t) {
      // Template not listed (yet, or missing): no length to draw or crop.
      body.style.left = `${this.x(inst.start ?? 0)}px`;
      body.style.width = '60px';
      body.title = `${inst.name}: template ${inst.template} is not known to the server's template list`;
      delete body.dataset['start'];
      delete body.dataset['end'];
      this.renderKeys(inst, dom);
      return;
    }
    const end = sceneEnd(t);
    const a = this.x(t.start), b = this.x(end);
    body.style.left = `${a}px`;
    body.style.width = `${Math.max(2, b - a)}px`;
    // The label stays readable when the track starts left of the view.
    dom.label.style.paddingLeft = `${Math.max(0, -a) + 6}px`;
    body.dataset['start'] = String(t.start);
    body.dataset['end'] = String(end);
    body.title =
      `${inst.name} (${inst.template}): scene ${t.start.toFixed(3)}–${end.toFixed(3)} s plays template ` +
      `${t.reverse ? `${t.end.toFixed(3)} → ${t.begin.toFixed(3)}` : `${t.begin.toFixed(3)} → ${t.end.toFixed(3)}`} s` +
      `${t.speed !== 1 ? ` at ${t.speed}×` : ''}${t.reverse ? ', reversed' : ''}. Drag to move; drag an end to crop` +
      `${issue ? `\n⚠ ${inst.name} ${issue}` : ''}`;
    this.renderKeys(inst, dom);
  }

  /** Diamonds at the transform keys' scene times, when the track has more than one (a single key is a placement, not a motion). */
  private renderKeys(inst: InstanceJson, dom: TrackDom) {
    const keys = inst.transform ?? [];
    const times = keys.length > 1 ? keys.map((k) => k.time ?? 0) : [];
    const kf = this.keyFlight;
    if (kf && kf.instance === inst.name && kf.index < times.length) times[kf.index] = kf.time; // the drag's preview
    while (dom.keys.length > times.length) dom.keys.pop()!.remove();
    for (let k = 0; k < times.length; k++) {
      let d = dom.keys[k];
      if (!d) {
        d = el('div', { className: 'key', testid: `timeline-key-${inst.name}-${k}`, attrs: { 'data-part': 'key', 'data-instance': inst.name, 'data-index': String(k) } });
        dom.keys.push(d);
        dom.row.append(d);
      }
      d.style.left = `${this.x(times[k]!)}px`;
      d.dataset['value'] = String(times[k]);
      const fr = this.sceneFrameRate();
      d.title = `${inst.name}: transform key ${k} at frame ${Math.round(times[k]! * fr)} (${times[k]!.toFixed(3)} s). Drag to move it in time`;
    }
  }

  private renderPlayhead() {
    const e = this.editor, fr = this.sceneFrameRate();
    const hasSession = e.session !== null;
    const frame = e.playheadFrame, live = e.view.live && !e.offRecord;
    this.playhead.hidden = !hasSession;
    this.playhead.style.left = `${this.x(frame / fr)}px`;
    this.playhead.classList.toggle('replay', !live && !e.offRecord);
    this.playhead.classList.toggle('off-record', e.offRecord);
    this.playhead.dataset['value'] = String(frame);
    this.playhead.dataset['live'] = String(live);
    this.playhead.dataset['recorded'] = String(!e.offRecord);
    const where = e.offRecord ? 'not simulated' : live ? 'live' : 'replay';
    const text = hasSession
      ? this.units === 'frames'
        ? `frame ${frame} / ${e.view.endFrame} · ${where}`
        : `${(frame / fr).toFixed(3)} s · frame ${frame} · ${where}`
      : '';
    if (this.readout.textContent !== text) this.readout.textContent = text;
    this.readout.classList.toggle('replay', !live);
    this.readout.title = e.offRecord
      ? 'Nothing is recorded at the playhead: the instances are drawn from their tracks; Play simulates up to it'
      : live
        ? 'The viewport shows the newest simulated frame'
        : 'The viewport shows a recorded frame; Live shows the newest, Play plays on from here';
  }
}

function readUnits(): TimeUnits {
  try {
    return localStorage.getItem('flowclip-time-units') === 'seconds' ? 'seconds' : 'frames';
  } catch {
    return 'frames';
  }
}

function clamp(x: number, lo: number, hi: number): number {
  return Math.min(hi, Math.max(lo, x));
}
