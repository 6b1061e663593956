// The editor's hub (the three.js editor's Editor): it owns the REST client,
// the session's stream and frame decoder, the undo history and the current
// document (scene, instances), and announces every change through typed
// signals. Panels only listen to signals and call the hub's methods (or
// execute Commands through it); they never talk to each other or the server.
import { Api, ApiError } from '../net/Api';
import { FrameDecoder, type FrameInfo } from '../net/FrameDecoder';
import { Stream, type ConnectionStatus, type StreamState } from '../net/Stream';
import { Layer } from '@wire';
import type {
  EditJson, InstanceEditResponse, InstanceJson, ParametersJson, PresetsJson, SceneJson, SceneSummary, SessionState, SessionStatusName,
  SettingsPatch, TemplateInfo, TransportName,
} from '../net/types';
import { AddInstanceCommand } from '../commands/AddInstanceCommand';
import type { Command } from './Command';
import { History } from './History';
import { Signal } from './Signal';

export interface SessionInfo {
  id: string;
  scene: string;
  dimension: 2 | 3;
  sceneJson: SceneJson | null;
  /** Created by this editor (deleted when another scene is opened or the page closes). */
  owned: boolean;
}

/** What the transport shows: from REST answers and StateChange messages, newest wins. */
export interface SessionView {
  status: SessionStatusName;
  frame: number;
  time: number;
  shownFrame: number;
  live: boolean;
  playbackSpeed: number;
  historyFirst: number;
  historyLast: number;
  errorMessage: string;
}

/** What the viewport shows: liquid (client side only) and the stream's optional layers (Layer flags). */
export interface LayerToggles {
  liquid: boolean;
  control: boolean;
  repulsion: boolean;
  boundary: boolean;
  /** Liquid coloured by speed (Layer.Speed) instead of its phase colour. */
  speed: boolean;
}

export type MessageLevel = 'error' | 'warning' | 'info';

export interface UserMessage {
  level: MessageLevel;
  text: string;
}

export class Editor {
  readonly api: Api;
  readonly history = new History();
  readonly decoder = new FrameDecoder();

  readonly signals = {
    scenesChanged: new Signal<SceneSummary[]>(),
    templatesChanged: new Signal<TemplateInfo[]>(),
    /** The parameter declarations for the session's dimension arrived (GET /api/parameters). */
    parametersChanged: new Signal<ParametersJson | null>(),
    /** The accuracy presets arrived (GET /api/presets). */
    presetsChanged: new Signal<PresetsJson>(),
    /** The session's scene JSON changed (settings edits re-read it). */
    sceneChanged: new Signal<SceneJson | null>(),
    /** The selected instance's name (null: none). Outliner, inspector, gizmo and timeline follow it. */
    selectionChanged: new Signal<string | null>(),
    /** A session was opened (or closed: null). */
    sessionChanged: new Signal<SessionInfo | null>(),
    sessionView: new Signal<SessionView>(),
    /** The frame shown changed (the playhead): scene time playheadTime(). */
    playheadChanged: new Signal<number>(),
    /** A frame was decoded into the particle buffers (the FrameInfo object is reused). */
    frameDecoded: new Signal<FrameInfo>(),
    connection: new Signal<{ status: ConnectionStatus; attempt: number; retryInMs: number }>(),
    instancesChanged: new Signal<ReadonlyMap<string, InstanceJson>>(),
    historyChanged: new Signal<void>(),
    /** The layer toggles changed (the stream was re-subscribed). */
    layersChanged: new Signal<LayerToggles>(),
    /** GET /api/health's rss_mb, polled every 2 s while the stream is open. */
    serverMemory: new Signal<number>(),
    /** Something for the user to read (errors are never only logged). */
    message: new Signal<UserMessage>(),
  };

  scenes: SceneSummary[] = [];
  templates: TemplateInfo[] = [];
  /** Parameter declarations for the open session's dimension (null until read). */
  parameters: ParametersJson | null = null;
  private readonly parameterCache = new Map<number, ParametersJson>();
  /** The accuracy study's presets with their measured figures (none until read, or without a study). */
  presets: PresetsJson = { presets: [], source: null };
  /** World point at the centre of the view (the viewport keeps it current): where a new instance goes. */
  viewCentre: number[] = [0.5, 0.5, 0];
  /** The selected instance (a name in `instances`) or null. */
  selected: string | null = null;
  session: SessionInfo | null = null;
  view: SessionView = emptyView();
  readonly instances = new Map<string, InstanceJson>();
  stream: Stream | null = null;
  /** Frames per wall second the stream sends at most (0: no limit). */
  maxFrameRate = 30;
  readonly layers: LayerToggles = { liquid: true, control: false, repulsion: false, boundary: false, speed: false };
  private healthTimer: ReturnType<typeof setInterval> | null = null;
  /** The frame the viewport shows (from the decoded frames, which are newer than any REST answer). */
  private shownFrame = 0;
  /** Instance names of adds still in flight (two quick adds get two names). */
  private readonly reservedNames = new Set<string>();
  /** Bumped by each openScene / attachSession: a slower earlier one gives up. */
  private openSeq = 0;

