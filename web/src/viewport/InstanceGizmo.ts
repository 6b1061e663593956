// The TransformControls gizmo on the selected instance: translate (W),
// rotate (E), scale (R); reflection is the inspector's. The gizmo moves a
// proxy object placed at the instance's transform at the playhead (the
// region centre's world position, its rotation and |scale|); each change
// during a drag becomes a SetInstanceTransformCommand: with auto-key on it
// keys the transform at the playhead, off it moves an animated track as a
// whole (core/TransformTrack.ts editTrack). The instance's box shows each
// pose at once (a hub preview); a drag sends at most one PATCH at a time
// (the newest pose wins) and all of a drag's commands merge into one
// history entry. 2D scenes: x/y translation and scale, rotation about z only.
import * as THREE from 'three';
import { TransformControls } from 'three/examples/jsm/controls/TransformControls.js';
import type { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
import type { Editor } from '../core/Editor';
import { SetInstanceTransformCommand } from '../commands/SetInstanceTransformCommand';
import { editTrack, evaluateTrack, type FullKey } from '../core/TransformTrack';
import type { TransformKey } from '../net/types';

const DEG = 180 / Math.PI;
let nextDrag = 1;

export type GizmoMode = 'translate' | 'rotate' | 'scale';

export class InstanceGizmo {
  readonly controls: TransformControls;
  readonly proxy = new THREE.Object3D();
  /** Pointer-move changes sent as commands during drags (tests read it). */
  sent = 0;
  private dim: 2 | 3 = 2;
  /** The drag in progress: its key time (the playhead at mouse-down) and the pose there, the proxy's z angle then. */
  private drag: { id: number; name: string; time: number; start: FullKey; startZ: number; lastZ: number; turns: number } | null = null;
  private inFlight = false;
  private pendingTrack: ((track: TransformKey[]) => TransformKey[]) | null = null;
  /** The hub preview showing the drag's newest pose (cleared when its last PATCH landed). */
  private preview: { name: string; token: number } | null = null;
  private readonly euler = new THREE.Euler();

  constructor(
    private readonly editor: Editor,
    camera: THREE.Camera,
    dom: HTMLElement,
    scene: THREE.Scene,
    private readonly requestRender: (why: string) => void,
    private getOrbit: () => OrbitControls,
  ) {
    this.proxy.name = 'gizmo-proxy';
    scene.add(this.proxy);
    this.controls = new TransformControls(camera, dom);
    this.controls.setSize(0.9);
    const helper = this.controls.getHelper();
    helper.name = 'gizmo';
    scene.add(helper);
    this.controls.addEventListener('change', () => this.requestRender('gizmo'));
    this.controls.addEventListener('dragging-changed', (e) => {
      this.getOrbit().enabled = !(e as unknown as { value: boolean }).value;
    });
    this.controls.addEventListener('mouseDown', () => this.beginDrag());
    this.controls.addEventListener('objectChange', () => this.onChange());
    this.controls.addEventListener('mouseUp', () => this.endDrag());

    editor.signals.selectionChanged.add(() => this.place());
    editor.signals.instancesChanged.add(() => this.place());
    editor.signals.playheadChanged.add(() => this.place());
    editor.signals.previewChanged.add(() => this.place()); // an undo, a redo or an inspector edit on its way
    editor.signals.sessionChanged.add((s) => {
      // A drag or its last pose never carries over to another session.
      this.drag = null;
      this.lastDrag = null;
      this.pendingTrack = null;
      this.preview = null;
      if (s) this.setDimension(s.dimension);
      this.place();
    });
    window.addEventListener('keydown', (e) => {
      const t = e.target as HTMLElement | null;
      if (t && (t.tagName === 'INPUT' || t.tagName === 'SELECT' || t.tagName === 'TEXTAREA')) return;
      if (e.ctrlKey || e.metaKey || e.altKey) return;
      const mode = ({ w: 'translate', e: 'rotate', r: 'scale' } as Record<string, GizmoMode>)[e.key.toLowerCase()];
      if (mode) this.setMode(mode);
    });
    this.place();
  }

  get mode(): GizmoMode {
    return this.controls.mode as GizmoMode;
  }

  setMode(mode: GizmoMode) {
    this.controls.setMode(mode);
    this.applyAxes();
    this.requestRender('gizmo');
  }

  setCamera(camera: THREE.Camera) {
    this.controls.camera = camera;
    this.requestRender('gizmo');
  }

  private setDimension(dim: 2 | 3) {
    this.dim = dim;
    this.applyAxes();
  }

  private applyAxes() {
    const c = this.controls, flat = this.dim === 2;
    c.showZ = !flat || c.mode === 'rotate';
    c.showX = !flat || c.mode !== 'rotate';
    c.showY = !flat || c.mode !== 'rotate';
    c.space = flat ? 'world' : 'local';
  }

  /** The proxy at the selected instance's transform at the playhead, as the viewport shows it (not while the user drags it). */
  private place() {
    if (this.drag) return;
    const e = this.editor;
    const inst = e.selected ? e.displayInstance(e.selected) : undefined;
    if (!inst || !e.session) {
      if (this.controls.object) {
        this.controls.detach();
        this.requestRender('gizmo');
      }
      return;
    }
    const k = evaluateTrack(inst.transform, e.playheadTime(), this.dim, e.templateCentre(inst.template));
    this.proxy.position.set(k.translation[0]!, k.translation[1]!, this.dim === 3 ? k.translation[2]! : 0);
    if (this.dim === 2) this.proxy.rotation.set(0, 0, k.rotation[0]! / DEG);
    else this.proxy.rotation.set(k.rotation[0]! / DEG, k.rotation[1]! / DEG, k.rotation[2]! / DEG, 'XYZ');
    this.proxy.scale.set(k.scale[0]!, k.scale[1]!, this.dim === 3 ? k.scale[2]! : 1);
    this.proxy.updateMatrixWorld();
    if (this.controls.object !== this.proxy) this.controls.attach(this.proxy);
    this.requestRender('gizmo');
  }

  private beginDrag() {
    const e = this.editor;
    const inst = e.selected ? e.instances.get(e.selected) : undefined;
    if (!inst) return;
    const time = e.playheadTime();
    this.drag = {
      id: nextDrag++,
      name: inst.name,
      time,
      start: evaluateTrack(inst.transform, time, this.dim, e.templateCentre(inst.template)),
      startZ: this.proxy.rotation.z,
      lastZ: this.proxy.rotation.z,
      turns: 0,
    };
  }

  /**
   * The proxy's pose → the key at the drag's time (rounded to 0.1 mm, 0.01°,
   * 1e-4 in scale), as an edit of the track the instance has when the
   * command runs. 2D angles accumulate from the key's own (three.js wraps
   * the proxy's to ±180°, the server interpolates angles linearly).
   */
  private onChange() {
    const d = this.drag;
    if (!d) return;
    const e = this.editor, inst = e.instances.get(d.name);
    if (!inst) return;
    const p = this.proxy, dim = this.dim;
    const r4 = (v: number) => Math.round(v * 1e4) / 1e4;
    const r2 = (v: number) => Math.round(v * 100) / 100;
    let step = p.rotation.z - d.lastZ;
    if (step > Math.PI) step -= 2 * Math.PI;
    else if (step < -Math.PI) step += 2 * Math.PI;
    d.turns += step;
    d.lastZ = p.rotation.z;
    const translation = [r4(p.position.x), r4(p.position.y), r4(p.position.z)].slice(0, dim);
    let rotation: number[];
    if (dim === 2) {
      rotation = [r2(d.start.rotation[0]! + d.turns * DEG)];
    } else {
      this.euler.copy(p.rotation).reorder('XYZ');
      rotation = [r2(this.euler.x * DEG), r2(this.euler.y * DEG), r2(this.euler.z * DEG)];
    }
    // Scale is a magnitude: reflection stays as it was (the inspector's).
    const scale = [p.scale.x, p.scale.y, p.scale.z].map((v) => Math.max(1e-3, r4(Math.abs(v)))).slice(0, dim);
    const time = d.time, tol = 0.5 / e.frameRate(), centre = e.templateCentre(inst.template), autoKey = e.autoKey;
    this.pendingTrack = (track: TransformKey[]) =>
      editTrack(track, time, tol, dim, centre, (k) => {
        k.translation = translation;
        k.rotation = rotation;
        k.scale = scale;
      }, autoKey);
    // The box follows the pointer, not the server's answers.
    this.preview = { name: inst.name, token: e.setPreview({ ...inst, transform: this.pendingTrack(structuredClone(inst.transform ?? [])) }) };
    this.pump();
  }

  /** One PATCH in flight during a drag (the newest pose wins); the release's pose is queued at once. */
  private pump(force = false) {
    const d = this.drag ?? this.lastDrag;
    if ((this.inFlight && !force) || !this.pendingTrack || !d) return;
    const edit = this.pendingTrack;
    this.pendingTrack = null;
    this.inFlight = true;
    this.sent++;
    void this.editor
      .execute(new SetInstanceTransformCommand(this.editor, d.name, edit, undefined, d.id))
      .finally(() => {
        this.inFlight = false;
        if (this.pendingTrack) this.pump();
        else if (!this.drag) {
          this.clearPreview();
          this.place();
        }
      });
  }

  private lastDrag: { id: number; name: string } | null = null;

  private clearPreview() {
    if (this.preview) this.editor.clearPreview(this.preview.name, this.preview.token);
    this.preview = null;
  }

  private endDrag() {
    this.lastDrag = this.drag;
    this.drag = null;
    // Queued now, behind the PATCH in flight: an undo pressed after the
    // release then undoes the whole drag.
    if (this.pendingTrack) this.pump(true);
    else if (!this.inFlight) {
      this.clearPreview();
      this.place();
    }
  }

  dispose() {
    this.controls.detach();
    this.controls.getHelper().removeFromParent();
    this.controls.dispose();
  }
}
