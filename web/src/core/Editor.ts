// The editor's hub (the three.js editor's Editor): it owns the REST client,
// the session's stream and frame decoder, the undo history and the current
// document (scene, instances), and announces every change through typed
// signals. Panels only listen to signals and call the hub's methods (or
// execute Commands through it); they never talk to each other or the server.
// Long because the hub is the one place that owns the editor's state.
import { Api, ApiError } from '../net/Api';
import { FrameDecoder, type FrameInfo } from '../net/FrameDecoder';
import { Stream, type ConnectionStatus, type StreamState } from '../net/Stream';
import { Layer } from '@wire';
import type {
  EditJson, EditPendingJson, InstanceEditResponse, InstanceJson, ParametersJson, PresetsJson, RecipeInfo, RecipeJob, RenderJob, RenderJobRequest, SceneJson,
  SceneSummary, SessionState, SurfaceJob,
  SessionStatusName, SettingsPatch, TemplateInfo, TransportArgs, TransportName,
} from '../net/types';
import { AddInstanceCommand } from '../commands/AddInstanceCommand';
import type { Command } from './Command';
import { History } from './History';
import { RecipeRecorder } from './RecipeRecorder';
import { Signal } from './Signal';

export interface SessionInfo {
  id: string;
  scene: string;
  dimension: 2 | 3;
  sceneJson: SceneJson | null;
  /** Created by this editor (deleted when another scene is opened or the page closes). */
  owned: boolean;
}

/** Frame ranges (inclusive) of the recorded frames against the current scene. */
export interface CacheView {
  /** Recorded and consistent with the scene. */
  valid: [number, number][];
  /** Recorded before an edit that changed them: viewable until re-simulated. */
  stale: [number, number][];
  /** A re-simulation in progress: restored at `from`, running to `to`, now at `frame`. */
  simulating: { from: number; to: number; frame: number } | null;
  checkpoints: number[];
  /** The server reported it (false: derived from the replay history's range). */
  reported: boolean;
}

/** The play range (frames, inclusive): playback stops at `end` or loops back to `start`. */
export interface PlayRange {
  start: number;
  /** null: the scene's end frame. */
  end: number | null;
  loop: boolean;
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
  cache: CacheView;
  /** Where playback stops by default: the scene's duration × frame rate. */
  endFrame: number;
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

/** Whether the server runs render jobs (GET /api/jobs), and where. */
export interface RenderAvailability {
  /** The server has answered (until then nothing is offered). */
  known: boolean;
  available: boolean;
  /** "local (2 workers)" or the Dask scheduler's address. */
  where: string;
  /** Why jobs cannot be submitted (empty when they can). */
  reason: string;
}

/** A render job submitted, or why the server refused it (`path`: the request's key it names). */
export type RenderSubmitResult = { job: RenderJob } | { error: string; path: string | null };

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
    /** The server's recipes were (re-)read (GET /api/recipes). */
    recipesChanged: new Signal<RecipeInfo[]>(),
    /** A recording job this editor follows changed (state, progress). */
    recipeJobChanged: new Signal<RecipeJob>(),
    /** The session's newest surface export job changed (state "export", on the stream). */
    exportJobChanged: new Signal<SurfaceJob | null>(),
    /** The session's render jobs changed (state "jobs", on the stream), oldest first. */
    renderJobsChanged: new Signal<readonly RenderJob[]>(),
    /** GET /api/jobs answered: whether the server runs render jobs, and where. */
    renderAvailabilityChanged: new Signal<RenderAvailability>(),
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
    /** Another scene or session is being opened (the message area clears). */
    sceneOpening: new Signal<void>(),
    /** Instances shown with values not yet confirmed by the server (a drag, an edit in flight). */
    previewChanged: new Signal<void>(),
    /** Instances that steer no liquid when they start, with the reason (name → text). */
    issuesChanged: new Signal<ReadonlyMap<string, string>>(),
    autoKeyChanged: new Signal<boolean>(),
    playRangeChanged: new Signal<PlayRange>(),
    /** Client-side playback (looping over recorded frames) started or stopped; seeks began or ended. */
    playbackChanged: new Signal<void>(),
    /** Ctrl+S: the toolbar saves under its name field. */
    saveRequested: new Signal<void>(),
    /** The Export dialog was asked for (toolbar). */
    exportRequested: new Signal<void>(),
    /** The Render final dialog was asked for (toolbar). */
    renderRequested: new Signal<void>(),
    /** F: the viewport frames the selection. */
    frameSelectionRequested: new Signal<void>(),
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

