// Adds a template instance to the session (POST .../instances); undo removes
// it, redo adds it again with the same name and keys.
import { Command } from '../core/Command';
import type { Editor } from '../core/Editor';
import type { InstanceJson } from '../net/types';

export class AddInstanceCommand extends Command {
  readonly name: string;
  private readonly instance: Partial<InstanceJson> & { template: string; name: string };
  private readonly sid: string;

  constructor(
    private readonly editor: Editor,
    instance: Partial<InstanceJson> & { template: string; name: string },
  ) {
    super();
    this.sid = editor.session?.id ?? '';
    this.name = `Add ${instance.name}`;
    this.instance = structuredClone(instance);
  }

  async execute() {
    const sid = this.editor.sessionFor(this.sid);
    try {
      const res = await this.editor.api.addInstance(sid, this.instance);
      this.editor.instanceUpdated(await this.editor.settleInstanceEdit(sid, this.instance.name, res), sid);
    } finally {
      this.editor.releaseName(this.instance.name);
    }
    if (sid === this.editor.session?.id) this.editor.select(this.instance.name);
  }

  async undo() {
    const sid = this.editor.sessionFor(this.sid);
    await this.editor.api.removeInstance(sid, this.instance.name);
    this.editor.instanceRemoved(this.instance.name, sid);
  }
}
