// Sets one key of an instance on the server (a JSON merge patch {key: value};
// undo patches the old value back, or null, which removes the key so that the
// server's default applies again). Successive changes of the same key merge.
import { Command } from '../core/Command';
import type { Editor } from '../core/Editor';

export class SetInstanceValueCommand extends Command {
  readonly name: string;
  override readonly mergeKey: string;
  private newValue: unknown;
  private readonly sid: string;

  constructor(
    private readonly editor: Editor,
    private readonly instance: string,
    private readonly key: string,
    newValue: unknown,
    private readonly oldValue: unknown,
  ) {
    super();
    this.sid = editor.session?.id ?? '';
    this.name = `Set ${instance}.${key}`;
    this.mergeKey = `value:${instance}.${key}`;
    this.newValue = structuredClone(newValue);
    this.oldValue = oldValue === undefined ? null : structuredClone(oldValue);
  }

  execute() {
    return this.apply(this.newValue);
  }

  undo() {
    return this.apply(this.oldValue);
  }

  override merge(newer: Command) {
    this.newValue = (newer as SetInstanceValueCommand).newValue;
  }

  private async apply(value: unknown) {
    const sid = this.editor.sessionFor(this.sid);
    const patch: Record<string, unknown> = { [this.key]: value };
    const token = this.editor.previewPatch(this.instance, patch);
    try {
      const res = await this.editor.api.patchInstance(sid, this.instance, patch);
      this.editor.instanceUpdated(await this.editor.settleInstanceEdit(sid, this.instance, res), sid);
    } finally {
      this.editor.clearPreview(this.instance, token);
    }
  }
}