  constructor(api = new Api('', tokenFromPage())) {
    this.api = api;
    this.history.changed.add(() => this.signals.historyChanged.dispatch());
    this.history.failed.add(({ command, error, phase }) =>
      this.reportError(error, `${phase === 'execute' ? '' : phase + ' '}${command.name}`),
    );
  }

  // ------------------------------------------------------------- scenes ---

  async loadScenes(): Promise<SceneSummary[]> {
    try {
      this.scenes = await this.api.listScenes();
    } catch (e) {
      this.reportError(e, 'list scenes');
      this.scenes = [];
    }
    this.signals.scenesChanged.dispatch(this.scenes);
    return this.scenes;
  }

  async loadTemplates(): Promise<TemplateInfo[]> {
    try {
      this.templates = await this.api.listTemplates();
    } catch (e) {
      this.reportError(e, 'list templates');
      this.templates = [];
    }
    this.signals.templatesChanged.dispatch(this.templates);
    return this.templates;
  }

  async loadPresets(): Promise<PresetsJson> {
    try {
      this.presets = await this.api.presets();
    } catch (e) {
      this.reportError(e, 'read the accuracy presets');
    }
    this.signals.presetsChanged.dispatch(this.presets);
    return this.presets;
  }

  async loadParameters(dimension: 2 | 3): Promise<ParametersJson | null> {
    let p = this.parameterCache.get(dimension) ?? null;
    if (!p) {
      try {
        p = await this.api.parameters(dimension);
        this.parameterCache.set(dimension, p);
      } catch (e) {
        this.reportError(e, 'read the parameter declarations');
      }
    }
    if (this.session?.dimension === dimension) {
      this.parameters = p;
      this.signals.parametersChanged.dispatch(p);
    }
    return p;
  }

  /** Creates a session of scene `name` and streams it (the previous session, if ours, is deleted). */
  async openScene(name: string): Promise<SessionInfo | null> {
    const seq = ++this.openSeq;
    let state: SessionState;
    try {
      state = await this.api.createSession(name);
    } catch (e) {
      if (seq === this.openSeq) this.reportError(e, `open scene ${name}`);
      return null;
    }
    if (seq !== this.openSeq) {
      // Another scene was picked meanwhile: this session is nobody's.
      void this.api.deleteSession(state.id).catch(() => undefined);
      return null;
    }
    await this.closeSession();
    return this.attach(state, name, true, seq);
  }

  /** Streams an existing session (not deleted when the editor leaves it). */
  async attachSession(id: string): Promise<SessionInfo | null> {
    const seq = ++this.openSeq;
    let state: SessionState;
    try {
      state = await this.api.getSession(id);
    } catch (e) {
      if (seq === this.openSeq) this.reportError(e, `attach to session ${id}`);
      return null;
    }
    if (seq !== this.openSeq) return null;
    await this.closeSession();
    return this.attach(state, state.name, false, seq);
  }

  async closeSession(): Promise<void> {
    const s = this.session;
    if (!s) return;
    this.stream?.close();
    this.stream = null;
    this.pollHealth(false);
    this.session = null;
    this.parameters = null;
    this.instances.clear();
    this.select(null);
    this.history.clear();
    this.view = emptyView();
    this.signals.sessionChanged.dispatch(null);
    if (s.owned) {
      try {
        await this.api.deleteSession(s.id);
      } catch (e) {
        if (!(e instanceof ApiError && e.status === 404)) this.reportError(e, `delete session ${s.id}`);
      }
    }
  }

