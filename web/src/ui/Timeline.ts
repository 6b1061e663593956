// The timeline (under the viewport): a ruler in scene seconds with the
// simulated range (the server's replay history) shaded and a playhead at the
// frame shown, and one track per instance (scene order) over the scene time
// it is active. Tracks select their instance, move (body) and crop (ends);
// the ruler scrubs through the history (seek). Wheel zooms around the
// cursor, Shift+wheel or dragging the empty background pans.
//
// It listens to the hub's signals and acts only through it: edits are
// SetInstanceValuesCommands (one history entry per drag), scrubbing is
// editor.transport('seek'). It renders on demand (one animation frame after
// something changed), never in a loop. Plain DOM: tests find the parts by
// data-testid and read data-* values.
import './timeline.css';
import type { Editor } from '../core/Editor';
import type { InstanceJson, TemplateInfo } from '../net/types';
import { SetInstanceValuesCommand, type InstanceValues } from '../commands/SetInstanceValuesCommand';
import { el } from './dom';
import { dragValues, keysOf, sceneEnd, tickStep, timingOf, withValues, type DragPart, type Timing } from './TimelineModel';

const RULER_HEIGHT = 22;
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
  | { kind: 'scrub'; pointerId: number };

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
  private readonly tracks: HTMLElement;
  private readonly playhead: HTMLElement;
  private readonly readout: HTMLElement;
  private readonly hint: HTMLElement;
  private readonly trackDoms = new Map<string, TrackDom>();

  /** Scene time at the left edge, s, and the zoom. */
  private viewStart = 0;
  private pxPerSecond = 100;
  /** Fit the view to the content at the next render that can (set when a session opens). */
  private fitPending = true;
  private width = 0;

  /**
   * The playhead: the frame the viewport shows. The decoded frames are the
   * truth (a REST answer can arrive after the stream's newer frames and state,
   * e.g. a step's answer after the stepped frame); the session view gives it
   * until the session's first frame arrives, and the pointer while scrubbing.
   */
  private shownFrame = 0;
  private frameArrived = false;
  /** Live or replay, and the replay history's range, from REST and StateChange. */
  private live = true;
  private historyFirst = 0;
  private historyLast = 0;
  /** The newest live frame decoded (the history reaches it even if a late REST answer says less). */
  private newestLiveFrame = 0;

  private drag: Drag | null = null;
  private flight: EditFlight | null = null;
  /** Scrubbing: the frame to seek next (latest wins) while one seek is in flight. */
  private seekWanted: number | null = null;
  /** The frame the pointer last asked for (the playhead shows it until the seeks are answered). */
  private scrubFrame: number | null = null;
  private seeking = false;

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
      title: 'Simulated range (the replay history on the server): drag here to scrub',
    });
    this.readout = el('span', { className: 'readout', testid: 'timeline-readout' });
    const fit = el('button', { className: 'fit', testid: 'timeline-fit', text: 'fit', title: 'Fit the view to the instances and the simulated range', attrs: { type: 'button' } });
    fit.addEventListener('click', () => this.fitView());
    this.ruler = el('div', {
      className: 'ruler', testid: 'timeline-ruler',
      title: 'Scene time, s. Press or drag to show a recorded frame (seek); the newest frame is live',
    }, [this.simulated, this.ticks]);
    this.tracks = el('div', { className: 'tracks', testid: 'timeline-tracks' });
    this.hint = el('div', { className: 'hint', text: 'open a scene to see its instances' });
    this.playhead = el('div', { className: 'playhead', testid: 'timeline-playhead', attrs: { 'data-value': '0' } });
    this.dom = el('div', { className: 'timeline', testid: 'timeline', attrs: { 'data-pending': 'false' } }, [
      this.ruler, this.tracks, this.hint, this.playhead, el('div', { className: 'corner' }, [this.readout, fit]),
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
      this.seekWanted = null;
      this.frameArrived = false;
      this.newestLiveFrame = 0;
      this.updatePending();
      this.fitPending = info !== null;
      this.readView();
      this.requestRender();
    });
    s.sessionView.add(() => {
      this.readView();
      this.requestRender();
    });
    s.frameDecoded.add((f) => {
      // StateChange messages come with status changes only: while playing,
      // the frames themselves move the playhead and grow the history.
      if (f.sessionId !== this.editor.session?.id) return;
      this.frameArrived = true;
      if (this.live) this.newestLiveFrame = Math.max(this.newestLiveFrame, f.frame);
      const last = Math.max(this.historyLast, this.newestLiveFrame);
      const shown = this.seeking && this.scrubFrame !== null ? this.scrubFrame : f.frame;
      if (shown === this.shownFrame && last === this.historyLast) return;
      this.shownFrame = shown;
      this.historyLast = last;
      this.requestRender('playhead');
    });
  }

  // -------------------------------------------------------------- state ---

  private readView() {
    const v = this.editor.view;
    if (!this.frameArrived) this.shownFrame = v.shownFrame;
    this.live = v.live;
    // Frame 0 with nothing after it: a reset (or a new session) cleared the history.
    if (v.frame === 0 && v.historyLast === 0) this.newestLiveFrame = 0;
    this.historyFirst = v.historyFirst;
    this.historyLast = Math.max(v.historyLast, this.newestLiveFrame);
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
    let end = this.historyLast / this.sceneFrameRate();
    const sceneDuration = this.editor.session?.sceneJson?.['duration'];
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
    if (target.closest('.ruler')) {
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
      const timing0 = this.timing(inst);
      // A key diamond only selects; no length to drag while the template is
      // unknown; and the previous drag's last PATCH lands first (its values
      // are this drag's old values, and one flight at a time keeps them in order).
      if (partName === 'key' || !timing0 || this.flight) return;
      const dragPart: DragPart = partName === 'left' ? 'left' : partName === 'right' ? 'right' : 'body';
      const old: InstanceValues = {};
      for (const k of keysOf(dragPart, timing0.reverse)) old[k] = inst[k];
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
    if (!d.moved && Math.abs(e.clientX - d.x0) < DRAG_THRESHOLD_PX) return;
    d.moved = true;
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
    this.dom.dataset['pending'] = String(this.flight !== null || this.seeking);
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

  /** Seeks the recorded frame nearest the pointer (within the history); the playhead follows at once. */
  private scrubTo(clientX: number) {
    const frame = clamp(Math.round(this.timeAt(clientX) * this.sceneFrameRate()), this.historyFirst, this.historyLast);
    if (frame !== this.shownFrame || this.live) {
      this.shownFrame = frame;
      this.requestRender('playhead');
    }
    this.seekWanted = frame;
    this.scrubFrame = frame;
    if (!this.seeking) void this.pumpSeeks();
  }

  private async pumpSeeks() {
    this.seeking = true;
    this.updatePending();
    let sent: number | null = null;
    while (this.seekWanted !== null) {
      const frame = this.seekWanted;
      this.seekWanted = null;
      if (frame === sent) continue;
      const v = this.editor.view;
      if (sent === null && !v.live && v.shownFrame === frame) continue; // already shown
      sent = frame;
      await this.editor.transport('seek', { frame }); // its errors are reported by the hub
    }
    this.seeking = false;
    this.scrubFrame = null;
    this.updatePending();
    // The last seek's frame is on its way to the viewport; a refused seek
    // leaves the playhead on the frame the viewport shows.
    const decoded = this.editor.decoder.info;
    if (sent !== null && this.editor.view.shownFrame === sent) this.shownFrame = sent;
    else if (this.frameArrived && decoded.sessionId === this.editor.session?.id) this.shownFrame = decoded.frame;
    this.readView();
    this.requestRender();
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

  private renderRuler() {
    const fr = this.sceneFrameRate();
    const step = tickStep(this.pxPerSecond, 64);
    const minor = step / (String(step).startsWith('2') ? 4 : 5);
    const t0 = this.viewStart, t1 = this.viewStart + this.width / this.pxPerSecond;
    const decimals = Math.max(0, -Math.floor(Math.log10(step) + 1e-9));
    const nodes: HTMLElement[] = [];
    for (let i = Math.ceil(t0 / minor); i * minor <= t1; i++) {
      const t = i * minor;
      const major = Math.abs(t / step - Math.round(t / step)) < 1e-6;
      const tick = el('div', { className: major ? 'tick major' : 'tick' });
      tick.style.left = `${this.x(t)}px`;
      if (major) tick.append(el('span', { text: `${t.toFixed(decimals)}s` }));
      nodes.push(tick);
    }
    this.ticks.replaceChildren(...nodes);
    this.renderSimulated();
  }

  private renderSimulated() {
    const fr = this.sceneFrameRate();
    const hasSession = this.editor.session !== null;
    this.simulated.hidden = !hasSession;
    const a = this.x(this.historyFirst / fr), b = this.x(this.historyLast / fr);
    this.simulated.style.left = `${a}px`;
    this.simulated.style.width = `${Math.max(2, b - a)}px`;
    this.simulated.dataset['first'] = String(this.historyFirst);
    this.simulated.dataset['last'] = String(this.historyLast);
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
    const text = `${arrow}${inst.name}`;
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
      `${t.speed !== 1 ? ` at ${t.speed}×` : ''}${t.reverse ? ', reversed' : ''}. Drag to move; drag an end to crop`;
    this.renderKeys(inst, dom);
  }

  /** Diamonds at the transform keys' scene times, when the track has more than one (a single key is a placement, not a motion). */
  private renderKeys(inst: InstanceJson, dom: TrackDom) {
    const keys = inst.transform ?? [];
    const times = keys.length > 1 ? keys.map((k) => k.time ?? 0) : [];
    while (dom.keys.length > times.length) dom.keys.pop()!.remove();
    for (let k = 0; k < times.length; k++) {
      let d = dom.keys[k];
      if (!d) {
        d = el('div', { className: 'key', testid: `timeline-key-${inst.name}-${k}`, attrs: { 'data-part': 'key', 'data-instance': inst.name } });
        dom.keys.push(d);
        dom.row.append(d);
      }
      d.style.left = `${this.x(times[k]!)}px`;
      d.dataset['value'] = String(times[k]);
      d.title = `${inst.name}: transform key ${k} at ${times[k]!.toFixed(3)} s`;
    }
  }

  private renderPlayhead() {
    const fr = this.sceneFrameRate();
    const hasSession = this.editor.session !== null;
    this.playhead.hidden = !hasSession;
    this.playhead.style.left = `${this.x(this.shownFrame / fr)}px`;
    this.playhead.classList.toggle('replay', !this.live);
    this.playhead.dataset['value'] = String(this.shownFrame);
    this.playhead.dataset['live'] = String(this.live);
    const text = hasSession
      ? `frame ${this.shownFrame} · ${(this.shownFrame / fr).toFixed(3)} s · ${this.live ? 'live' : 'replay'}`
      : '';
    if (this.readout.textContent !== text) this.readout.textContent = text;
    this.readout.classList.toggle('replay', !this.live);
    this.readout.title = this.live
      ? 'The viewport shows the newest simulated frame'
      : 'The viewport shows a recorded frame; scrub to the end of the simulated range (or Live) to see the newest frame, play or step to simulate on';
  }
}

function clamp(x: number, lo: number, hi: number): number {
  return Math.min(hi, Math.max(lo, x));
}
