// REST client of `flowclip serve`. Its routes, parameters, bodies and answers
// are typed from proto/openapi.yaml (`paths` of the generated `@openapi`,
// scripts/wire.mjs): a route, parameter or field the contract does not have
// fails the editor's type check. Every failure is an ApiError carrying the
// server's Error object (status, code, message, path), or status 0 when the
// server could not be reached.
import type { paths } from '@openapi';
import type { ExportRequest, InstanceInputJson, RenderJobRequest, InstanceJson, SceneJson, SettingsPatch, TransportArgs, TransportName } from './types';

export class ApiError extends Error {
  constructor(
    readonly status: number,
    readonly code: string,
    message: string,
    readonly path?: string,
  ) {
    super(message);
    this.name = 'ApiError';
  }

  /** "422 unprocessable: speed must be > 0 (instances[0].speed)" */
  describe(): string {
    const where = this.path ? ` (${this.path})` : '';
    return this.status ? `${this.status} ${this.code}: ${this.message}${where}` : this.message;
  }
}

// ----------------------------------------------- the contract's routes ---

type Method = 'get' | 'post' | 'patch' | 'delete';
type Route = keyof paths;
/** The routes of the contract that have method M. */
type RouteWith<M extends Method> = { [P in Route]: M extends keyof paths[P] ? P : never }[Route];
type Operation<P extends Route, M extends Method> = M extends keyof paths[P] ? paths[P][M] : never;

type JsonOf<R> = R extends { content: { 'application/json': infer J } } ? J : never;
/** The JSON of the operation's 2xx answers (a union when it has several, e.g. 201 applied | 202 pending). */
type Answer<O> = O extends { responses: infer R } ? JsonOf<R[Extract<keyof R, 200 | 201 | 202 | 203 | 204>]> : never;

type PathArgs<O> = O extends { parameters: { path: infer P } } ? { path: P } : { path?: undefined };
type QueryArgs<O> = O extends { parameters: { query?: infer Q } } ? { query?: Q } : { query?: undefined };
type BodyArgs<O> = O extends { requestBody: { content: { 'application/json': infer B } } }
  ? { body: B }
  : O extends { requestBody?: { content: { 'application/json': infer B } } }
    ? { body?: B }
    : { body?: undefined };
/** Path parameters, query and JSON body of the operation, as the contract declares them. */
type Args<O> = PathArgs<O> & QueryArgs<O> & BodyArgs<O>;
/** The arguments may be left out when none is required. */
type ArgList<O> = Record<string, never> extends Args<O> ? [args?: Args<O>] : [args: Args<O>];

/** "/api/sessions/{id}/instances/{name}" with its parameters percent-encoded, plus the query string. */
function url(route: string, path: Record<string, unknown> = {}, query: Record<string, unknown> = {}): string {
  const filled = route.replace(/\{(\w+)\}/g, (_, k: string) => {
    if (path[k] === undefined) throw new Error(`${route}: path parameter ${k} is missing`);
    return encodeURIComponent(String(path[k]));
  });
  const q = new URLSearchParams();
  for (const [k, v] of Object.entries(query)) if (v !== undefined) q.set(k, String(v));
  const qs = q.toString();
  return qs ? `${filled}?${qs}` : filled;
}

export class Api {
  /** `base`: the server's origin ('' = the page's); `token`: the server's --token, if any. */
  constructor(
    readonly base = '',
    readonly token: string | null = null,
  ) {}

  /** An operation of the contract: `call('get', '/api/sessions/{id}', { path: { id } })`. */
  call<M extends Method, P extends RouteWith<M>>(
    method: M, route: P, ...[args]: ArgList<Operation<P, M>>
  ): Promise<Answer<Operation<P, M>>> {
    // Read as plain records: the union of every route's arguments is too large for the checker to narrow here.
    const given: unknown = args;
    const a = (given ?? {}) as { path?: Record<string, unknown>; query?: Record<string, unknown>; body?: unknown };
    return this.request(method.toUpperCase(), url(route, a.path, a.query), a.body);
  }

  /** A raw request (any path, untyped answer); `call` is the typed one. */
  async request<T>(method: string, path: string, body?: unknown): Promise<T> {
    const headers: Record<string, string> = {};
    if (body !== undefined) headers['Content-Type'] = 'application/json';
    if (this.token) headers['Authorization'] = `Bearer ${this.token}`;
    let res: Response;
    try {
      res = await fetch(this.base + path, {
        method,
        headers,
        body: body === undefined ? undefined : JSON.stringify(body),
      });
    } catch (e) {
      throw new ApiError(0, 'network', `${method} ${path}: the server cannot be reached (${String(e)})`);
    }
    const text = await res.text();
    let json: unknown = null;
    if (text) {
      try {
        json = JSON.parse(text);
      } catch {
        json = null;
      }
    }
    if (!res.ok) {
      const err = (json as { error?: { code?: string; message?: string; path?: string } } | null)?.error;
      throw new ApiError(
        res.status,
        err?.code ?? 'http_error',
        err?.message ?? `${method} ${path}: HTTP ${res.status}`,
        err?.path,
      );
    }
    return json as T;
  }