  private async attach(state: SessionState, scene: string, owned: boolean, seq: number): Promise<SessionInfo | null> {
    let sceneJson: SceneJson | null = null;
    try {
      sceneJson = await this.api.getSessionScene(state.id);
    } catch (e) {
      this.reportError(e, 'read the session scene');
    }
    let instances = sceneJson?.instances ?? [];
    try {
      instances = await this.api.listInstances(state.id); // every key, defaults written
    } catch (e) {
      this.reportError(e, 'list instances');
    }
    if (seq !== this.openSeq) {
      if (owned) void this.api.deleteSession(state.id).catch(() => undefined);
      return null;
    }
    const info: SessionInfo = { id: state.id, scene, dimension: state.dimension, sceneJson, owned };
    this.session = info;
    this.history.clear();
    this.shownFrame = state.shown.frame;
    this.setInstances(instances);
    this.applyState(state);
    this.signals.sessionChanged.dispatch(info);
    void this.loadParameters(state.dimension);
    // Moving bodies are boundary particles: show them in scenes that have some.
    const bodies = sceneJson?.['bodies'];
    if (Array.isArray(bodies) && bodies.length > 0 && !this.layers.boundary) this.setLayers({ boundary: true });
    this.connectStream(info);
    return info;
  }

  // ------------------------------------------------------------- layers ---

  /** The stream's Layer flags for the toggles (Instances always). */
  layerFlags(): Layer {
    const l = this.layers;
    return (Layer.Instances | (l.control ? Layer.Control : 0) | (l.repulsion ? Layer.Repulsion : 0) |
      (l.boundary ? Layer.Boundary : 0) | (l.speed ? Layer.Speed : 0)) as Layer;
  }

  /** Changes layer toggles; the stream is re-subscribed when its flags change (the server resends the frame). */
  setLayers(change: Partial<LayerToggles>) {
    const before = this.layerFlags();
    Object.assign(this.layers, change);
    this.decoder.colorBySpeed = this.layers.speed;
    const flags = this.layerFlags();
    if (flags !== before && this.stream) {
      try {
        this.stream.subscribe(this.maxFrameRate, flags);
      } catch {
        // Not connected: kept by the stream and sent when it (re)connects.
      }
    }
    this.signals.layersChanged.dispatch(this.layers);
  }

  private pollHealth(on: boolean) {
    if (!on) {
      if (this.healthTimer) clearInterval(this.healthTimer);
      this.healthTimer = null;
      return;
    }
    if (this.healthTimer) return;
    const poll = () => {
      this.api.health().then(
        (h) => {
          if (typeof h.rss_mb === 'number') this.signals.serverMemory.dispatch(h.rss_mb);
        },
        () => undefined, // the stream reports a lost server
      );
    };
    poll();
    this.healthTimer = setInterval(poll, 2000);
  }

  private connectStream(info: SessionInfo) {
    const stream = new Stream(info.id, this.decoder, {
      token: this.api.token, maxFrameRate: this.maxFrameRate, layers: this.layerFlags(),
    });
    this.stream = stream;
    stream.frame.add((f) => {
      if (f.frame !== this.shownFrame && this.stream === stream) {
        this.shownFrame = f.frame;
        this.signals.playheadChanged.dispatch(this.playheadTime());
      }
      this.signals.frameDecoded.dispatch(f);
    });
    stream.state.add((s) => this.applyStreamState(s));
    stream.error.add((e) => this.message('error', `server: ${e.message} (${e.codeName})`));
    let lost = false;
    stream.connection.add((c) => {
      this.signals.connection.dispatch(c);
      this.pollHealth(c.status === 'open');
      if (c.status === 'reconnecting' && !lost) {
        lost = true;
        this.message('warning', 'connection to the server lost; reconnecting…');
      } else if (c.status === 'open' && lost) {
        lost = false;
        this.message('info', 'reconnected');
        void this.resync();
      }
    });
    stream.connect();
  }

  /** Re-reads the session after a lost connection (the stream itself restarts with state and frame). */
  async resync(): Promise<void> {
    const s = this.session;
    if (!s) return;
    try {
      this.applyState(await this.api.getSession(s.id));
      this.setInstances(await this.api.listInstances(s.id));
    } catch (e) {
      if (e instanceof ApiError && e.status === 404) {
        this.message('error', `session ${s.id} no longer exists on the server; open a scene again`);
        this.stream?.close();
        this.stream = null;
        this.pollHealth(false);
        return;
      }
      this.reportError(e, 'resync');
    }
  }

  // ---------------------------------------------------------- transport ---

  async transport(command: TransportName, args: { frames?: number; frame?: number; speed?: number } = {}) {
    const s = this.session;
    if (!s) {
      this.message('warning', 'open a scene first');
      return;
    }
    // The stream's StateChange messages are newer than a REST answer that
    // arrives after them: the answer is applied only if none came meanwhile.
    const seq = this.streamStates;
    try {
      const state = await this.api.transport(s.id, command, args);
      if (this.streamStates === seq) this.applyState(state);
    } catch (e) {
      this.reportError(e, command);
    }
  }

  // ----------------------------------------------------------- document ---

