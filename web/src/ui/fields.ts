// Inspector fields: a label, an input and a unit, with the value shown kept
// in step with the document (never overwritten while the user types in it).
// A field commits on `change` (Enter or leaving it); the owner turns the
// value into a Command. Values the field cannot read (not a number) are
// reported and the field reverts; range checks are the server's (its error
// message names the key), so the user sees exactly what the server says.
import type { ParamSpecJson } from '../net/types';
import { el } from './dom';

export interface Field {
  readonly row: HTMLElement;
  readonly input: HTMLInputElement | HTMLSelectElement;
  /** Shows `value` (unless the user is editing the field). */
  show(value: unknown): void;
  setEnabled(on: boolean): void;
}

/**
 * Applies a value; a returned promise keeps the field showing what the user
 * chose until it settles (the document then says what was accepted), so a
 * signal arriving meanwhile does not flip a checkbox back.
 */
export type Commit = (value: unknown) => Promise<void> | void;
export type Complain = (text: string) => void;

/** Up to 6 significant digits, no trailing zeros. */
export function formatNumber(v: number): string {
  if (!Number.isFinite(v)) return String(v);
  return String(Number(v.toPrecision(6)));
}

/** The field's pending state around a commit: `show` is deferred while one is in flight. */
class Pending {
  private count = 0;
  private last: { value: unknown } | null = null;
  constructor(private readonly apply: (v: unknown) => void) {}
  run(commit: Commit, value: unknown) {
    const r = commit(value);
    if (!(r instanceof Promise)) return;
    this.count++;
    void r.finally(() => {
      if (--this.count === 0 && this.last) this.apply(this.last.value);
    });
  }
  show(value: unknown) {
    this.last = { value };
    if (this.count === 0) this.apply(value);
  }
}

function row(label: string, title: string, input: HTMLElement, unit: string, testid: string): HTMLElement {
  return el('label', { className: 'field-row', title, testid: `${testid}-row` }, [
    el('span', { className: 'field-label', text: label }),
    input,
    el('span', { className: 'field-unit', text: unit }),
  ]);
}

/** A number input. `allowEmpty`: an empty field commits null (the key's default, e.g. crop_end = template end). */
export function numberField(
  testid: string, label: string, unit: string, title: string, commit: Commit, complain: Complain,
  opts: { step?: number; integer?: boolean; allowEmpty?: boolean; placeholder?: string } = {},
): Field {
  const input = el('input', { testid, attrs: { type: 'text', inputmode: 'decimal', spellcheck: 'false' } });
  if (opts.placeholder) input.placeholder = opts.placeholder;
  let shown = '';
  // True while the user types (between an input and its change): the value
  // shown is then left alone; after a commit the server's answer shows,
  // even in the focused field (a refused value reverts).
  let typing = false;
  const pending = new Pending((value) => {
    shown = typeof value === 'number' ? formatNumber(value) : value === null || value === undefined ? '' : String(value);
    input.dataset['value'] = shown;
    if (!typing || document.activeElement !== input) input.value = shown;
  });
  input.addEventListener('input', () => (typing = true));
  input.addEventListener('change', () => {
    typing = false;
    const text = input.value.trim();
    if (text === '' && opts.allowEmpty) {
      pending.run(commit, null);
      return;
    }
    const v = Number(text);
    if (text === '' || !Number.isFinite(v)) {
      complain(`${label}: "${text}" is not a number`);
      input.value = shown;
      return;
    }
    pending.run(commit, opts.integer ? Math.round(v) : v);
  });
  input.addEventListener('keydown', (e) => {
    if (e.key === 'Escape') {
      typing = false;
      input.value = shown;
      input.blur();
    }
  });
  return {
    row: row(label, title, input, unit, testid),
    input,
    show(value: unknown) {
      pending.show(value);
    },
    setEnabled(on: boolean) {
      input.disabled = !on;
    },
  };
}

export function checkboxField(testid: string, label: string, title: string, commit: Commit): Field {
  const input = el('input', { testid, attrs: { type: 'checkbox' } });
  const pending = new Pending((value) => {
    input.checked = value === true;
    input.dataset['value'] = String(value === true);
  });
  input.addEventListener('change', () => pending.run(commit, input.checked));
  return {
    row: row(label, title, input, '', testid),
    input,
    show(value: unknown) {
      pending.show(value);
    },
    setEnabled(on: boolean) {
      input.disabled = !on;
    },
  };
}

export function selectField(testid: string, label: string, title: string, options: string[], commit: Commit): Field {
  const input = el('select', { testid });
  const setOptions = (names: string[]) => {
    input.replaceChildren(...names.map((n) => el('option', { text: n, attrs: { value: n } })));
  };
  setOptions(options);
  const pending = new Pending((value) => {
    const v = String(value ?? '');
    if (![...input.options].some((o) => o.value === v)) setOptions([...[...input.options].map((o) => o.value), v]);
    input.value = v;
    input.dataset['value'] = v;
  });
  input.addEventListener('change', () => pending.run(commit, input.value));
  return {
    row: row(label, title, input, '', testid),
    input,
    show(value: unknown) {
      pending.show(value);
    },
    setEnabled(on: boolean) {
      input.disabled = !on;
    },
  };
}

/** A field for a declared parameter: checkbox for booleans, number otherwise; its title is the declaration's help and range. */
export function paramField(prefix: string, spec: ParamSpecJson, commit: Commit, complain: Complain): Field {
  const testid = `${prefix}-${spec.name}`;
  const range = spec.type === 'boolean' ? '' : ` [${formatNumber(spec.min)}, ${formatNumber(spec.max)}]`;
  const title = `${spec.name}: ${spec.help}${range}; default ${String(spec.default)}`;
  const label = spec.name.replace(/_/g, ' ');
  if (spec.type === 'boolean') return checkboxField(testid, label, title, commit);
  return numberField(testid, label, spec.unit, title, commit, complain, { integer: spec.type === 'integer' });
}