  /**
   * The playhead, a frame in [0, end frame]: the decoded frame, the frame a
   * seek is bringing, or (offRecord) a frame nothing is recorded at, where the
   * viewport draws the instances from the client's own track evaluation.
   */
  playheadFrame = 0;
  offRecord = false;
  /** The newest frame simulated live (the history reaches it even if a REST answer says less). */
  private newestLiveFrame = 0;
  private frameArrived = false;
  /** Seeks: one in flight, the latest wanted frame next. */
  private seekWanted: number | null = null;
  seeking = false;
  private seekDone: Promise<void> = Promise.resolve();
  /** Auto-key: edits key the transform at the playhead; off: an animated track moves as a whole. */
  autoKey = false;
  playRange: PlayRange = { start: 0, end: null, loop: false };
  /** Client-side playback of recorded frames (loop). */
  private loopTimer: ReturnType<typeof setInterval> | null = null;
  private loopOrigin = { at: 0, frame: 0 };
  /** The frame the current play was asked to stop at (the server's `until`). */
  private playUntil: number | null = null;
  /** Instances shown with unconfirmed values, by name (token: who set it). */
  private readonly previews = new Map<string, { token: number; instance: InstanceJson }>();
  private previewTokens = 0;
  /** Instances that steer no liquid when they start: name → reason. */
  readonly issues = new Map<string, string>();

  /** Recipes and their recording jobs; a recorded template re-reads the templates and scenes. */
  readonly recipes: RecipeRecorder;