  setInstances(list: InstanceJson[]) {
    this.instances.clear();
    for (const i of list) this.instances.set(i.name, i);
    this.signals.instancesChanged.dispatch(this.instances);
    if (this.selected !== null && !this.instances.has(this.selected)) this.select(null);
  }

  /** Selects an instance by name (null: none); unknown names select nothing. */
  select(name: string | null) {
    const next = name !== null && this.instances.has(name) ? name : null;
    if (next === this.selected) return;
    this.selected = next;
    this.signals.selectionChanged.dispatch(next);
  }

  /**
   * The instance after an accepted edit. A session inside a long frame
   * answers 202 (pending): the edit is polled until it is applied, then the
   * instance is read; a rejected edit throws like a 422.
   */
  async settleInstanceEdit(sid: string, name: string, res: InstanceEditResponse): Promise<InstanceJson> {
    if (res.instance) return res.instance;
    await this.settleEdit(sid, res.edit);
    return this.api.getInstance(sid, name);
  }

  /** Waits for a pending edit (HTTP 202) to be applied; a rejected one throws like a 422. */
  async settleEdit(sid: string, edit: EditJson): Promise<void> {
    if (edit.accepted === true) return;
    if (edit.accepted === false) throw new ApiError(422, 'unprocessable', edit.error?.message ?? 'edit rejected', edit.error?.path);
    const deadline = performance.now() + 60_000;
    for (;;) {
      const r = await this.api.getEdit(sid, edit.id);
      const e = r.edit ?? r;
      if (e.accepted === false) throw new ApiError(422, 'unprocessable', e.error?.message ?? 'edit rejected', e.error?.path);
      if (e.accepted === true) return;
      if (performance.now() > deadline) throw new Error(`edit ${edit.id} still pending after 60 s`);
      await new Promise((resolve) => setTimeout(resolve, 100));
    }
  }

  /** The session a command was made in, if it is still the open one (else it must not run). */
  sessionFor(sid: string): string {
    if (!sid) throw new Error('no session is open');
    if (this.session?.id !== sid) throw new Error(`session ${sid} is no longer open`);
    return sid;
  }

  /** Scene time of the frame shown (frame n ends at n / frame_rate): the playhead. */
  playheadTime(): number {
    return this.shownFrame / this.frameRate();
  }

  frameRate(): number {
    const fr = (this.session?.sceneJson?.['settings'] as { frame_rate?: number } | undefined)?.frame_rate;
    return typeof fr === 'number' && fr > 0 ? fr : 60;
  }

  templateInfo(name: string): TemplateInfo | undefined {
    return this.templates.find((t) => t.name === name);
  }

  /** The template's capture-region centre (where an empty transform track plays it). */
  templateCentre(name: string): number[] {
    const t = this.templateInfo(name);
    const mn = t?.region_min ?? [0, 0, 0], mx = t?.region_max ?? [0, 0, 0];
    return mn.map((v, d) => (v + (mx[d] ?? v)) / 2);
  }

  /** `base`, or base_2, base_3, … : a name no instance has (names follow [A-Za-z0-9_-]{1,64}). */
  uniqueInstanceName(base: string): string {
    const clean = base.replace(/[^A-Za-z0-9_-]/g, '_').slice(0, 56) || 'instance';
    const taken = (n: string) => this.instances.has(n) || this.reservedNames.has(n);
    let name = clean;
    for (let k = 2; taken(name); k++) name = `${clean}_${k}`;
    this.reservedNames.add(name);
    return name;
  }

  releaseName(name: string) {
    this.reservedNames.delete(name);
  }

  /**
   * Instances `template` with its region centre at `position` (world; the
   * view centre by default), starting at the playhead so that it plays from
   * the frame the user looks at.
   */
  addInstance(template: string, position: number[] = this.viewCentre): Promise<void> {
    const s = this.session;
    if (!s) {
      this.message('warning', 'open a scene first');
      return Promise.resolve();
    }
    const t = this.templateInfo(template);
    if (t?.dimension !== undefined && t.dimension !== s.dimension) {
      this.message('error', `template ${template} is ${t.dimension}D; the scene is ${s.dimension}D`);
      return Promise.resolve();
    }
    const name = this.uniqueInstanceName(template);
    const translation = position.slice(0, s.dimension).map((v) => Math.round(v * 1e4) / 1e4);
    const start = Math.round(this.playheadTime() * 1e4) / 1e4;
    return this.execute(new AddInstanceCommand(this, { name, template, start, transform: [{ time: start, translation }] }));
  }

