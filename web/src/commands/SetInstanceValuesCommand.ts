// Sets several keys of an instance at once on the server (one JSON merge
// patch {key: value, ...}, so that the server validates them together: a
// crop of the left end changes crop_begin and start, and neither alone is
// what the user asked for). Undo patches the old values back (null for a key
// that was absent, which removes it so that the server's default applies).
//
// Merging: commands of the same mergeKey merge as any other command does
// (History: within 0.5 s of the previous one). A drag passes a `gesture`:
// the mergeKey is the gesture's own and every command of the gesture carries
// the gesture's start time, so the whole drag is one history entry however
// long the user holds still in the middle of it, and two drags made in quick
// succession stay two entries.
import { Command } from '../core/Command';
import type { Editor } from '../core/Editor';

export type InstanceValues = Record<string, unknown>;

/** One pointer drag (or any other continuous edit) that must be one undo step. */
export interface Gesture {
  /** Unique per gesture, e.g. "timeline:drop:crop-end:7". */
  readonly id: string;
  /** performance.now() when the gesture began. */
  readonly startedAt: number;
}

export class SetInstanceValuesCommand extends Command {
  readonly name: string;
  override readonly mergeKey: string;
  private newValues: InstanceValues;
  private oldValues: InstanceValues;

  constructor(
    private readonly editor: Editor,
    private readonly instance: string,
    newValues: InstanceValues,
    oldValues: InstanceValues,
    options: { name?: string; gesture?: Gesture } = {},
  ) {
    super();
    const keys = Object.keys(newValues);
    this.name = options.name ?? `Set ${instance}.${keys.join(', ')}`;
    this.mergeKey = options.gesture ? `values:${instance}:${options.gesture.id}` : `values:${instance}.${keys.sort().join(',')}`;
    if (options.gesture) this.createdAt = options.gesture.startedAt;
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
    const sid = this.editor.requireSession();
    const res = await this.editor.api.patchInstance(sid, this.instance, values);
    this.editor.instanceUpdated(res.instance);
  }
}
