// The outliner (right panel, top): the scene's instances in scene order with
// their template and whether they play at the frame shown, ⚠ on one that
// steers no liquid (the title says why); click selects, ✕ removes (an
// undoable command).
import type { Editor } from '../core/Editor';
import { RemoveInstanceCommand } from '../commands/RemoveInstanceCommand';
import type { FrameInfo } from '../net/FrameDecoder';
import { el } from './dom';

export class Outliner {
  readonly dom: HTMLElement;
  private readonly list: HTMLElement;
  private active = new Set<string>();

  constructor(private readonly editor: Editor) {
    this.list = el('div', { className: 'outliner-list', testid: 'outliner-list' });
    this.dom = el('section', { className: 'panel outliner', testid: 'outliner' }, [el('h2', { text: 'Instances' }), this.list]);
    editor.signals.instancesChanged.add(() => this.render());
    editor.signals.selectionChanged.add(() => this.render());
    editor.signals.issuesChanged.add(() => this.render());
    editor.signals.frameDecoded.add((f) => this.onFrame(f));
    this.render();
  }

  private onFrame(f: FrameInfo) {
    // Re-render only when the set of playing instances changed (no allocation otherwise).
    let same = true, n = 0;
    for (let k = 0; k < f.instanceCount; k++) {
      if (!f.instances[k]!.active) continue;
      n++;
      if (!this.active.has(f.instances[k]!.name)) same = false;
    }
    if (same && n === this.active.size) return;
    this.active = new Set();
    for (let k = 0; k < f.instanceCount; k++) if (f.instances[k]!.active) this.active.add(f.instances[k]!.name);
    this.render();
  }

  private render() {
    const e = this.editor;
    this.list.replaceChildren();
    if (e.instances.size === 0) {
      this.list.append(el('div', { className: 'empty', text: e.session ? 'No instances: add a template from the library' : 'No scene open' }));
      return;
    }
    for (const inst of e.instances.values()) {
      const remove = el('button', { text: '✕', testid: `outliner-remove-${inst.name}`, title: `Remove ${inst.name}`, attrs: { type: 'button' } });
      remove.addEventListener('click', (ev) => {
        ev.stopPropagation();
        void e.execute(new RemoveInstanceCommand(e, inst.name));
      });
      const active = this.active.has(inst.name);
      const issue = e.issues.get(inst.name);
      const item = el('div', {
        className: `outliner-item${inst.name === e.selected ? ' selected' : ''}${issue ? ' warning' : ''}`,
        testid: `outliner-item-${inst.name}`,
        title: `${active ? 'playing at the frame shown' : 'not playing at the frame shown'}${issue ? `\n⚠ ${inst.name} ${issue}` : ''}`,
      }, [
        el('span', { className: `dot${active ? ' active' : ''}` }),
        el('span', { className: 'outliner-name', text: inst.name }),
        ...(issue ? [el('span', { className: 'outliner-warning', testid: `outliner-warning-${inst.name}`, text: '⚠', title: `${inst.name} ${issue}` })] : []),
        el('span', { className: 'outliner-template', text: inst.template }),
        remove,
      ]);
      item.addEventListener('click', () => e.select(inst.name));
      this.list.append(item);
    }
  }
}
