// Recording recipes on the server (GET /api/recipes, /api/recipes/jobs/{id}):
// the recipes, and the jobs this editor follows, polled while they are queued
// or running. When a job has recorded its templates the editor re-reads the
// templates and scenes (onRecorded), then the recipes.
import type { Api } from '../net/Api';
import type { RecipeInfo, RecipeJob } from '../net/types';
import type { Signal } from './Signal';

/** How often a queued or running job is polled, ms (the server updates it every simulation frame). */
export const JOB_POLL_MS = 300;

export interface RecipeSignals {
  recipesChanged: Signal<RecipeInfo[]>;
  recipeJobChanged: Signal<RecipeJob>;
}

export function jobActive(job: RecipeJob | undefined): boolean {
  return job !== undefined && (job.state === 'queued' || job.state === 'running');
}

export class RecipeRecorder {
  recipes: RecipeInfo[] = [];
  /** The newest job of each recipe (by recipe name) this editor started or found running. */
  readonly jobs = new Map<string, RecipeJob>();
  /** Ids being polled: one poll chain per job. */
  private readonly followed = new Set<string>();

  constructor(
    private readonly api: Api,
    private readonly signals: RecipeSignals,
    private readonly onRecorded: () => Promise<unknown>,
    private readonly reportError: (e: unknown, what: string) => void,
  ) {}

  async load(): Promise<RecipeInfo[]> {
    try {
      this.recipes = await this.api.listRecipes();
    } catch (e) {
      this.reportError(e, 'list recipes');
      this.recipes = [];
    }
    // Jobs already running (started by another editor, or before a reload) are followed too.
    for (const r of this.recipes) if (r.job) this.follow(r.job);
    this.signals.recipesChanged.dispatch(this.recipes);
    return this.recipes;
  }

  /** Starts recording recipe `name` (or joins its queued or running job). */
  async record(name: string, force = false): Promise<RecipeJob | null> {
    try {
      const job = await this.api.recordRecipe(name, force);
      this.update(job);
      if (jobActive(job)) this.follow(job.id);
      return job;
    } catch (e) {
      this.reportError(e, `record recipe ${name}`);
      return null;
    }
  }

  async cancel(recipe: string): Promise<void> {
    const job = this.jobs.get(recipe);
    if (!job) return;
    try {
      this.update(await this.api.cancelRecipeJob(job.id));
    } catch (e) {
      this.reportError(e, `cancel recording ${recipe}`);
    }
  }

  private follow(id: string) {
    if (this.followed.has(id)) return;
    this.followed.add(id);
    const poll = async () => {
      try {
        const job = await this.api.recipeJob(id);
        this.update(job);
        if (jobActive(job)) {
          setTimeout(() => void poll(), JOB_POLL_MS);
          return;
        }
      } catch (e) {
        this.reportError(e, `follow recording job ${id}`);
      }
      this.followed.delete(id);
    };
    setTimeout(() => void poll(), JOB_POLL_MS);
  }

  private update(job: RecipeJob) {
    const before = this.jobs.get(job.recipe);
    // A late answer about an older job does not replace the newer one.
    if (before && before.id !== job.id && jobNumber(before.id) > jobNumber(job.id)) return;
    this.jobs.set(job.recipe, job);
    this.signals.recipeJobChanged.dispatch(job);
    const changed = before?.id !== job.id || before.state !== job.state;
    if (!changed) return;
    if (job.state === 'done') void this.onRecorded().then(() => this.load());
    if (job.state === 'failed') this.reportError(new Error(job.error ?? 'failed'), `record recipe ${job.recipe}`);
  }
}

function jobNumber(id: string): number {
  return Number(id.slice(1)) || 0;
}
