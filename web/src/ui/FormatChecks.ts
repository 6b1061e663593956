// Checkboxes of the surface formats the server can write: the exporters GET
// /api/parameters registers (a fixed list until it answers). The Export and
// Render final dialogs both offer them. Acts only through the editor's signals.
import type { Editor } from '../core/Editor';
import { el } from './dom';

const FALLBACK_FORMATS = ['vdb', 'ply', 'points', 'obj', 'usd'];

export class FormatChecks {
  readonly dom: HTMLElement;

  /** `prefix`: test ids `${prefix}-formats` and `${prefix}-format-NAME`; `defaults`: checked until the user changes them. */
  constructor(
    private readonly editor: Editor,
    private readonly prefix: string,
    private readonly defaults: ReadonlySet<string>,
  ) {
    this.dom = el('div', { className: 'export-formats', testid: `${prefix}-formats` });
    editor.signals.parametersChanged.add(() => this.render());
    this.render();
  }

  checked(): string[] {
    return [...this.dom.querySelectorAll<HTMLInputElement>('input[type=checkbox]')].filter((b) => b.checked).map((b) => b.value);
  }

  private render() {
    const exporters = this.editor.parameters?.exporters;
    const names = exporters ? Object.keys(exporters) : FALLBACK_FORMATS;
    // A re-render (the other dimension's registry) keeps what the user checked.
    const boxes = this.dom.querySelectorAll('input[type=checkbox]');
    const checked = new Set(boxes.length ? this.checked() : this.defaults);
    this.dom.replaceChildren(
      ...names.map((n) => {
        const box = el('input', { testid: `${this.prefix}-format-${n}`, attrs: { type: 'checkbox', value: n } });
        box.checked = checked.has(n);
        return el('label', { title: exporters?.[n]?.help ?? n }, [box, ` ${n}`]);
      }),
    );
  }
}