  constructor(api = new Api('', tokenFromPage())) {
    this.api = api;
    this.recipes = new RecipeRecorder(api, this.signals, () => Promise.all([this.loadTemplates(), this.loadScenes()]),
      (e, what) => this.reportError(e, what));
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
    this.signals.sceneOpening.dispatch();
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
    this.signals.sceneOpening.dispatch();
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
    this.resetPlayback();
    this.renderJobsInState = new Set();
    this.setRenderJobs([]);
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
    // The scene's instances may leave `name` out (it defaults to the template's).
    let instances: InstanceJson[] = (sceneJson?.instances ?? []).map((i) => ({ ...i, name: i.name ?? i.template }));
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
    this.resetPlayback();
    this.shownFrame = state.shown.frame;
    this.playheadFrame = state.shown.frame;
    this.setInstances(instances);
    this.applyState(state);
    this.signals.sessionChanged.dispatch(info);
    void this.loadParameters(state.dimension);
    // Moving bodies are boundary particles: show them in scenes that have some.
    if ((sceneJson?.bodies?.length ?? 0) > 0 && !this.layers.boundary) this.setLayers({ boundary: true });
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
      if (this.stream !== stream) return;
      this.onFrame(f);
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

  async transport(command: TransportName, args: TransportArgs = {}) {
    const s = this.session;
    if (!s) {
      this.message('warning', 'open a scene first');
      return;
    }
    if (command !== 'speed') {
      // Any transport command takes over from client-side playback and an off-record playhead.
      this.stopLoop();
      if (command !== 'play') this.playUntil = null;
      if (this.offRecord) {
        // Back on the frame the viewport shows (the command's frames move it on from there).
        this.offRecord = false;
        if (this.frameArrived) this.playheadFrame = this.shownFrame;
        this.signals.playheadChanged.dispatch(this.playheadTime());
      }
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
    if ('instance' in res) return res.instance;
    await this.settleEdit(sid, res.edit);
    return this.api.getInstance(sid, name);
  }

  /** Waits for a pending edit (HTTP 202) to be applied; a rejected one throws like a 422. */
  async settleEdit(sid: string, edit: EditJson | EditPendingJson): Promise<void> {
    const settled = (e: EditJson | EditPendingJson): boolean => {
      if (!('accepted' in e)) return false;
      if (!e.accepted) throw new ApiError(422, 'unprocessable', e.error?.message ?? 'edit rejected', e.error?.path);
      return true;
    };
    if (settled(edit)) return;
    const deadline = performance.now() + 60_000;
    for (;;) {
      const r = await this.api.getEdit(sid, edit.id);
      if (settled('edit' in r ? r.edit : r)) return;
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

  /** Scene time of the playhead (frame n ends at n / frame_rate). */
  playheadTime(): number {
    return this.playheadFrame / this.frameRate();
  }

  frameRate(): number {
    const fr = this.session?.sceneJson?.settings?.frame_rate;
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
    const { translation, scale } = fitInDomain(t, s.sceneJson?.domain, position, s.dimension);
    const start = Math.round(this.playheadTime() * 1e4) / 1e4;
    const key = scale < 1 ? { time: start, translation, scale: new Array<number>(s.dimension).fill(scale) } : { time: start, translation };
    return this.execute(new AddInstanceCommand(this, { name, template, start, transform: [key] }));
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
    const old = this.instances.get(instance.name);
    this.instances.set(instance.name, instance);
    // Where it starts or what it holds changed: unknown until frames at its start say again.
    if (old && JSON.stringify(old) !== JSON.stringify(instance)) this.setIssue(instance.name, null);
    this.signals.instancesChanged.dispatch(this.instances);
  }

  instanceRemoved(name: string, sid?: string) {
    if (sid !== undefined && sid !== this.session?.id) return;
    this.instances.delete(name);
    this.setIssue(name, null);
    this.signals.instancesChanged.dispatch(this.instances);
    if (this.selected === name) this.select(null);
  }

  // ------------------------------------------------------------ preview ---

  /**
   * Shows `instance` (values not yet confirmed by the server) in place of the
   * document's until cleared; returns a token for clearPreview (a newer
   * preview of the same instance is not cleared by an older one's owner).
   */
  setPreview(instance: InstanceJson): number {
    const token = ++this.previewTokens;
    this.previews.set(instance.name, { token, instance });
    this.signals.previewChanged.dispatch();
    return token;
  }

  /** Previews a merge patch of an instance (null removes a key); 0 when there is no such instance. */
  previewPatch(name: string, patch: Record<string, unknown>): number {
    const current = this.instances.get(name);
    if (!current) return 0;
    const next: Record<string, unknown> = { ...current };
    for (const [k, v] of Object.entries(patch)) {
      if (v === null) delete next[k];
      else next[k] = structuredClone(v);
    }
    return this.setPreview(next as InstanceJson);
  }

  clearPreview(name: string, token: number) {
    if (this.previews.get(name)?.token !== token) return;
    this.previews.delete(name);
    this.signals.previewChanged.dispatch();
  }

  /** The instance as the viewport shows it: its preview, else the document's. */
  displayInstance(name: string): InstanceJson | undefined {
    return this.previews.get(name)?.instance ?? this.instances.get(name);
  }

  // ------------------------------------------------------------- issues ---

  private setIssue(name: string, reason: string | null) {
    const had = this.issues.get(name) ?? null;
    if (had === reason) return;
    if (reason === null) this.issues.delete(name);
    else this.issues.set(name, reason);
    this.signals.issuesChanged.dispatch(this.issues);
  }

  /**
   * An instance steers no liquid if, in the first frames it is active, its
   * box holds none of its phase: control reached no particle and the
   * occupancy overlap is zero.
   */
  private checkIssues(f: FrameInfo) {
    const fr = this.frameRate();
    const window = Math.max(3, Math.round(0.1 * fr));
    for (let k = 0; k < f.instanceCount; k++) {
      const rec = f.instances[k]!;
      if (!rec.active) continue;
      const inst = this.instances.get(rec.name);
      if (!inst) continue;
      const startFrame = Math.round((inst.start ?? 0) * fr);
      const since = f.frame - startFrame;
      if (since < 0 || since > window) continue;
      const none = rec.controlled === 0 && rec.fidelity <= 0;
      const phase = inst.phase ?? this.session?.sceneJson?.phases?.[0]?.name ?? 'its phase';
      this.setIssue(rec.name, none
        ? `steers no liquid: when it starts (${(inst.start ?? 0).toFixed(3)} s) its box holds no ${phase} liquid. ` +
          'Move it over the liquid, or start it when liquid is there'
        : null);
    }
  }

  // ----------------------------------------------------------- playhead ---

  /** The frames recorded on the server (valid or stale), as one range. */
  recordedRange(): [number, number] {
    return [this.view.historyFirst, Math.max(this.view.historyLast, this.newestLiveFrame)];
  }

  isRecorded(frame: number): boolean {
    const [a, b] = this.recordedRange();
    return frame >= a && frame <= b;
  }

  /** The last frame the playhead can go to: the scene's end frame, or the newest recorded frame if later. */
  lastFrame(): number {
    return Math.max(this.view.endFrame, this.recordedRange()[1]);
  }

  /** The play range with its end resolved and both ends within [0, lastFrame()]. */
  rangeFrames(): { start: number; end: number } {
    const last = this.lastFrame();
    const end = Math.min(last, Math.max(1, this.playRange.end ?? this.view.endFrame));
    const start = Math.min(Math.max(0, this.playRange.start), end - 1);
    return { start: Math.max(0, start), end };
  }

  setPlayRange(change: Partial<PlayRange>) {
    Object.assign(this.playRange, change);
    if (this.playRange.end !== null && this.playRange.end === this.view.endFrame) this.playRange.end = null;
    this.signals.playRangeChanged.dispatch(this.playRange);
  }

  setAutoKey(on: boolean) {
    if (on === this.autoKey) return;
    this.autoKey = on;
    this.signals.autoKeyChanged.dispatch(on);
  }

  /**
   * Moves the playhead (the user's: scrubbing, keys, Home). A recorded frame
   * is shown by a seek (one in flight, the latest wins); any other frame in
   * [0, lastFrame()] is shown without the server: the viewport draws the
   * instances there from the tracks.
   */
  setPlayhead(frame: number) {
    this.stopLoop();
    this.movePlayhead(frame);
  }

  private movePlayhead(frame: number) {
    if (!this.session) return;
    frame = Math.min(this.lastFrame(), Math.max(0, Math.round(frame)));
    if (this.isRecorded(frame)) {
      this.offRecord = false;
      this.seekWanted = frame;
      if (!this.seeking) this.seekDone = this.pumpSeeks();
    } else {
      this.offRecord = true;
      this.seekWanted = null;
    }
    if (frame !== this.playheadFrame || this.offRecord) {
      this.playheadFrame = frame;
      this.signals.playheadChanged.dispatch(this.playheadTime());
    }
  }

  private async pumpSeeks() {
    this.seeking = true;
    this.signals.playbackChanged.dispatch();
    let sent: number | null = null;
    while (this.seekWanted !== null) {
      const frame = this.seekWanted;
      this.seekWanted = null;
      if (frame === sent) continue;
      const v = this.view;
      if (sent === null && !v.live && v.shownFrame === frame && this.frameArrived && this.shownFrame === frame) continue; // already shown
      sent = frame;
      await this.seekNow(frame);
    }
    this.seeking = false;
    // The last seek's frame is on its way; a refused seek leaves the playhead on the frame the viewport shows.
    if (!this.offRecord) {
      const shown = sent !== null && this.view.shownFrame === sent ? sent : this.frameArrived ? this.shownFrame : this.playheadFrame;
      if (shown !== this.playheadFrame) {
        this.playheadFrame = shown;
        this.signals.playheadChanged.dispatch(this.playheadTime());
      }
    }
    this.signals.playbackChanged.dispatch();
  }

  /** A seek's REST request (not transport(): it must not stop client-side playback). */
  private async seekNow(frame: number) {
    const s = this.session;
    if (!s) return;
    const seq = this.streamStates;
    try {
      const state = await this.api.transport(s.id, 'seek', { frame });
      if (this.streamStates === seq) this.applyState(state);
    } catch (e) {
      this.reportError(e, 'seek');
    }
  }

  /** Resolves when no seek is in flight. */
  seekIdle(): Promise<void> {
    return this.seekDone;
  }

  /** The next (+1) or previous (−1) transform key of the selected instance (of every instance when none is selected). */
  jumpToKey(direction: 1 | -1) {
    const fr = this.frameRate();
    const chosen = this.selected ? [this.instances.get(this.selected)] : [...this.instances.values()];
    const frames = new Set<number>();
    for (const inst of chosen) for (const k of inst?.transform ?? []) frames.add(Math.round((k.time ?? 0) * fr));
    const sorted = [...frames].filter((f) => f >= 0 && f <= this.lastFrame()).sort((a, b) => a - b);
    const at = this.playheadFrame;
    const target = direction > 0 ? sorted.find((f) => f > at) : [...sorted].reverse().find((f) => f < at);
    if (target === undefined) {
      this.message('info', `no ${direction > 0 ? 'next' : 'previous'} key${this.selected ? ` of ${this.selected}` : ''}`);
      return;
    }
    this.setPlayhead(target);
  }

  // ----------------------------------------------------------- playback ---

  /** Playing: the server simulates or replays, or the client loops over recorded frames. */
  isPlaying(): boolean {
    return this.view.status === 'playing' || this.view.status === 'stepping' || this.loopTimer !== null;
  }

  get looping(): boolean {
    return this.loopTimer !== null;
  }

  /**
   * Plays from the playhead to the play range's end (from its start when the
   * playhead is outside it), where playback stops, or loops: over recorded
   * frames the client seeks them at the scene's frame rate; what is not
   * recorded yet is simulated first (the server stops at the end).
   */
  async play() {
    if (!this.session) {
      this.message('warning', 'open a scene first');
      return;
    }
    const { start, end } = this.rangeFrames();
    if (this.playheadFrame >= end || this.playheadFrame < start) {
      this.setPlayhead(start);
      await this.seekIdle();
    }
    const [, last] = this.recordedRange();
    if (this.playRange.loop && end <= last && this.isRecorded(start)) {
      this.startLoop();
      return;
    }
    this.playUntil = end;
    await this.transport('play', { until: end });
  }

  async pause() {
    const wasLooping = this.loopTimer !== null;
    this.stopLoop();
    this.playUntil = null;
    const v = this.view;
    if (v.status === 'playing' || v.status === 'stepping') await this.transport('pause');
    else if (wasLooping) this.signals.sessionView.dispatch(this.view);
  }

  togglePlay(): Promise<void> {
    return this.isPlaying() ? this.pause() : this.play();
  }

  private startLoop() {
    this.stopLoop();
    const fr = this.frameRate();
    this.loopOrigin = { at: performance.now(), frame: this.playheadFrame };
    // Real time: a slow seek skips frames rather than slowing the loop down.
    this.loopTimer = setInterval(() => {
      if (this.seeking) return;
      const { start, end } = this.rangeFrames();
      const length = end - start + 1;
      const elapsed = Math.floor(((performance.now() - this.loopOrigin.at) / 1000) * fr);
      const frame = start + ((this.loopOrigin.frame - start + elapsed) % length + length) % length;
      if (frame !== this.playheadFrame) this.movePlayhead(frame);
    }, 1000 / fr);
    this.signals.playbackChanged.dispatch();
    this.signals.sessionView.dispatch(this.view);
  }

  private stopLoop() {
    if (this.loopTimer === null) return;
    clearInterval(this.loopTimer);
    this.loopTimer = null;
    this.signals.playbackChanged.dispatch();
    this.signals.sessionView.dispatch(this.view);
  }

  /** A new session: playhead at its start, no client playback, no previews or issues. */
  private resetPlayback() {
    this.stopLoop();
    this.playheadFrame = 0;
    this.offRecord = false;
    this.newestLiveFrame = 0;
    this.frameArrived = false;
    this.seekWanted = null;
    this.playUntil = null;
    this.playRange = { start: 0, end: null, loop: this.playRange.loop };
    this.previews.clear();
    if (this.issues.size) {
      this.issues.clear();
      this.signals.issuesChanged.dispatch(this.issues);
    }
  }

  private onFrame(f: FrameInfo) {
    this.shownFrame = f.frame;
    this.frameArrived = true;
    const running = this.view.status === 'playing' || this.view.status === 'stepping';
    if (this.view.live || running) this.newestLiveFrame = Math.max(this.newestLiveFrame, f.frame);
    // Simulating has reached an off-record playhead: follow the frames again.
    if (this.offRecord && running && f.frame >= this.playheadFrame) this.offRecord = false;
    // While seeks are in flight the playhead shows the frame asked for (pumpSeeks settles it); while
    // paused, frames re-simulated on the way to the frame shown do not move it back.
    const resim = this.view.cache.simulating;
    const catchingUp = resim !== null && !running && f.frame >= resim.from && f.frame < this.playheadFrame && this.playheadFrame <= resim.to;
    if (!this.offRecord && !this.seeking && !catchingUp && f.frame !== this.playheadFrame) {
      this.playheadFrame = f.frame;
      this.signals.playheadChanged.dispatch(this.playheadTime());
    }
    this.checkIssues(f);
  }

  /** The server stopped at the play's end (`until`): a looping range plays on from its start. */
  private statusChanged(before: SessionStatusName, after: SessionStatusName) {
    if ((before !== 'playing' && before !== 'stepping') || after !== 'paused') return;
    const until = this.playUntil;
    this.playUntil = null;
    if (until !== null && this.playRange.loop && this.view.frame >= until) void this.play();
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
    const before = this.view.status;
    const historyFirst = s.history.first ?? 0, historyLast = s.history.last ?? 0;
    this.view = {
      status: s.status,
      frame: s.frame,
      time: s.time,
      shownFrame: s.shown.frame,
      live: s.shown.live,
      playbackSpeed: s.playback_speed,
      historyFirst,
      historyLast,
      errorMessage: s.error?.message ?? '',
      cache: s.cache
        ? { valid: s.cache.valid ?? [], stale: s.cache.stale ?? [], simulating: s.cache.simulating ?? null, checkpoints: s.cache.checkpoints ?? [], reported: true }
        : derivedCache(historyFirst, historyLast, s.history.last !== null),
      endFrame: typeof s.end_frame === 'number' ? s.end_frame : this.sceneEndFrame(),
    };
    const job = s.export ?? null, key = job ? JSON.stringify(job) : '';
    if (key !== this.exportJobKey) {
      this.exportJobKey = key;
      this.exportJob = job;
      this.signals.exportJobChanged.dispatch(job);
    }
    this.mergeRenderJobs(s.jobs ?? []);
    this.afterState(before);
  }

  /** The session's newest surface export job, as its state says (null: none). */
  exportJob: SurfaceJob | null = null;
  private exportJobKey = '';

  /** Exports the history as NAME.h5 and meshes it into `formats`; progress arrives as exportJobChanged. */
  async exportSurfaces(name: string, formats: string[], surface: Record<string, number> = {}, force = false): Promise<SurfaceJob | null> {
    const s = this.session;
    if (!s) return null;
    try {
      const answer = await this.api.exportHistory(s.id, { name, formats, surface, force });
      const job = answer.surface_job ?? null;
      if (job) {
        this.exportJob = job;
        this.exportJobKey = JSON.stringify(job);
        this.signals.exportJobChanged.dispatch(job);
      }
      return job;
    } catch (e) {
      this.reportError(e, `export ${name}`);
      return null;
    }
  }

  async cancelExport(): Promise<void> {
    const job = this.exportJob;
    if (!job) return;
    try {
      await this.api.cancelExportJob(job.id);
    } catch (e) {
      this.reportError(e, `cancel export ${job.name}`);
    }
  }

  /** The session's render jobs, oldest first, as its states reported them (mergeRenderJobs). */
  renderJobs: readonly RenderJob[] = [];
  private renderJobsKey = '[]';
  renderAvailability: RenderAvailability = { known: false, available: false, where: '', reason: 'asking the server whether it runs render jobs' };

  /** The ids the last state listed. */
  private renderJobsInState = new Set<string>();

  /**
   * The state's jobs merged into the ones seen in this session, by id: the
   * state lists only the newest, and a job that leaves it keeps its last
   * known state (an unfinished one is read once more). An older report (a
   * REST answer behind the stream) never moves a job back.
   */
  private mergeRenderJobs(fromState: readonly RenderJob[]) {
    const known = new Map(this.renderJobs.map((j) => [j.id, j]));
    for (const job of fromState) {
      const had = known.get(job.id);
      if (!had || !isBehind(job, had)) known.set(job.id, job);
    }
    const listed = new Set(fromState.map((j) => j.id));
    for (const id of this.renderJobsInState) {
      const job = known.get(id);
      if (!listed.has(id) && job && (job.state === 'queued' || job.state === 'running')) void this.refreshRenderJob(id);
    }
    this.renderJobsInState = listed;
    this.setRenderJobs([...known.values()].sort((a, b) => jobNumber(a) - jobNumber(b)));
  }

  private async refreshRenderJob(id: string) {
    const s = this.session;
    try {
      const job = await this.api.job(id);
      if (this.session !== s) return;
      const had = this.renderJobs.find((j) => j.id === id);
      if (had && !isBehind(job, had)) this.setRenderJobs(this.renderJobs.map((j) => (j.id === id ? job : j)));
    } catch {
      // Gone from the server (only the newest finished jobs are kept): its last known state stays.
    }
  }

  private setRenderJobs(jobs: readonly RenderJob[]) {
    const key = JSON.stringify(jobs);
    if (key === this.renderJobsKey) return;
    this.renderJobsKey = key;
    this.renderJobs = jobs;
    this.signals.renderJobsChanged.dispatch(jobs);
  }

  /** Asks the server once whether it runs render jobs (flowclip-batch) and where. */
  async loadRenderAvailability(): Promise<RenderAvailability> {
    try {
      const r = await this.api.listJobs();
      this.renderAvailability = {
        known: true, available: r.available, where: r.where,
        reason: r.available ? '' : 'this server runs no render jobs: it found no flowclip-batch (flowclip serve --batch-command)',
      };
    } catch (e) {
      this.renderAvailability = {
        known: true, available: false, where: '',
        reason: `render jobs are unavailable: ${e instanceof ApiError ? e.describe() : String(e)}`,
      };
    }
    this.signals.renderAvailabilityChanged.dispatch(this.renderAvailability);
    return this.renderAvailability;
  }

  /** Runs the session's current scene again as a render job; its progress arrives as renderJobsChanged. */
  async submitRender(request: Omit<RenderJobRequest, 'session'>): Promise<RenderSubmitResult> {
    const s = this.session;
    if (!s) return { error: 'open a scene first', path: null };
    try {
      const job = await this.api.submitJob({ ...request, session: s.id });
      // Shown at once; the stream's state brings the same job on.
      if (this.session === s && !this.renderJobs.some((j) => j.id === job.id)) this.setRenderJobs([...this.renderJobs, job]);
      return { job };
    } catch (e) {
      if (e instanceof ApiError) return { error: e.describe(), path: e.path ?? null };
      return { error: e instanceof Error ? e.message : String(e), path: null };
    }
  }

  /** A file of a done render job's task (null: refused, reported). */
  async renderJobFile(id: string, task: string, file: string): Promise<Blob | null> {
    try {
      return await this.api.jobFile(id, task, file);
    } catch (e) {
      this.reportError(e, `download ${file}`);
      return null;
    }
  }

  async cancelRender(id: string): Promise<void> {
    try {
      await this.api.cancelJob(id);
    } catch (e) {
      // 409: it ended meanwhile (the state says how).
      if (!(e instanceof ApiError && e.status === 409)) this.reportError(e, `cancel render job ${id}`);
    }
  }

  private afterState(before: SessionStatusName) {
    // Frame 0 with nothing after it: a reset (or a new session) cleared the history.
    if (this.view.frame === 0 && this.view.historyLast === 0) this.newestLiveFrame = 0;
    this.signals.sessionView.dispatch(this.view);
    if (before !== this.view.status) this.statusChanged(before, this.view.status);
  }

  /** The scene's duration × frame rate (where playback stops when the server does not say). */
  sceneEndFrame(): number {
    const d = this.session?.sceneJson?.duration;
    return Math.max(1, Math.round((typeof d === 'number' && d > 0 ? d : 10) * this.frameRate()));
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
    const before = this.view.status;
    const cache = this.view.cache.reported ? this.view.cache : derivedCache(s.historyFirst, s.historyLast, true);
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
      cache,
      endFrame: this.view.endFrame,
    };
    if (s.status === 'error' && !wasError) this.message('error', `simulation stopped: ${s.message}`);
    this.afterState(before);
  }
}

/** "j12" → 12: jobs in the order they were submitted. */
function jobNumber(j: RenderJob): number {
  return Number(j.id.slice(1)) || 0;
}

/** `a` is an older report of job `b` (not finished while `b` is, or fewer frames done). */
function isBehind(a: RenderJob, b: RenderJob): boolean {
  const ended = (j: RenderJob) => j.state === 'done' || j.state === 'failed' || j.state === 'cancelled';
  if (ended(b)) return !ended(a);
  if (ended(a)) return false;
  if (a.state === 'queued' && b.state === 'running') return true;
  return a.frames_done < b.frames_done;
}

function emptyView(): SessionView {
  return {
    status: 'paused', frame: 0, time: 0, shownFrame: 0, live: true, playbackSpeed: 0,
    historyFirst: 0, historyLast: 0, errorMessage: '', cache: derivedCache(0, 0, false), endFrame: 0,
  };
}

/** A server without cache ranges: the replay history is all valid. */
function derivedCache(first: number, last: number, any: boolean): CacheView {
  return { valid: any ? [[first, last]] : [], stale: [], simulating: null, checkpoints: [], reported: false };
}

/**
 * Where a new instance of template `t` goes: its region centred at
 * `position`, scaled down (uniformly, to 0.01) when the region is larger than
 * 90 % of the domain, and moved so that its box lies inside the domain.
 */
export function fitInDomain(
  t: TemplateInfo | undefined, domain: { min: number[]; max: number[] } | undefined, position: number[], dim: 2 | 3,
): { translation: number[]; scale: number } {
  const r4 = (v: number) => Math.round(v * 1e4) / 1e4;
  const p = position.slice(0, dim);
  if (!t?.region_min || !t.region_max || !domain) return { translation: p.map(r4), scale: 1 };
  let scale = 1;
  for (let d = 0; d < dim; d++) {
    const size = (t.region_max[d] ?? 0) - (t.region_min[d] ?? 0), room = (domain.max[d] ?? 0) - (domain.min[d] ?? 0);
    if (size > 0 && room > 0) scale = Math.min(scale, (0.9 * room) / size);
  }
  if (scale < 1) scale = Math.max(0.01, Math.floor(scale * 100) / 100);
  const translation = p.map((v, d) => {
    const half = (((t.region_max![d] ?? 0) - (t.region_min![d] ?? 0)) * scale) / 2;
    const lo = (domain.min[d] ?? 0) + half, hi = (domain.max[d] ?? 0) - half;
    return r4(lo <= hi ? Math.min(hi, Math.max(lo, v)) : v);
  });
  return { translation, scale };
}

/** `?token=T` in the page's URL (a server started with --token), kept for the tab. */
function tokenFromPage(): string | null {
  if (typeof location === 'undefined') return null;
  const t = new URLSearchParams(location.search).get('token');
  if (t) sessionStorage.setItem('flowclip-token', t);
  return t ?? sessionStorage.getItem('flowclip-token');
}
