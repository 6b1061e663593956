// Replaces an instance's transform track on the server (PATCH
// /api/sessions/{id}/instances/{name} with {transform}); undo PATCHes the
// old track back. The new track is built when the command runs, from the
// track the instance has then (a function of the current track), so that
// edits issued in quick succession never overwrite each other with stale
// copies; the old track is the one found at the first run. A gizmo drag
// issues one per pointer move; they merge into one history entry.
import { Command } from '../core/Command';
import type { Editor } from '../core/Editor';
import type { TransformKey } from '../net/types';

export type TrackEdit = TransformKey[] | ((current: TransformKey[]) => TransformKey[]);

export class SetInstanceTransformCommand extends Command {
  readonly name: string;
  override readonly mergeKey: string | null;
  override readonly mergeWindowMs: number | null;
  private readonly sid: string;
  private edit: TrackEdit;
  private resolved: TransformKey[] | null = null;
  private oldValue: TransformKey[] | undefined;

  /**
   * `drag`: an id unique to one drag (gizmo, key); its commands all merge, however
   * slow the drag. `options.name` / `options.merge = false`: a distinct entry
   * (adding or removing a key never merges with a move).
   */
  constructor(
    private readonly editor: Editor,
    private readonly instance: string,
    edit: TrackEdit,
    oldValue?: TransformKey[],
    drag?: number | string,
    options: { name?: string; merge?: boolean } = {},
  ) {
    super();
    this.sid = editor.session?.id ?? '';
    this.name = options.name ?? `Move ${instance}`;
    this.mergeKey = options.merge === false ? null : drag === undefined ? `transform:${instance}` : `transform:${instance}:drag${drag}`;
    this.mergeWindowMs = drag === undefined ? null : Infinity;
    this.edit = typeof edit === 'function' ? edit : structuredClone(edit);
    this.oldValue = oldValue === undefined ? undefined : structuredClone(oldValue);
  }

  execute() {
    if (!this.resolved) {
      const current = this.editor.instances.get(this.instance)?.transform ?? [];
      if (this.oldValue === undefined) this.oldValue = structuredClone(current);
      this.resolved = typeof this.edit === 'function' ? this.edit(structuredClone(current)) : this.edit;
    }
    return this.apply(this.resolved);
  }

  undo() {
    return this.apply(this.oldValue ?? []);
  }

  override merge(newer: Command) {
    const n = newer as SetInstanceTransformCommand;
    this.edit = n.edit;
    this.resolved = n.resolved;
  }

  private async apply(transform: TransformKey[]) {
    const sid = this.editor.sessionFor(this.sid);
    const current = this.editor.instances.get(this.instance);
    // The viewport shows the new track while the server answers.
    const token = current ? this.editor.setPreview({ ...current, transform: structuredClone(transform) }) : 0;
    try {
      const res = await this.editor.api.patchInstance(sid, this.instance, { transform });
      this.editor.instanceUpdated(await this.editor.settleInstanceEdit(sid, this.instance, res), sid);
    } finally {
      if (current) this.editor.clearPreview(this.instance, token);
    }
  }
}
