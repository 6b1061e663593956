// Removes an instance (DELETE .../instances/{name}); undo adds it back with
// every key it had (the server's full instance JSON) at its place in the scene
// order's end.
import { Command } from '../core/Command';
import type { Editor } from '../core/Editor';
import type { InstanceJson } from '../net/types';

export class RemoveInstanceCommand extends Command {
  readonly name: string;
  private readonly instance: InstanceJson;

  constructor(
    private readonly editor: Editor,
    instance: InstanceJson,
  ) {
    super();
    this.name = `Remove ${instance.name}`;
    this.instance = structuredClone(instance);
  }

  async execute() {
    const sid = this.editor.requireSession();
    await this.editor.api.removeInstance(sid, this.instance.name);
    this.editor.instanceRemoved(this.instance.name);
  }

  async undo() {
    const sid = this.editor.requireSession();
    const res = await this.editor.api.addInstance(sid, this.instance);
    this.editor.instanceUpdated(await this.editor.settleInstanceEdit(sid, this.instance.name, res));
  }
}
