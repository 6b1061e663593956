// REST client of `flowclip serve` (proto/openapi.yaml). Every failure is an
// ApiError carrying the server's Error object (status, code, message, path),
// or status 0 when the server could not be reached.
import type {
  EditJson, EditResultJson, InstanceEditResponse, InstanceJson, ParametersJson, PresetsJson, RecipeInfo, RecipeJob, SceneJson, SceneSummary,
  SessionState, SettingsPatch, TemplateInfo, TemplatePreviewJson, TransportArgs, TransportName,
} from './types';

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

export class Api {
  /** `base`: the server's origin ('' = the page's); `token`: the server's --token, if any. */
  constructor(
    readonly base = '',
    readonly token: string | null = null,
  ) {}

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
    return this.request<{ status: string; version: string; sessions: number; rss_mb?: number }>('GET', '/api/health');
  }
  listScenes() {
    return this.request<{ scenes: SceneSummary[] }>('GET', '/api/scenes').then((r) => r.scenes);
  }
  listTemplates() {
    return this.request<{ templates: TemplateInfo[] }>('GET', '/api/templates').then((r) => r.templates);
  }
  /** The recipes the server can record, with the templates each records. */
  listRecipes() {
    return this.request<{ recipes: RecipeInfo[] }>('GET', '/api/recipes').then((r) => r.recipes);
  }
  /** Starts recording a recipe in the background (or returns its queued or running job). */
  recordRecipe(name: string, force = false) {
    return this.request<RecipeJob>('POST', `/api/recipes/${enc(name)}/record`, force ? { force } : undefined);
  }
  recipeJob(id: string) {
    return this.request<RecipeJob>('GET', `/api/recipes/jobs/${enc(id)}`);
  }
  cancelRecipeJob(id: string) {
    return this.request<RecipeJob>('DELETE', `/api/recipes/jobs/${enc(id)}`);
  }
  /** Every parameter's declaration for scenes of that dimension (the inspector's fields). */
  parameters(dimension: 2 | 3) {
    return this.request<ParametersJson>('GET', `/api/parameters?dimension=${dimension}`);
  }
  /** The accuracy presets the study chose (draft, preview, final) with their measured figures. */
  presets() {
    return this.request<PresetsJson>('GET', '/api/presets');
  }
  templatePreview(name: string, maxPoints = 1500) {
    return this.request<TemplatePreviewJson>('GET', `/api/templates/${enc(name)}/preview?max=${maxPoints}`);
  }
  getScene(name: string) {
    return this.request<SceneJson>('GET', `/api/scenes/${enc(name)}`);
  }
  /** Saves the session's current scene (every accepted edit) as NAME.json in the server's scene directory. */
  saveScene(session: string, name: string, force = false) {
    return this.request<{ name: string; path: string }>('POST', '/api/scenes', { name, session, force });
  }
  /** An edit's result: 200 applied or rejected (`accepted`, `error`), 202 `{pending: true}` not yet. */
  getEdit(id: string, edit: number) {
    return this.request<EditResultJson>('GET', `/api/sessions/${enc(id)}/edits/${edit}`);
  }
  patchSettings(id: string, patch: SettingsPatch) {
    return this.request<{ edit: EditJson }>('PATCH', `/api/sessions/${enc(id)}/settings`, patch);
  }
  createSession(scene: string | SceneJson, options: { name?: string; playback_speed?: number } = {}) {
    return this.request<SessionState>('POST', '/api/sessions', { scene, ...options });
  }
  deleteSession(id: string) {
    return this.request<{ deleted: string }>('DELETE', `/api/sessions/${enc(id)}`);
  }
  getSession(id: string) {
    return this.request<SessionState>('GET', `/api/sessions/${enc(id)}`);
  }
  getSessionScene(id: string) {
    return this.request<SceneJson>('GET', `/api/sessions/${enc(id)}/scene`);
  }
  transport(id: string, command: TransportName, args: TransportArgs = {}) {
    return this.request<SessionState>('POST', `/api/sessions/${enc(id)}/transport`, { command, ...args });
  }
  listInstances(id: string) {
    return this.request<{ instances: InstanceJson[] }>('GET', `/api/sessions/${enc(id)}/instances`).then(
      (r) => r.instances,
    );
  }
  getInstance(id: string, name: string) {
    return this.request<InstanceJson>('GET', `/api/sessions/${enc(id)}/instances/${enc(name)}`);
  }
  /** JSON merge patch (RFC 7396) of one instance. */
  patchInstance(id: string, name: string, patch: Partial<InstanceJson>) {
    return this.request<InstanceEditResponse>('PATCH', `/api/sessions/${enc(id)}/instances/${enc(name)}`, patch);
  }
  addInstance(id: string, instance: Partial<InstanceJson> & { template: string }) {
    return this.request<InstanceEditResponse>('POST', `/api/sessions/${enc(id)}/instances`, instance);
  }
  removeInstance(id: string, name: string) {
    return this.request<{ edit: unknown }>('DELETE', `/api/sessions/${enc(id)}/instances/${enc(name)}`);
  }
}

const enc = encodeURIComponent;
