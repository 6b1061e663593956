// Replaces an instance's transform track on the server (PATCH
// /api/sessions/{id}/instances/{name} with {transform}); undo PATCHes the
// old track back. A gizmo drag issues one per pointer move; they merge into
// one history entry.
import { Command } from '../core/Command';
import type { Editor } from '../core/Editor';
import type { TransformKey } from '../net/types';

export class SetInstanceTransformCommand extends Command {
  readonly name: string;
  override readonly mergeKey: string;
  override readonly mergeWindowMs: number | null;
  private newValue: TransformKey[];

  /** `drag`: an id unique to one gizmo drag; its commands all merge, however slow the drag. */
  constructor(
    private readonly editor: Editor,
    private readonly instance: string,
    newValue: TransformKey[],
    private readonly oldValue: TransformKey[],
    drag?: number,
  ) {
    super();
    this.name = `Move ${instance}`;
    this.mergeKey = drag === undefined ? `transform:${instance}` : `transform:${instance}:drag${drag}`;
    this.mergeWindowMs = drag === undefined ? null : Infinity;
    this.newValue = structuredClone(newValue);
    this.oldValue = structuredClone(oldValue);
  }

  execute() {
    return this.apply(this.newValue);
  }

  undo() {
    return this.apply(this.oldValue);
  }

  override merge(newer: Command) {
    this.newValue = (newer as SetInstanceTransformCommand).newValue;
  }

  private async apply(transform: TransformKey[]) {
    const sid = this.editor.requireSession();
    const res = await this.editor.api.patchInstance(sid, this.instance, { transform });
    this.editor.instanceUpdated(await this.editor.settleInstanceEdit(sid, this.instance, res));
  }
}
