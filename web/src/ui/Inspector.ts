// The inspector (right panel): the selected instance's transform at the
// playhead, rounded (0.1 mm, 0.01°, 1e-4), marked keyed (a key is at the
// playhead) or animated (interpolated between keys), with keyframes added
// and removed there; an edit keys it (auto-key on) or moves an animated
// track as a whole (off); a warning when it steers no liquid; its time map (start,
// crop, speed, reverse), its phase and its control parameters; below, the
// scene's solver, simulation and control settings. Parameter fields are
// built from the server's declarations (GET /api/parameters: name, unit,
// range, default, help), the same ones the scene parser validates with.
// Every change is a Command executed through the hub.
import type { Editor } from '../core/Editor';
import { SetInstanceTransformCommand } from '../commands/SetInstanceTransformCommand';
import { SetInstanceValuesCommand } from '../commands/SetInstanceValuesCommand';
import { SetSceneSettingsCommand } from '../commands/SetSceneSettingsCommand';
import { addKeyAt, editTrack, evaluateTrack, keyIndexAt, removeKeyAt, type FullKey } from '../core/TransformTrack';
import { instanceValue, type AccuracyPresetJson, type InstanceJson, type ParametersJson, type ParamSpecJson, type SettingsPatch, type TransformKey } from '../net/types';
import { el } from './dom';
import { checkboxField, formatNumber, numberField, paramField, selectField, type Field } from './fields';

const AXES = ['x', 'y', 'z'];

type SettingsGroup = 'solver' | 'settings' | 'control';

/** How the study's figures read (GET /api/presets: cost and error keys). */
const FIGURES: Record<string, [string, number]> = {
  us_per_particle_step: ['µs per particle-step', 2],
  ms_per_frame: ['ms per frame', 1],
  wall_s_per_sim_s: ['wall s per simulated s', 2],
  avg_density_error_pct: ['% average density error', 3],
  max_density_error_pct: ['% largest density error', 2],
  volume_drift_pct: ['% volume drift', 2],
  surge_front_rms: ['surge front RMS error (x/a, Martin & Moyce)', 3],
};

function figures(values: Record<string, number>): string[] {
  return Object.entries(values).map(([k, v]) => {
    const [label, digits] = FIGURES[k] ?? [k.replace(/_/g, ' '), 3];
    return `${v.toFixed(digits)} ${label}`;
  });
}

/** "draft: 1.52 µs per particle-step, 0.800 % average density error" (the option text: cost and the headline error). */
function presetLabel(p: AccuracyPresetJson): string {
  const pick = (values: Record<string, number>, key: string) =>
    figures(key in values ? { [key]: values[key]! } : values)[0] ?? '';
  const cost = pick(p.cost, 'us_per_particle_step');
  const err = pick(p.error, 'avg_density_error_pct');
  return `${p.name}: ${cost}${err ? `, ${err}` : ''}`;
}

export class Inspector {
  readonly dom: HTMLElement;
  private readonly instanceBox: HTMLElement;
  private readonly sceneBox: HTMLElement;
  private readonly header: HTMLElement;
  private readonly warning: HTMLElement;
  private readonly keyInfo: HTMLElement;
  private readonly addKey: HTMLButtonElement;
  private readonly removeKey: HTMLButtonElement;
  /** Instance fields by instance key (transform fields under "transform.translation.0" etc.). */
  private fields = new Map<string, Field>();
  private readonly paramBox: HTMLElement;
  private paramsFor: ParametersJson | null = null;
  private sceneFields = new Map<string, Field>();
  private sceneFieldsFor = '';
  private presetField: Field | null = null;
  private readonly presetFigures: HTMLElement;