  /** PATCHes the scene settings and re-reads the session's scene (the inspector shows it). */
  async applySettings(patch: SettingsPatch, sid: string): Promise<void> {
    const s = this.sessionFor(sid);
    const res = await this.api.patchSettings(s, patch);
    await this.settleEdit(s, res.edit);
    if (this.session?.id === s) await this.refreshScene();
  }

  async refreshScene(): Promise<void> {
    const s = this.session;
    if (!s) return;
    s.sceneJson = await this.api.getSessionScene(s.id);
    this.signals.sceneChanged.dispatch(s.sceneJson);
  }

  /** Saves the session's current scene as NAME.json on the server (scene directory). */
  async saveScene(name: string, force = false): Promise<boolean> {
    const s = this.session;
    if (!s) {
      this.message('warning', 'open a scene first');
      return false;
    }
    try {
      await this.history.idle(); // edits still queued belong in the file
      const r = await this.api.saveScene(s.id, name, force);
      this.message('info', `saved scene ${r.name} (${r.path})`);
      await this.loadScenes();
      return true;
    } catch (e) {
      this.reportError(e, `save scene ${name}`);
      return false;
    }
  }

  /** The session's current scene JSON (every accepted edit), for a download. */
  async currentSceneJson(): Promise<SceneJson | null> {
    const s = this.session;
    if (!s) return null;
    try {
      await this.history.idle();
      return await this.api.getSessionScene(s.id);
    } catch (e) {
      this.reportError(e, 'read the scene');
      return null;
    }
  }

  /** The server's answer to an instance edit. */
  instanceUpdated(instance: InstanceJson, sid?: string) {
    if (sid !== undefined && sid !== this.session?.id) return; // an answer for a session since closed
    this.instances.set(instance.name, instance);
    this.signals.instancesChanged.dispatch(this.instances);
  }

  instanceRemoved(name: string, sid?: string) {
    if (sid !== undefined && sid !== this.session?.id) return;
    this.instances.delete(name);
    this.signals.instancesChanged.dispatch(this.instances);
    if (this.selected === name) this.select(null);
  }

  // ------------------------------------------------------------ history ---

  execute(cmd: Command): Promise<void> {
    return this.history.execute(cmd);
  }
  undo(): Promise<void> {
    return this.history.undo();
  }
  redo(): Promise<void> {
    return this.history.redo();
  }

  /** The session id, or an error for commands issued without one. */
  requireSession(): string {
    if (!this.session) throw new Error('no session is open');
    return this.session.id;
  }

  // ----------------------------------------------------------- messages ---

  message(level: MessageLevel, text: string) {
    this.signals.message.dispatch({ level, text });
  }

  reportError(e: unknown, context: string) {
    const text = e instanceof ApiError ? e.describe() : e instanceof Error ? e.message : String(e);
    this.message('error', context ? `${context}: ${text}` : text);
  }

  // -------------------------------------------------------------- state ---

  private applyState(s: SessionState) {
    this.view = {
      status: s.status,
      frame: s.frame,
      time: s.time,
      shownFrame: s.shown.frame,
      live: s.shown.live,
      playbackSpeed: s.playback_speed,
      historyFirst: s.history.first ?? 0,
      historyLast: s.history.last ?? 0,
      errorMessage: s.error?.message ?? '',
    };
    this.signals.sessionView.dispatch(this.view);
  }

  /** StateChange messages received (REST answers older than the newest are not applied). */
  private streamStates = 0;

  private applyStreamState(s: StreamState) {
    this.streamStates++;
    if (s.state) {
      this.applyState(s.state);
      return;
    }
    const wasError = this.view.status === 'error';
    this.view = {
      status: s.status,
      frame: s.frame,
      time: s.time,
      shownFrame: s.shownFrame,
      live: s.live,
      playbackSpeed: s.playbackSpeed,
      historyFirst: s.historyFirst,
      historyLast: s.historyLast,
      errorMessage: s.message,
    };
    if (s.status === 'error' && !wasError) this.message('error', `simulation stopped: ${s.message}`);
    this.signals.sessionView.dispatch(this.view);
  }
}

function emptyView(): SessionView {
  return {
    status: 'paused', frame: 0, time: 0, shownFrame: 0, live: true, playbackSpeed: 0,
    historyFirst: 0, historyLast: 0, errorMessage: '',
  };
}

/** `?token=T` in the page's URL (a server started with --token), kept for the tab. */
function tokenFromPage(): string | null {
  if (typeof location === 'undefined') return null;
  const t = new URLSearchParams(location.search).get('token');
  if (t) sessionStorage.setItem('flowclip-token', t);
  return t ?? sessionStorage.getItem('flowclip-token');
}
