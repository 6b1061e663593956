// Sets keys of an instance on the server: one key (an inspector field) or
// several at once, in one JSON merge patch {key: value, ...}, so that the
// server validates them together (a crop of the left end changes crop_begin
// and start, and neither alone is what the user asked for). Undo patches the
// old values back (null for a key that was absent, which removes it so that
// the server's default applies again).
//
// Merging: commands of the same instance and keys merge as any other command
// does (History: within 0.5 s of the previous one), so that quick changes of
// one field are one history entry. A drag passes `drag`, an id unique to the
// drag: the mergeKey is the drag's own and the merge window infinite (as
// SetInstanceTransformCommand's gizmo drags), so the whole drag is one
// history entry however long the user holds still in the middle of it, and
// two drags made in quick succession stay two entries.
import { Command } from '../core/Command';
import type { Editor } from '../core/Editor';

export type InstanceValues = Record<string, unknown>;

export class SetInstanceValuesCommand extends Command {
  readonly name: string;
  override readonly mergeKey: string;
  override readonly mergeWindowMs: number | null;
  private newValues: InstanceValues;
  private oldValues: InstanceValues;
  private readonly sid: string;

  constructor(
    private readonly editor: Editor,
    private readonly instance: string,
    newValues: InstanceValues,
    oldValues: InstanceValues,
    options: { name?: string; drag?: string } = {},
  ) {
    super();
    this.sid = editor.session?.id ?? '';
    const keys = Object.keys(newValues);
    this.name = options.name ?? `Set ${instance}.${keys.join(', ')}`;
    this.mergeKey = options.drag !== undefined ? `values:${instance}:drag:${options.drag}` : `values:${instance}.${[...keys].sort().join(',')}`;
    this.mergeWindowMs = options.drag !== undefined ? Infinity : null;
    this.newValues = structuredClone(newValues);
    this.oldValues = {};
    for (const k of keys) this.oldValues[k] = oldValues[k] === undefined ? null : structuredClone(oldValues[k]);
  }

  execute() {
    return this.apply(this.newValues);
  }

  undo() {
    return this.apply(this.oldValues);
  }

  /** The newer command's values win; the older's old values stay (a key first set by the newer keeps the newer's old value). */
  override merge(newer: Command) {
    const n = newer as SetInstanceValuesCommand;
    this.newValues = { ...this.newValues, ...n.newValues };
    this.oldValues = { ...n.oldValues, ...this.oldValues };
  }

  private async apply(values: InstanceValues) {
    const sid = this.editor.sessionFor(this.sid);
    const patch: Record<string, unknown> = values;
    const token = this.editor.previewPatch(this.instance, patch);
    try {
      const res = await this.editor.api.patchInstance(sid, this.instance, patch);
      this.editor.instanceUpdated(await this.editor.settleInstanceEdit(sid, this.instance, res), sid);
    } finally {
      this.editor.clearPreview(this.instance, token);
    }
  }
}
