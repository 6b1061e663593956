// Removes an instance (DELETE .../instances/{name}); undo adds it back with
// every key it had when it was removed (the server's full instance JSON,
// copied when the command runs, so that edits still landing before it are
// kept), at the end of the scene order.
import { Command } from '../core/Command';
import type { Editor } from '../core/Editor';
import type { InstanceJson } from '../net/types';

export class RemoveInstanceCommand extends Command {
  readonly name: string;
  private readonly sid: string;
  private removed: InstanceJson | null = null;

  constructor(
    private readonly editor: Editor,
    private readonly instanceName: string,
  ) {
    super();
    this.sid = editor.session?.id ?? '';
    this.name = `Remove ${instanceName}`;
  }

  async execute() {
    const sid = this.editor.sessionFor(this.sid);
    const current = this.editor.instances.get(this.instanceName);
    if (!current) throw new Error(`no instance ${this.instanceName}`);
    this.removed = structuredClone(current);
    const res = await this.editor.api.removeInstance(sid, this.instanceName);
    await this.editor.settleEdit(sid, res.edit); // 202: applied within a long frame
    this.editor.instanceRemoved(this.instanceName, sid);
  }

  async undo() {
    const sid = this.editor.sessionFor(this.sid);
    if (!this.removed) return;
    const res = await this.editor.api.addInstance(sid, this.removed);
    this.editor.instanceUpdated(await this.editor.settleInstanceEdit(sid, this.instanceName, res), sid);
  }
}