  health() {
    return this.call('get', '/api/health');
  }
  listScenes() {
    return this.call('get', '/api/scenes').then((r) => r.scenes);
  }
  listTemplates() {
    return this.call('get', '/api/templates').then((r) => r.templates);
  }
  /** The recipes the server can record, with the templates each records. */
  listRecipes() {
    return this.call('get', '/api/recipes').then((r) => r.recipes);
  }
  /** Starts recording a recipe in the background (or returns its queued or running job). */
  recordRecipe(name: string, force = false) {
    return this.call('post', '/api/recipes/{name}/record', { path: { name }, body: force ? { force } : undefined });
  }
  recipeJob(id: string) {
    return this.call('get', '/api/recipes/jobs/{id}', { path: { id } });
  }
  cancelRecipeJob(id: string) {
    return this.call('delete', '/api/recipes/jobs/{id}', { path: { id } });
  }
  /** Exports the session's history as NAME.h5; with `formats`, starts meshing it into NAME/ (answer 202, `surface_job`). */
  exportHistory(id: string, body: ExportRequest) {
    return this.call('post', '/api/sessions/{id}/export', { path: { id }, body });
  }
  exportJob(id: string) {
    return this.call('get', '/api/exports/jobs/{id}', { path: { id } });
  }
  cancelExportJob(id: string) {
    return this.call('delete', '/api/exports/jobs/{id}', { path: { id } });
  }
  /** A file of a finished surface export, as a Blob (with the token, which a plain link would not send). */
  async exportFile(name: string, file: string): Promise<Blob> {
    const path = url('/api/exports/{name}/{file}', { name, file });
    const headers: Record<string, string> = this.token ? { Authorization: `Bearer ${this.token}` } : {};
    const res = await fetch(this.base + path, { headers });
    if (!res.ok) throw new ApiError(res.status, 'http_error', `GET ${path}: HTTP ${res.status}`);
    return res.blob();
  }
  /** Render jobs of the server, whether it runs them (flowclip-batch found) and where (a scheduler or local workers). */
  listJobs() {
    return this.call('get', '/api/jobs');
  }
  /** Runs the session's current scene again as a batch (answer 202, the queued job). */
  submitJob(body: RenderJobRequest) {
    return this.call('post', '/api/jobs', { body });
  }
  job(id: string) {
    return this.call('get', '/api/jobs/{id}', { path: { id } });
  }
  cancelJob(id: string) {
    return this.call('delete', '/api/jobs/{id}', { path: { id } });
  }
  /** A file of a done render job's task (`file` may hold a slash: percent-encoded), as a Blob. */
  async jobFile(id: string, task: string, file: string): Promise<Blob> {
    const path = url('/api/jobs/{id}/files/{task}/{file}', { id, task, file });
    const headers: Record<string, string> = this.token ? { Authorization: `Bearer ${this.token}` } : {};
    const res = await fetch(this.base + path, { headers });
    if (!res.ok) throw new ApiError(res.status, 'http_error', `GET ${path}: HTTP ${res.status}`);
    return res.blob();
  }
  /** Every parameter's declaration for scenes of that dimension (the inspector's fields). */
  parameters(dimension: 2 | 3) {
    return this.call('get', '/api/parameters', { query: { dimension } });
  }
  /** The accuracy presets the study chose (draft, preview, final) with their measured figures. */
  presets() {
    return this.call('get', '/api/presets');
  }
  templatePreview(name: string, maxPoints = 1500) {
    return this.call('get', '/api/templates/{name}/preview', { path: { name }, query: { max: maxPoints } });
  }
  getScene(name: string) {
    return this.call('get', '/api/scenes/{name}', { path: { name } });
  }
  /** Saves the session's current scene (every accepted edit) as NAME.json in the server's scene directory. */
  saveScene(session: string, name: string, force = false) {
    return this.call('post', '/api/scenes', { body: { name, session, force } });
  }
  /** An edit's result: 200 applied or rejected (`accepted`, `error`), 202 pending, alone or as `{edit}`. */
  getEdit(id: string, edit: number) {
    return this.call('get', '/api/sessions/{id}/edits/{edit_id}', { path: { id, edit_id: edit } });
  }
  patchSettings(id: string, patch: SettingsPatch) {
    return this.call('patch', '/api/sessions/{id}/settings', { path: { id }, body: patch });
  }
  createSession(scene: string | SceneJson, options: { name?: string; playback_speed?: number } = {}) {
    return this.call('post', '/api/sessions', { body: { scene, ...options } });
  }
  deleteSession(id: string) {
    return this.call('delete', '/api/sessions/{id}', { path: { id } });
  }
  getSession(id: string) {
    return this.call('get', '/api/sessions/{id}', { path: { id } });
  }
  getSessionScene(id: string) {
    return this.call('get', '/api/sessions/{id}/scene', { path: { id } });
  }
  transport(id: string, command: TransportName, args: TransportArgs = {}) {
    return this.call('post', '/api/sessions/{id}/transport', { path: { id }, body: { command, ...args } });
  }
  listInstances(id: string) {
    return this.call('get', '/api/sessions/{id}/instances', { path: { id } }).then((r) => r.instances);
  }
  getInstance(id: string, name: string) {
    return this.call('get', '/api/sessions/{id}/instances/{name}', { path: { id, name } });
  }
  /** JSON merge patch (RFC 7396) of one instance (null removes a key). */
  patchInstance(id: string, name: string, patch: Partial<InstanceJson> | Record<string, unknown>) {
    return this.call('patch', '/api/sessions/{id}/instances/{name}', { path: { id, name }, body: patch });
  }
  addInstance(id: string, instance: InstanceInputJson) {
    return this.call('post', '/api/sessions/{id}/instances', { path: { id }, body: instance });
  }
  removeInstance(id: string, name: string) {
    return this.call('delete', '/api/sessions/{id}/instances/{name}', { path: { id, name } });
  }
}
