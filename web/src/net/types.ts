// JSON shapes of the REST API (proto/openapi.yaml), as far as the editor reads them.

export type Vec = number[];

export interface SceneSummary {
  name: string;
  dimension: 2 | 3 | null;
  instances: number;
  error?: string;
  /** Templates its instances name that the server's database lacks. */
  missing_templates?: string[];
}

export interface TemplateInfo {
  name: string;
  dimension?: 2 | 3;
  frames?: number;
  frame_rate?: number;
  duration?: number;
  avg_particles?: number;
  region_min?: Vec;
  region_max?: Vec;
  bytes?: number;
  error?: string;
}

/** GET /api/recipes: a recipe the server can record, and the templates it records. */
export interface RecipeInfo {
  name: string;
  dimension?: 2 | 3;
  templates?: { name: string; recorded: boolean }[];
  /** The database has every one of its templates. */
  recorded?: boolean;
  /** Simulation frames a recording advances. */
  frames?: number;
  /** Wall time of this server's newest successful recording of it, s. */
  last_seconds?: number;
  /** Its queued or running job. */
  job?: string;
  error?: string;
}

export type RecipeJobState = 'queued' | 'running' | 'done' | 'failed' | 'cancelled';

/** A recording job (POST /api/recipes/{name}/record, GET/DELETE /api/recipes/jobs/{id}). */
export interface RecipeJob {
  id: string;
  recipe: string;
  templates: string[];
  dimension: 2 | 3;
  force: boolean;
  state: RecipeJobState;
  progress: number;
  frames_done: number;
  frames: number;
  cancel_requested: boolean;
  elapsed_s: number;
  error?: string;
}

export type SessionStatusName = 'paused' | 'playing' | 'stepping' | 'error';

export interface FrameStatsJson {
  frame: number;
  time: number;
  wall_ms?: number;
  liquid_particles?: number;
  temporary_particles?: number;
  [key: string]: unknown;
}

export interface SessionState {
  id: string;
  name: string;
  dimension: 2 | 3;
  status: SessionStatusName;
  frame: number;
  time: number;
  playback_speed: number;
  shown: { live: boolean; frame: number };
  history: { first: number | null; last: number | null; frames: number; bytes: number; cap: number; dropped: number };
  stats: FrameStatsJson;
  particles: { liquid: number; temporary: number; boundary: number };
  instances: number;
  pending_edits: number;
  steps_left: number;
  computing?: boolean;
  memory: Record<string, number>;
  error?: { message: string; frame: number };
  /** Recorded frames against the current scene (inclusive ranges); absent from servers without re-simulation. */
  cache?: {
    valid: [number, number][];
    stale: [number, number][];
    simulating: { from: number; to: number; frame: number } | null;
    checkpoints?: number[];
    checkpoint_every?: number;
    checkpoint_bytes?: number;
  };
  /** Where playback stops: the scene's duration × frame rate. */
  end_frame?: number;
}

export interface TransformKey {
  time?: number;
  translation: Vec;
  rotation?: number | Vec;
  scale?: number | Vec;
  reflect?: boolean[];
}

export interface InstanceJson {
  name: string;
  template: string;
  phase?: string;
  transform?: TransformKey[];
  start?: number;
  crop_begin?: number;
  crop_end?: number;
  speed?: number;
  reverse?: boolean;
  falloff_width?: number;
  [key: string]: unknown;
}

export interface EditJson {
  id: number;
  type: string;
  /** Absent while pending (HTTP 202: the session is inside a long frame). */
  accepted?: boolean;
  pending?: boolean;
  frame?: number;
  instance?: string;
  error?: { path: string; message: string };
}

/** GET .../edits/{id}: the Edit itself, or {edit: {pending}} while it waits. */
export type EditResultJson = EditJson & { edit?: EditJson };

/** An accepted instance edit carries the instance; a pending one (202) does not. */
export interface InstanceEditResponse {
  edit: EditJson;
  instance?: InstanceJson;
}

export interface SceneJson {
  name?: string;
  dimension: 2 | 3;
  particle_radius?: number;
  domain?: { min: Vec; max: Vec };
  phases?: { name: string; color?: number[] }[];
  instances?: InstanceJson[];
  [key: string]: unknown;
}

export type TransportName = 'play' | 'pause' | 'step' | 'reset' | 'seek' | 'speed';

export interface TransportArgs {
  frames?: number;
  frame?: number;
  speed?: number;
  /** play: the frame to stop at. */
  until?: number;
}

/** One parameter's declaration (GET /api/parameters): the server's ParamSpec. */
export interface ParamSpecJson {
  name: string;
  unit: string;
  min: number;
  max: number;
  default: number | boolean;
  type: 'number' | 'integer' | 'boolean';
  help: string;
}

export interface RegisteredPartJson {
  help: string;
  params: ParamSpecJson[];
}

export interface ParametersJson {
  dimension: 2 | 3;
  instance: ParamSpecJson[];
  control: ParamSpecJson[];
  settings: ParamSpecJson[];
  solvers: Record<string, RegisteredPartJson>;
  effects: Record<string, RegisteredPartJson>;
}

/** GET /api/templates/{name}/preview: one frame's positions, flattened (dimension numbers each). */
export interface TemplatePreviewJson {
  name: string;
  dimension: 2 | 3;
  frame: number;
  frames: number;
  time: number;
  particles: number;
  stride: number;
  region_min: Vec;
  region_max: Vec;
  positions: number[];
}

/** PATCH /api/sessions/{id}/settings: merge patches of the scene's objects. */
export interface SettingsPatch {
  settings?: Record<string, unknown>;
  solver?: Record<string, unknown>;
  control?: Record<string, unknown>;
}

/** One accuracy preset of `flowclip bench accuracy` (GET /api/presets): the scene solver and settings values it sets, with the cost and error measured at that point of the study. */
export interface AccuracyPresetJson {
  name: string;
  description?: string;
  solver: Record<string, number | string>;
  settings: Record<string, number>;
  cost: Record<string, number>;
  error: Record<string, number>;
}

export interface PresetsJson {
  presets: AccuracyPresetJson[];
  source: string | null;
  /** Set when the server has no presets file (its path). */
  missing?: string;
}
