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
  InstanceJson, SceneJson, SceneSummary, SessionState, SessionStatusName, TemplateInfo, TransportName,
} from '../net/types';
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
    /** The selected instance's name (null: none). Outliner, inspector, gizmo and timeline follow it. */
    selectionChanged: new Signal<string | null>(),
    /** A session was opened (or closed: null). */
    sessionChanged: new Signal<SessionInfo | null>(),
    sessionView: new Signal<SessionView>(),
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
  /** The selected instance (a name in `instances`) or null. */
  selected: string | null = null;
  session: SessionInfo | null = null;
  view: SessionView = emptyView();
  readonly instances = new Map<string, InstanceJson>();
  stream: Stream | null = null;
  /** Frames per wall second the stream sends at most (0: no limit). */
  maxFrameRate = 30;
  readonly layers: LayerToggles = { liquid: true, control: false, repulsion: false, boundary: false };
  private healthTimer: ReturnType<typeof setInterval> | null = null;

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

  /** Creates a session of scene `name` and streams it (the previous session, if ours, is deleted). */
  async openScene(name: string): Promise<SessionInfo | null> {
    let state: SessionState;
    try {
      state = await this.api.createSession(name);
    } catch (e) {
      this.reportError(e, `open scene ${name}`);
      return null;
    }
    await this.closeSession();
    return this.attach(state, name, true);
  }

  /** Streams an existing session (not deleted when the editor leaves it). */
  async attachSession(id: string): Promise<SessionInfo | null> {
    let state: SessionState;
    try {
      state = await this.api.getSession(id);
    } catch (e) {
      this.reportError(e, `attach to session ${id}`);
      return null;
    }
    await this.closeSession();
    return this.attach(state, state.name, false);
  }

  async closeSession(): Promise<void> {
    const s = this.session;
    if (!s) return;
    this.stream?.close();
    this.stream = null;
    this.pollHealth(false);
    this.session = null;
    this.instances.clear();
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

  private async attach(state: SessionState, scene: string, owned: boolean): Promise<SessionInfo> {
    let sceneJson: SceneJson | null = null;
    try {
      sceneJson = await this.api.getSessionScene(state.id);
    } catch (e) {
      this.reportError(e, 'read the session scene');
    }
    const info: SessionInfo = { id: state.id, scene, dimension: state.dimension, sceneJson, owned };
    this.session = info;
    this.history.clear();
    let instances = sceneJson?.instances ?? [];
    try {
      instances = await this.api.listInstances(state.id); // every key, defaults written
    } catch (e) {
      this.reportError(e, 'list instances');
    }
    this.setInstances(instances);
    this.applyState(state);
    this.signals.sessionChanged.dispatch(info);
    this.connectStream(info);
    return info;
  }

  // ------------------------------------------------------------- layers ---

  /** The stream's Layer flags for the toggles (Instances always). */
  layerFlags(): Layer {
    const l = this.layers;
    return (Layer.Instances | (l.control ? Layer.Control : 0) | (l.repulsion ? Layer.Repulsion : 0) |
      (l.boundary ? Layer.Boundary : 0)) as Layer;
  }

  /** Changes layer toggles; the stream is re-subscribed when its flags change (the server resends the frame). */
  setLayers(change: Partial<LayerToggles>) {
    const before = this.layerFlags();
    Object.assign(this.layers, change);
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
    stream.frame.add((f) => this.signals.frameDecoded.dispatch(f));
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
    try {
      this.applyState(await this.api.transport(s.id, command, args));
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

  /** The server's answer to an instance edit. */
  instanceUpdated(instance: InstanceJson) {
    this.instances.set(instance.name, instance);
    this.signals.instancesChanged.dispatch(this.instances);
  }

  instanceRemoved(name: string) {
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

  private applyStreamState(s: StreamState) {
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