  constructor(private readonly editor: Editor) {
    this.header = el('div', { className: 'inspector-header', testid: 'inspector-header' });
    this.keyInfo = el('span', { className: 'key-info', testid: 'inspector-key-info' });
    this.warning = el('div', { className: 'inspector-warning', testid: 'inspector-warning' });
    this.addKey = el('button', { text: '◆ key', testid: 'inspector-add-key', title: 'Add a keyframe at the playhead holding the transform there', attrs: { type: 'button' } });
    this.removeKey = el('button', { text: '◇ key', testid: 'inspector-remove-key', title: 'Remove the keyframe at the playhead', attrs: { type: 'button' } });
    this.addKey.addEventListener('click', () => this.keyAtPlayhead(true));
    this.removeKey.addEventListener('click', () => this.keyAtPlayhead(false));
    this.paramBox = el('div', { className: 'inspector-group' });
    this.instanceBox = el('div', { className: 'inspector-instance', testid: 'inspector-instance' });
    this.sceneBox = el('div', { className: 'inspector-scene', testid: 'inspector-scene' });
    this.presetFigures = el('div', { className: 'preset-figures', testid: 'scene-preset-figures' });
    this.dom = el('section', { className: 'panel inspector', testid: 'inspector' }, [
      el('h2', { text: 'Inspector' }),
      this.instanceBox,
      el('h2', { text: 'Scene settings' }),
      this.sceneBox,
    ]);
    this.buildInstanceFields();

    editor.signals.selectionChanged.add(() => this.update());
    editor.signals.instancesChanged.add(() => this.update());
    editor.signals.playheadChanged.add(() => this.update()); // the transform at the playhead
    editor.signals.issuesChanged.add(() => this.update());
    editor.signals.autoKeyChanged.add(() => this.update());
    editor.signals.presetsChanged.add(() => {
      this.buildSceneFields();
      this.update();
    });
    editor.signals.parametersChanged.add(() => {
      this.buildParamFields();
      this.buildSceneFields();
      this.update();
    });
    editor.signals.sceneChanged.add(() => this.updateScene());
    editor.signals.sessionChanged.add(() => {
      this.buildInstanceFields();
      this.buildParamFields();
      this.buildSceneFields();
      this.update();
    });
    this.update();
  }

  // ------------------------------------------------------------ instance ---

  private selectedInstance(): InstanceJson | null {
    const e = this.editor;
    return e.selected ? e.instances.get(e.selected) ?? null : null;
  }

  private dim(): 2 | 3 {
    return this.editor.session?.dimension ?? 2;
  }

  private tolerance(): number {
    return 0.5 / this.editor.frameRate();
  }

  private complain = (text: string) => this.editor.message('error', text);

  private buildInstanceFields() {
    const dim = this.dim();
    this.fields = new Map();
    const transform = el('div', { className: 'inspector-group' });
    const addTransform = (what: 'translation' | 'rotation' | 'scale', label: string, unit: string, n: number) => {
      for (let d = 0; d < n; d++) {
        const axis = what === 'rotation' && dim === 2 ? '' : ` ${AXES[d]}`;
        const f = numberField(`inspector-${what}-${d}`, `${label}${axis}`, unit, `${label} at the playhead`, (v) =>
          this.editTransform((k) => {
            k[what][d] = v as number;
          }), this.complain);
        this.fields.set(`transform.${what}.${d}`, f);
        transform.append(f.row);
      }
    };
    addTransform('translation', 'position', 'm', dim);
    addTransform('rotation', 'rotation', '°', dim === 2 ? 1 : 3);
    addTransform('scale', 'scale', '×', dim);
    for (let d = 0; d < dim; d++) {
      const f = checkboxField(`inspector-reflect-${d}`, `reflect ${AXES[d]}`, `Mirror the template along its ${AXES[d]} axis`, (v) =>
        this.editTransform((k) => {
          k.reflect[d] = v as boolean;
        }));
      this.fields.set(`transform.reflect.${d}`, f);
      transform.append(f.row);
    }
    transform.append(el('div', { className: 'key-row' }, [this.keyInfo, this.addKey, this.removeKey]));

    const time = el('div', { className: 'inspector-group' });
    const timeField = (key: string, label: string, unit: string, title: string, allowEmpty = false, placeholder = '') => {
      const f = numberField(`inspector-${key}`, label, unit, title, (v) => this.setValue(key, v), this.complain, { allowEmpty, placeholder });
      this.fields.set(key, f);
      time.append(f.row);
    };
    timeField('start', 'start', 's', 'Scene time the instance starts playing');
    timeField('crop_begin', 'crop begin', 's', 'Template time the instance starts from');
    timeField('crop_end', 'crop end', 's', 'Template time the instance ends at (empty: the template\'s end)', true, 'end');
    timeField('speed', 'speed', '×', 'Template seconds per scene second (> 0)');
    const reverse = checkboxField('inspector-reverse', 'reverse', 'Play the template backwards', (v) => this.setValue('reverse', v));
    this.fields.set('reverse', reverse);
    time.append(reverse.row);
    const phase = selectField('inspector-phase', 'phase', 'The liquid phase this instance controls', [], (v) => this.setValue('phase', v));
    this.fields.set('phase', phase);
    time.append(phase.row);

    this.instanceBox.replaceChildren(
      this.header,
      this.warning,
      el('h3', { text: 'Transform at the playhead' }),
      transform,
      el('h3', { text: 'Time' }),
      time,
      el('h3', { text: 'Control' }),
      this.paramBox,
    );
  }

