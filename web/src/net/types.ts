// The REST API's JSON shapes under the names the editor uses. Every one is a
// schema of proto/openapi.yaml: `@openapi` is generated from it at build time
// (scripts/wire.mjs, openapi-typescript), so that a field renamed or removed
// in the contract fails the editor's type check.
import type { components, paths } from '@openapi';

type Schemas = components['schemas'];

export type Vec = Schemas['Vec'];

export type SceneSummary = Schemas['SceneSummary'];
export type TemplateInfo = Schemas['Template'];
/** GET /api/recipes: a recipe the server can record, and the templates it records. */
export type RecipeInfo = Schemas['Recipe'];
/** A recording job (POST /api/recipes/{name}/record, GET/DELETE /api/recipes/jobs/{id}). */
export type RecipeJob = Schemas['RecipeJob'];
export type RecipeJobState = RecipeJob['state'];
/** A surface export job (POST /api/sessions/{id}/export with formats, GET/DELETE /api/exports/jobs/{id}). */
export type SurfaceJob = Schemas['SurfaceJob'];
export type ExportRequest = Schemas['ExportRequest'];

/** A render job (POST /api/jobs, GET/DELETE /api/jobs/{id}; the session's state `jobs`). */
export type RenderJob = Schemas['RenderJob'];
export type RenderJobState = RenderJob['state'];
export type RenderTask = RenderJob['tasks'][number];
/** POST /api/jobs's body: the session's scene again at a final resolution, with a wedge and surfaces. */
export type RenderJobRequest = paths['/api/jobs']['post']['requestBody']['content']['application/json'];
/** GET /api/jobs: every render job of the server, whether it runs them (`available`) and where. */
export type RenderJobList = paths['/api/jobs']['get']['responses'][200]['content']['application/json'];

export type SessionState = Schemas['State'];
export type SessionStatusName = SessionState['status'];
export type FrameStatsJson = Schemas['FrameStats'];

export type TransformKey = Schemas['TransformKey'];
/** An instance as the server returns it (named). */
export type InstanceJson = Schemas['Instance'];
/** An instance as a request or a scene writes it (`name` defaults to the template's). */
export type InstanceInputJson = Schemas['InstanceInput'];

/**
 * An instance's value by key name. The inspector and the timeline read the
 * instance parameters by the names GET /api/parameters declares, which the
 * contract's Instance lists too; named fields read as `inst.start`.
 */
export function instanceValue(inst: InstanceJson, key: string): unknown {
  return (inst as Record<string, unknown>)[key];
}

/** An edit's result: applied (`accepted`) or rejected (`error`). */
export type EditJson = Schemas['Edit'];
/** An edit the session has not applied yet (HTTP 202: it is inside a long frame). */
export type EditPendingJson = Schemas['EditPending'];
/** GET .../edits/{id}: the Edit itself, or, while it waits, the pending edit (alone or as {edit}). */
export type EditResultJson = EditJson | EditPendingJson | Schemas['EditPendingResponse'];
/** An accepted instance edit carries the instance; a pending one (202) does not. */
export type InstanceEditResponse = Schemas['InstanceEditResponse'] | Schemas['EditPendingResponse'];
/** A settings or remove edit: applied, or pending (202). */
export type EditResponse = Schemas['EditResponse'] | Schemas['EditPendingResponse'];

export type SceneJson = Schemas['Scene'];

export type TransportRequest = Schemas['TransportRequest'];
export type TransportName = TransportRequest['command'];
export type TransportArgs = Omit<TransportRequest, 'command'>;

/** One parameter's declaration (GET /api/parameters): the server's ParamSpec. */
export type ParamSpecJson = Schemas['ParamSpec'];
export type RegisteredPartJson = Schemas['RegisteredParts'][string];
export type ParametersJson = Schemas['Parameters'];

/** GET /api/templates/{name}/preview: one frame's positions, flattened (dimension numbers each). */
export type TemplatePreviewJson = Schemas['TemplatePreview'];

/** PATCH /api/sessions/{id}/settings: merge patches of the scene's objects. */
export type SettingsPatch = Schemas['SettingsPatch'];

/** GET /api/presets: the accuracy presets of `flowclip bench accuracy`, with their measured cost and error. */
export type PresetsJson = Schemas['Presets'];
export type AccuracyPresetJson = Schemas['AccuracyPreset'];

export type HealthJson = Schemas['Health'];
