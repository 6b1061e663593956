// Changes scene-level settings (PATCH .../settings: merge patches of the
// scene's "solver", "settings" and "control" objects); undo patches the old
// values back (null removes a key that was absent, so the default applies).
// Successive changes of the same keys merge (typing in a field).
import { Command } from '../core/Command';
import type { Editor } from '../core/Editor';
import type { SettingsPatch } from '../net/types';

export class SetSceneSettingsCommand extends Command {
  readonly name: string;
  override readonly mergeKey: string;
  private patch: SettingsPatch;
  private readonly old: SettingsPatch;
  private readonly sid: string;

  constructor(
    private readonly editor: Editor,
    patch: SettingsPatch,
    old: SettingsPatch,
  ) {
    super();
    this.sid = editor.session?.id ?? '';
    const keys = Object.entries(patch).flatMap(([group, obj]) => Object.keys(obj ?? {}).map((k) => `${group}.${k}`));
    this.name = `Set ${keys.join(', ')}`;
    this.mergeKey = `settings:${keys.sort().join(',')}`;
    this.patch = structuredClone(patch);
    this.old = structuredClone(old);
  }

  execute() {
    return this.editor.applySettings(this.patch, this.sid);
  }

  undo() {
    return this.editor.applySettings(this.old, this.sid);
  }

  override merge(newer: Command) {
    this.patch = (newer as SetSceneSettingsCommand).patch;
  }
}