  /** Control parameters from the declarations (rebuilt when they arrive or the dimension changes). */
  private buildParamFields() {
    const p = this.editor.parameters;
    if (p === this.paramsFor) return;
    this.paramsFor = p;
    for (const key of [...this.fields.keys()]) if (key.startsWith('param.')) this.fields.delete(key);
    this.paramBox.replaceChildren();
    if (!p) return;
    for (const spec of p.instance) {
      const f = paramField('inspector', spec, (v) => this.setValue(spec.name, v), this.complain);
      this.fields.set(`param.${spec.name}`, f);
      this.paramBox.append(f.row);
    }
  }

  private update() {
    const inst = this.selectedInstance();
    this.instanceBox.hidden = inst === null;
    this.updateScene();
    if (!inst) return;
    const e = this.editor, dim = this.dim(), t = e.playheadTime();
    const centre = e.templateCentre(inst.template);
    const info = e.templateInfo(inst.template);
    this.header.textContent = `${inst.name} · ${inst.template}${info?.duration !== undefined ? ` (${formatNumber(info.duration)} s)` : ''}`;
    this.header.dataset['value'] = inst.name;
    const issue = e.issues.get(inst.name) ?? null;
    this.warning.hidden = issue === null;
    this.warning.textContent = issue ? `⚠ ${inst.name} ${issue}` : '';
    const k = evaluateTrack(inst.transform, t, dim, centre);
    const keys = inst.transform ?? [];
    const at = keyIndexAt(keys, t, this.tolerance());
    // Keyed: the value of the key here; animated: interpolated between keys (Blender's yellow and green).
    const state = keys.length > 1 ? (at >= 0 ? 'keyed' : 'animated') : '';
    const digits = { translation: 4, rotation: 2, scale: 4 } as const;
    for (const what of ['translation', 'rotation', 'scale'] as const)
      k[what].forEach((v, d) => {
        const f = this.fields.get(`transform.${what}.${d}`);
        if (!f) return;
        f.show(Number(v.toFixed(digits[what])));
        f.row.dataset['state'] = state;
      });
    k.reflect.forEach((v, d) => this.fields.get(`transform.reflect.${d}`)?.show(v));
    this.keyInfo.textContent = `frame ${e.playheadFrame} · ${keys.length} key${keys.length === 1 ? '' : 's'}${at >= 0 ? ' · ◆ here' : keys.length > 1 ? ' · interpolated' : ''}` +
      `${keys.length > 1 && !e.autoKey ? ' · auto-key off: edits move the whole track' : ''}`;
    this.keyInfo.dataset['keys'] = String(keys.length);
    this.keyInfo.dataset['here'] = String(at >= 0);
    this.removeKey.disabled = at < 0;
    for (const key of ['start', 'crop_begin', 'crop_end', 'speed', 'reverse'] as const)
      this.fields.get(key)?.show(key === 'crop_end' && (inst.crop_end === undefined || inst.crop_end < 0) ? null : inst[key]);
    const phases = (e.session?.sceneJson?.phases ?? []).map((p) => p.name);
    const phase = this.fields.get('phase')!;
    const select = phase.input as HTMLSelectElement;
    if ([...select.options].map((o) => o.value).join('|') !== phases.join('|'))
      select.replaceChildren(...phases.map((n) => el('option', { text: n, attrs: { value: n } })));
    phase.show(inst.phase ?? phases[0] ?? '');
    for (const [key, f] of this.fields) if (key.startsWith('param.')) f.show(instanceValue(inst, key.slice(6)));
  }

