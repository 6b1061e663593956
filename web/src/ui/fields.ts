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

export type Commit = (value: unknown) => void;
export type Complain = (text: string) => void;

/** Up to 6 significant digits, no trailing zeros. */
export function formatNumber(v: number): string {
  if (!Number.isFinite(v)) return String(v);
  return String(Number(v.toPrecision(6)));
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
  input.addEventListener('input', () => (typing = true));
  input.addEventListener('change', () => {
    typing = false;
    const text = input.value.trim();
    if (text === '' && opts.allowEmpty) {
      commit(null);
      return;
    }
    const v = Number(text);
    if (text === '' || !Number.isFinite(v)) {
      complain(`${label}: "${text}" is not a number`);
      input.value = shown;
      return;
    }
    commit(opts.integer ? Math.round(v) : v);
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
      shown = typeof value === 'number' ? formatNumber(value) : value === null || value === undefined ? '' : String(value);
      input.dataset['value'] = shown;
      if (!typing || document.activeElement !== input) input.value = shown;
    },
    setEnabled(on: boolean) {
      input.disabled = !on;
    },
  };
}

export function checkboxField(testid: string, label: string, title: string, commit: Commit): Field {
  const input = el('input', { testid, attrs: { type: 'checkbox' } });
  input.addEventListener('change', () => commit(input.checked));
  return {
    row: row(label, title, input, '', testid),
    input,
    show(value: unknown) {
      input.checked = value === true;
      input.dataset['value'] = String(value === true);
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
  input.addEventListener('change', () => commit(input.value));
  return {
    row: row(label, title, input, '', testid),
    input,
    show(value: unknown) {
      const v = String(value ?? '');
      if (![...input.options].some((o) => o.value === v)) setOptions([...[...input.options].map((o) => o.value), v]);
      input.value = v;
      input.dataset['value'] = v;
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