  private setValue(key: string, value: unknown): Promise<void> | void {
    const inst = this.selectedInstance();
    if (!inst) return;
    const old = instanceValue(inst, key);
    if (JSON.stringify(old ?? null) === JSON.stringify(value)) return;
    return this.editor.execute(new SetInstanceValuesCommand(this.editor, inst.name, { [key]: value }, { [key]: old })).then(() => this.update());
  }

  private editTransform(change: (k: FullKey) => void): Promise<void> | void {
    const inst = this.selectedInstance();
    if (!inst) return;
    const e = this.editor, time = e.playheadTime(), tol = this.tolerance(), dim = this.dim();
    const centre = e.templateCentre(inst.template);
    // Built from the track as it is when the command runs (edits in flight land first).
    const autoKey = e.autoKey;
    const edit = (track: TransformKey[]) => editTrack(track, time, tol, dim, centre, change, autoKey);
    return e.execute(new SetInstanceTransformCommand(e, inst.name, edit)).then(() => this.update());
  }

  private keyAtPlayhead(add: boolean) {
    const inst = this.selectedInstance();
    if (!inst) return;
    const e = this.editor, t = e.playheadTime(), tol = this.tolerance(), dim = this.dim();
    const centre = e.templateCentre(inst.template);
    const edit = (track: TransformKey[]) => (add ? addKeyAt(track, t, tol, dim, centre) : removeKeyAt(track, t, tol));
    const name = `${add ? 'Add' : 'Remove'} key of ${inst.name} at ${t.toFixed(3)} s`;
    void e.execute(new SetInstanceTransformCommand(e, inst.name, edit, undefined, undefined, { name, merge: false }))
      .then(() => this.update());
  }

  // --------------------------------------------------------------- scene ---

  private sceneGroup(group: SettingsGroup): Record<string, unknown> {
    const scene = this.editor.session?.sceneJson as Record<string, unknown> | null | undefined;
    return (scene?.[group] as Record<string, unknown> | undefined) ?? {};
  }

  private solverMethod(): string {
    return String(this.sceneGroup('solver')['method'] ?? 'dfsph');
  }

  /** Solver method, its parameters, simulation settings and control settings (rebuilt when the method changes). */
  private buildSceneFields() {
    const p = this.editor.parameters;
    const method = this.solverMethod();
    const presets = this.editor.presets.presets;
    const id = p ? `${p.dimension}:${method}:${presets.map((x) => x.name).join(',')}` : '';
    if (id === this.sceneFieldsFor) return;
    this.sceneFieldsFor = id;
    this.sceneFields = new Map();
    this.presetField = null;
    this.sceneBox.replaceChildren();
    if (!p || !this.editor.session) return;
    if (presets.length) {
      // The study's presets, each with what it costs and how accurate it is.
      const title = ['Accuracy presets from the Pareto front of `flowclip bench accuracy`', this.editor.presets.source ?? '',
        ...presets.map((x) => `${x.name}: ${x.description ?? ''}\n  ${[...figures(x.cost), ...figures(x.error)].join('; ')}`)].join('\n');
      const f = selectField('scene-preset', 'accuracy preset', title, ['custom', ...presets.map((x) => x.name)], (v) => this.applyPreset(String(v)));
      for (const o of (f.input as HTMLSelectElement).options) {
        const x = presets.find((q) => q.name === o.value);
        o.textContent = x ? presetLabel(x) : 'custom (cost not measured)';
      }
      this.presetField = f;
      this.sceneBox.append(f.row, this.presetFigures);
    }
    const methods = Object.keys(p.solvers);
    const m = selectField('scene-solver-method', 'pressure solver', methods.map((n) => `${n}: ${p.solvers[n]!.help}`).join('\n'), methods,
      (v) => this.changeMethod(String(v)));
    this.sceneFields.set('solver.method', m);
    this.sceneBox.append(m.row);
    const add = (group: SettingsGroup, specs: ParamSpecJson[]) => {
      for (const spec of specs) {
        const f = paramField(`scene-${group}`, spec, (v) => this.setSetting(group, spec.name, v), this.complain);
        this.sceneFields.set(`${group}.${spec.name}`, f);
        this.sceneBox.append(f.row);
      }
    };
    add('solver', p.solvers[method]?.params ?? []);
    add('settings', p.settings);
    add('control', p.control);
  }

  private updateScene() {
    this.sceneBox.hidden = this.editor.session === null;
    this.buildSceneFields();
    for (const [key, f] of this.sceneFields) {
      const [group, name] = key.split('.') as [SettingsGroup, string];
      f.show(this.sceneGroup(group)[name]);
    }
    if (this.presetField) {
      const current = this.currentPreset();
      this.presetField.show(current?.name ?? 'custom');
      this.presetFigures.textContent = current
        ? [...figures(current.cost), ...figures(current.error)].join(' · ')
        : 'custom settings: not a point of the accuracy study';
    }
  }

  /** The preset whose every solver and settings value the scene has (a declared default counts when the scene omits the key). */
  private currentPreset(): AccuracyPresetJson | null {
    const p = this.editor.parameters;
    const value = (group: 'solver' | 'settings', name: string): unknown => {
      const v = this.sceneGroup(group)[name];
      if (v !== undefined) return v;
      if (name === 'method') return 'dfsph';
      const specs = group === 'settings' ? p?.settings : p?.solvers[this.solverMethod()]?.params;
      return specs?.find((s) => s.name === name)?.default;
    };
    const same = (a: unknown, b: unknown) =>
      typeof a === 'number' && typeof b === 'number' ? Math.abs(a - b) <= 1e-9 * Math.max(1, Math.abs(b)) : a === b;
    return this.editor.presets.presets.find((x) =>
      Object.entries(x.solver).every(([k, v]) => same(value('solver', k), v)) &&
      Object.entries(x.settings).every(([k, v]) => same(value('settings', k), v))) ?? null;
  }

  /** One command sets every value of the preset (undo restores them; another solver's own parameters are removed, as changeMethod does). */
  private applyPreset(name: string): Promise<void> | void {
    const preset = this.editor.presets.presets.find((x) => x.name === name);
    const p = this.editor.parameters;
    if (!preset || !p) return;
    const oldSolver = this.sceneGroup('solver'), oldSettings = this.sceneGroup('settings');
    const oldMethod = this.solverMethod();
    const method = String(preset.solver['method'] ?? oldMethod);
    const patch: SettingsPatch = { solver: { ...preset.solver, method }, settings: { ...preset.settings } };
    const undo: SettingsPatch = { solver: { method: oldMethod }, settings: {} };
    if (method !== oldMethod) {
      const keep = new Set((p.solvers[method]?.params ?? []).map((s) => s.name));
      for (const s of p.solvers[oldMethod]?.params ?? []) {
        if (!keep.has(s.name)) patch.solver![s.name] = null;
        undo.solver![s.name] = oldSolver[s.name] ?? null;
      }
    }
    for (const k of Object.keys(preset.solver)) if (k !== 'method') undo.solver![k] = oldSolver[k] ?? null;
    for (const k of Object.keys(preset.settings)) undo.settings![k] = oldSettings[k] ?? null;
    const e = this.editor;
    return e.execute(new SetSceneSettingsCommand(e, patch, undo)).then(() => this.updateScene());
  }

  private setSetting(group: SettingsGroup, name: string, value: unknown): Promise<void> | void {
    const old = this.sceneGroup(group)[name];
    if (JSON.stringify(old ?? null) === JSON.stringify(value)) return;
    const e = this.editor;
    return e.execute(new SetSceneSettingsCommand(e, { [group]: { [name]: value } }, { [group]: { [name]: old ?? null } }))
      .then(() => this.updateScene());
  }

  /** Another pressure solver: its own parameters replace the old one's (a merge patch removes those with null). */
  private changeMethod(method: string): Promise<void> | void {
    const p = this.editor.parameters, oldMethod = this.solverMethod();
    if (!p || method === oldMethod) return;
    const oldSolver = this.sceneGroup('solver');
    const newNames = new Set((p.solvers[method]?.params ?? []).map((s) => s.name));
    const oldNames = new Set((p.solvers[oldMethod]?.params ?? []).map((s) => s.name));
    const patch: SettingsPatch = { solver: { method } };
    const undo: SettingsPatch = { solver: { method: oldMethod } };
    for (const n of oldNames) if (!newNames.has(n)) patch.solver![n] = null;
    for (const n of new Set([...oldNames, ...newNames])) undo.solver![n] = oldSolver[n] ?? null;
    const e = this.editor;
    return e.execute(new SetSceneSettingsCommand(e, patch, undo)).then(() => this.updateScene());
  }
}
