// The 3D view: streamed particles, the domain box, the instance and falloff
// boxes. 2D scenes get an orthographic camera (pan and zoom), 3D scenes a
// perspective one (orbit). It renders on demand only (a new frame, a camera
// change, a resize, an edit), at most once per animation frame, never in a
// loop: software GL would otherwise take the CPU the simulation and the
// stream need.
//
// Instance boxes come from the document, not from the frames: each is its
// template's region placed by the client's own evaluation of the transform
// track at the playhead (core/TransformTrack.ts, as the server evaluates
// it), so that they follow every edit, preview and undo at once, and are
// drawn at frames nothing is recorded at yet.
import * as THREE from 'three';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
import type { Editor, SessionInfo } from '../core/Editor';
import type { FrameInfo } from '../net/FrameDecoder';
import { Boxes, type BoxInfo } from './Boxes';
import { evaluateTrack, keyMatrix } from '../core/TransformTrack';
import { sceneEnd, timingOf } from '../ui/TimelineModel';
import { el } from '../ui/dom';
import { InstanceGizmo } from './InstanceGizmo';
import { TEMPLATE_DRAG_TYPE } from '../ui/TemplateLibrary';
import { ParticleLayer } from './ParticleLayer';

export class Viewport {
  readonly renderer: THREE.WebGLRenderer;
  readonly scene = new THREE.Scene();
  readonly particles = new ParticleLayer();
  /** The optional layers (editor.layers): boundary particles, control particles with α, repulsion particles. */
  readonly boundary = new ParticleLayer('boundary');
  readonly control = new ParticleLayer('control');
  readonly repulsion = new ParticleLayer('repulsion');
  readonly boxes = new Boxes();
  readonly ortho = new THREE.OrthographicCamera(-1, 1, 1, -1, -100, 100);
  readonly persp = new THREE.PerspectiveCamera(45, 1, 0.01, 100);
  camera: THREE.OrthographicCamera | THREE.PerspectiveCamera = this.ortho;
  controls: OrbitControls;
  /** TransformControls on the selected instance. */
  readonly gizmo: InstanceGizmo;
  /** Renders done (tests check that nothing renders while nothing changes). */
  renders = 0;
  /** Render requests by reason ('frame', 'camera', 'resize', 'session', 'fit', 'layers'). */
  readonly requests: Record<string, number> = {};

  private pending = false;
  private orthoHeight = 1;
  private dimension: 2 | 3 = 2;
  private fitPending = true;
  private readonly resizeObserver: ResizeObserver;
  /** Says what the viewport shows when the playhead is where nothing is recorded. */
  private readonly note: HTMLElement;
  private boxesScheduled = false;

  constructor(
    readonly container: HTMLElement,
    private readonly editor: Editor,
  ) {
    this.renderer = new THREE.WebGLRenderer({ antialias: false, powerPreference: 'low-power' });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
    this.renderer.setClearColor(0x15181d, 1);
    this.renderer.domElement.dataset['testid'] = 'viewport-canvas';
    container.appendChild(this.renderer.domElement);

    // Drawn in this order (2D: all at z = 0): boundary, liquid, repulsion, control on top.
    this.boundary.points.renderOrder = 0;
    this.particles.points.renderOrder = 1;
    this.repulsion.points.renderOrder = 2;
    this.control.points.renderOrder = 3;
    this.scene.add(this.boxes.group, this.boundary.points, this.particles.points, this.repulsion.points, this.control.points);
    this.ortho.position.set(0.5, 0.5, 10);
    this.controls = this.makeControls();
    this.gizmo = new InstanceGizmo(editor, this.camera, this.renderer.domElement, this.scene,
      (why) => this.requestRender(why), () => this.controls);
    this.installDrop();
    this.installPicking();
    editor.decoder.target = this.particles;
    editor.decoder.boundaryTarget = this.boundary;
    editor.decoder.controlTarget = this.control;
    editor.decoder.repulsionTarget = this.repulsion;
    editor.signals.layersChanged.add((l) => {
      this.particles.points.visible = l.liquid;
      this.boundary.points.visible = l.boundary;
      this.control.points.visible = l.control;
      this.repulsion.points.visible = l.repulsion;
      this.requestRender('layers');
    });

    editor.signals.frameDecoded.add((f) => this.onFrame(f));
    editor.signals.sessionChanged.add((s) => this.onSession(s));
    const boxes = () => this.scheduleBoxes();
    for (const sig of [editor.signals.instancesChanged, editor.signals.previewChanged, editor.signals.playheadChanged,
      editor.signals.templatesChanged, editor.signals.issuesChanged, editor.signals.parametersChanged]) sig.add(boxes);
    editor.signals.frameSelectionRequested.add(() => this.frameSelection());
    editor.signals.sessionView.add(() => this.updateNote());
    this.note = el('div', { className: 'viewport-note', testid: 'viewport-note' });
    this.note.hidden = true;
    container.append(this.note);

    this.resizeObserver = new ResizeObserver(() => this.resize());
    this.resizeObserver.observe(container);
    this.resize();
  }

  /** Schedules one render at the next animation frame (coalesced). */
  requestRender(reason = 'other') {
    this.requests[reason] = (this.requests[reason] ?? 0) + 1;
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
      this.render();
    });
  }

  private readonly bufferSize = new THREE.Vector2();

  render() {
    const h = this.renderer.getDrawingBufferSize(this.bufferSize).y;
    this.particles.updateScale(this.camera, h);
    this.boundary.updateScale(this.camera, h);
    this.control.updateScale(this.camera, h);
    this.repulsion.updateScale(this.camera, h);
    this.renderer.render(this.scene, this.camera);
    this.renders++;
  }

  /** Frames the domain (called on the first frame of a session). */
  fit(min: ArrayLike<number>, max: ArrayLike<number>) {
    const cx = (min[0]! + max[0]!) / 2, cy = (min[1]! + max[1]!) / 2, cz = (min[2]! + max[2]!) / 2;
    const w = max[0]! - min[0]!, h = max[1]! - min[1]!, d = max[2]! - min[2]!;
    const aspect = this.aspect();
    if (this.dimension === 2) {
      this.orthoHeight = Math.max(h, w / aspect) * 1.08 || 1;
      this.ortho.zoom = 1;
      this.ortho.position.set(cx, cy, 10);
      this.controls.target.set(cx, cy, 0);
      this.updateOrtho();
    } else {
      const radius = 0.5 * Math.hypot(w, h, d) || 1;
      const fov = THREE.MathUtils.degToRad(this.persp.fov);
      const dist = (radius / Math.sin(fov / 2)) * 1.05;
      const dir = new THREE.Vector3(0.55, 0.45, 1).normalize();
      this.persp.position.set(cx, cy, cz).addScaledVector(dir, dist);
      this.persp.near = dist / 100;
      this.persp.far = dist * 10;
      this.persp.updateProjectionMatrix();
      this.controls.target.set(cx, cy, cz);
    }
    this.controls.update();
    this.updateViewCentre();
    this.requestRender('fit');
  }

  /** Recomputes the instance boxes at the next animation frame (coalesced with the render). */
  private scheduleBoxes() {
    if (this.boxesScheduled) return;
    this.boxesScheduled = true;
    requestAnimationFrame(() => {
      this.boxesScheduled = false;
      this.updateBoxes();
    });
  }

  private readonly boxMatrix = new THREE.Matrix4();

  /** Every instance's box at the playhead, from the document (the frame's record when its template is not listed). */
  updateBoxes() {
    const e = this.editor, s = e.session;
    if (!s) return;
    const dim = s.dimension, t = e.playheadTime();
    const f = e.decoder.info;
    const list: BoxInfo[] = [];
    for (const name of e.instances.keys()) {
      const inst = e.displayInstance(name)!;
      const info = e.templateInfo(inst.template);
      const warning = e.issues.has(name);
      if (info?.region_min && info.region_max) {
        const centre = e.templateCentre(inst.template);
        keyMatrix(evaluateTrack(inst.transform, t, dim, centre), dim, centre, this.boxMatrix);
        const timing = timingOf(inst, info);
        const active = timing !== null && t >= timing.start - 1e-9 && t <= sceneEnd(timing) + 1e-9;
        const pad = (v: number[]) => [v[0] ?? 0, v[1] ?? 0, dim === 3 ? v[2] ?? 0 : 0];
        list.push({
          name, active, warning, matrix: this.boxMatrix.elements.slice(), templateMin: pad(info.region_min), templateMax: pad(info.region_max),
          falloffWidth: typeof inst.falloff_width === 'number' ? inst.falloff_width : 0,
        });
        continue;
      }
      if (f.sessionId !== s.id) continue;
      for (let k = 0; k < f.instanceCount; k++) {
        const rec = f.instances[k]!;
        if (rec.name === name) list.push({ ...rec, warning });
      }
    }
    this.boxes.update(list, dim);
    this.updateNote();
    this.requestRender('boxes');
  }

  private updateNote() {
    const e = this.editor, frame = e.playheadFrame;
    const off = e.session !== null && e.offRecord;
    const stale = e.session !== null && !off && e.view.cache.stale.some(([a, b]) => frame >= a && frame <= b);
    this.note.hidden = !off && !stale;
    this.note.dataset['value'] = off ? String(frame) : '';
    this.note.dataset['kind'] = off ? 'not-simulated' : stale ? 'stale' : '';
    if (off) {
      const shown = e.decoder.info.frame;
      this.note.textContent = `Frame ${frame} is not simulated yet: the boxes are at frame ${frame}, the liquid is frame ${shown}. Play simulates up to it`;
    } else if (stale) {
      const sim = e.view.cache.simulating;
      this.note.textContent = `Frame ${frame} is stale: an edit changed it` +
        (sim ? `; re-simulating from frame ${sim.from}, now at ${Math.max(sim.frame, e.decoder.info.frame)}` : '; it will be re-simulated');
    }
  }

  /** F: the selected instance's box fills the view (nothing selected: the domain). */
  frameSelection() {
    const e = this.editor, s = e.session;
    if (!s) return;
    const box = this.boxes.shown.find((b) => b.name === e.selected);
    if (!box) {
      const d = s.sceneJson?.domain;
      if (d) this.fit([d.min[0] ?? 0, d.min[1] ?? 0, d.min[2] ?? 0], [d.max[0] ?? 0, d.max[1] ?? 0, d.max[2] ?? 0]);
      return;
    }
    const m = new THREE.Matrix4().fromArray(box.matrix);
    const b = new THREE.Box3();
    const g = box.falloffWidth;
    for (let c = 0; c < 8; c++) {
      const p = new THREE.Vector3(
        c & 1 ? box.templateMax[0]! : box.templateMin[0]!,
        c & 2 ? box.templateMax[1]! : box.templateMin[1]!,
        c & 4 ? box.templateMax[2]! : box.templateMin[2]!,
      ).applyMatrix4(m);
      b.expandByPoint(p);
    }
    b.expandByScalar(g);
    this.fit([b.min.x, b.min.y, b.min.z], [b.max.x, b.max.y, b.max.z]);
  }

  private onSession(s: SessionInfo | null) {
    if (!s) {
      for (const l of this.layers()) l.commit(0);
      this.boxes.group.visible = false;
      this.requestRender('session');
      return;
    }
    this.boxes.group.visible = true;
    this.setDimension(s.dimension);
    const scene = s.sceneJson;
    for (const l of this.layers()) l.setRadius(scene?.particle_radius ?? 0.005);
    const phases = (scene?.phases ?? []).map((p) => (p.color && p.color.length >= 3 ? p.color : null));
    const d = this.editor.decoder;
    d.setColors([0.45, 0.7, 1.0], phases, d.temporaryColor, d.boundaryColor);
    this.fitPending = true;
    if (scene?.domain) {
      const pad = (v: number[]) => [v[0] ?? 0, v[1] ?? 0, v[2] ?? 0];
      this.boxes.setDomain(pad(scene.domain.min), pad(scene.domain.max));
      this.fit(pad(scene.domain.min), pad(scene.domain.max));
      this.fitPending = false;
    }
    this.updateBoxes();
  }

  private onFrame(f: FrameInfo) {
    if (f.dimension !== this.dimension) this.setDimension(f.dimension);
    this.boxes.setDomain(f.domainMin, f.domainMax);
    this.scheduleBoxes(); // a template not listed takes its box from the frame; the note names the frame
    if (this.fitPending) {
      this.fitPending = false;
      this.fit(f.domainMin, f.domainMax);
    }
    this.requestRender('frame');
  }

  private layers(): ParticleLayer[] {
    return [this.particles, this.boundary, this.control, this.repulsion];
  }

  private setDimension(dim: 2 | 3) {
    if (dim === this.dimension && this.camera === (dim === 2 ? this.ortho : this.persp)) return;
    this.dimension = dim;
    this.camera = dim === 2 ? this.ortho : this.persp;
    this.controls.dispose();
    this.controls = this.makeControls();
    this.gizmo.setCamera(this.camera);
    this.resize();
  }

  /** World point under client pixel (x, y): 2D on z = 0; 3D on the plane through the orbit target facing the camera. */
  worldAt(clientX: number, clientY: number): THREE.Vector3 {
    const r = this.renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((clientX - r.left) / r.width) * 2 - 1, -((clientY - r.top) / r.height) * 2 + 1);
    const ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, this.camera);
    const normal = this.dimension === 2 ? new THREE.Vector3(0, 0, 1) : this.camera.getWorldDirection(new THREE.Vector3()).negate();
    const plane = new THREE.Plane().setFromNormalAndCoplanarPoint(normal, this.dimension === 2 ? new THREE.Vector3() : this.controls.target);
    const hit = new THREE.Vector3();
    return ray.ray.intersectPlane(plane, hit) ?? this.controls.target.clone();
  }

  /** Client pixel of world point p (tests aim the mouse with it). */
  screenOf(p: THREE.Vector3): { x: number; y: number } {
    const r = this.renderer.domElement.getBoundingClientRect();
    const v = p.clone().project(this.camera);
    return { x: r.left + ((v.x + 1) / 2) * r.width, y: r.top + ((1 - v.y) / 2) * r.height };
  }

  /** A template dragged from the library is instanced where it is dropped. */
  private installDrop() {
    const dom = this.renderer.domElement;
    dom.addEventListener('dragover', (e) => {
      if (e.dataTransfer?.types.includes(TEMPLATE_DRAG_TYPE)) {
        e.preventDefault();
        e.dataTransfer.dropEffect = 'copy';
      }
    });
    dom.addEventListener('drop', (e) => {
      const name = e.dataTransfer?.getData(TEMPLATE_DRAG_TYPE);
      if (!name) return;
      e.preventDefault();
      const p = this.worldAt(e.clientX, e.clientY);
      void this.editor.addInstance(name, [p.x, p.y, p.z]);
    });
  }

  /**
   * A click (no drag) selects the instance whose box is under the cursor
   * (the nearest along the view ray; the ray is taken into each instance's
   * template space, where its box is axis-aligned); a click on nothing
   * deselects. Clicks on the gizmo's handles are the gizmo's.
   */
  private installPicking() {
    const dom = this.renderer.domElement;
    let down: { x: number; y: number; onGizmo: boolean } | null = null;
    dom.addEventListener('pointerdown', (e) => {
      // TransformControls has run its hover test by now; its pointerup clears the axis.
      down = e.button === 0 ? { x: e.clientX, y: e.clientY, onGizmo: this.gizmo.controls.axis !== null } : null;
    });
    dom.addEventListener('pointerup', (e) => {
      const d = down;
      down = null;
      if (!d || d.onGizmo || Math.hypot(e.clientX - d.x, e.clientY - d.y) > 4) return;
      this.editor.select(this.instanceAt(e.clientX, e.clientY));
    });
  }

  /** Name of the instance whose box the view ray through client pixel (x, y) hits first, or null. */
  instanceAt(clientX: number, clientY: number): string | null {
    const dim = this.dimension;
    const r = this.renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((clientX - r.left) / r.width) * 2 - 1, -((clientY - r.top) / r.height) * 2 + 1);
    const caster = new THREE.Raycaster();
    caster.setFromCamera(ndc, this.camera);
    const inv = new THREE.Matrix4(), m = new THREE.Matrix4(), hit = new THREE.Vector3();
    let best: string | null = null, bestDist = Infinity;
    for (const inst of this.boxes.shown) {
      m.fromArray(inst.matrix);
      if (Math.abs(m.determinant()) < 1e-12) continue;
      inv.copy(m).invert();
      const ray = caster.ray.clone().applyMatrix4(inv);
      const mn = inst.templateMin, mx = inst.templateMax;
      // 2D boxes are flat: give them depth so that the ray along z meets them.
      const box = new THREE.Box3(
        new THREE.Vector3(mn[0], mn[1], dim === 2 ? -1 : mn[2]),
        new THREE.Vector3(mx[0], mx[1], dim === 2 ? 1 : mx[2]),
      );
      if (!ray.intersectBox(box, hit)) continue;
      const d = hit.applyMatrix4(m).distanceTo(caster.ray.origin);
      if (d < bestDist) {
        bestDist = d;
        best = inst.name;
      }
    }
    return best;
  }

  private updateViewCentre() {
    const t = this.controls.target;
    this.editor.viewCentre = [t.x, t.y, t.z];
  }

  private makeControls(): OrbitControls {
    const c = new OrbitControls(this.camera, this.renderer.domElement);
    c.enableDamping = false; // damping needs a render loop
    if (this.camera === this.ortho) {
      c.enableRotate = false;
      c.screenSpacePanning = true;
      c.mouseButtons = { LEFT: THREE.MOUSE.PAN, MIDDLE: THREE.MOUSE.DOLLY, RIGHT: THREE.MOUSE.PAN };
      c.touches = { ONE: THREE.TOUCH.PAN, TWO: THREE.TOUCH.DOLLY_PAN };
    }
    c.addEventListener('change', () => {
      this.updateViewCentre();
      this.requestRender('camera');
    });
    return c;
  }

  private aspect(): number {
    const w = this.container.clientWidth || 1, h = this.container.clientHeight || 1;
    return w / h;
  }

  private updateOrtho() {
    const aspect = this.aspect();
    const h = this.orthoHeight;
    this.ortho.left = (-h * aspect) / 2;
    this.ortho.right = (h * aspect) / 2;
    this.ortho.top = h / 2;
    this.ortho.bottom = -h / 2;
    this.ortho.updateProjectionMatrix();
  }

  private resize() {
    const w = this.container.clientWidth || 1, h = this.container.clientHeight || 1;
    this.renderer.setSize(w, h, false);
    this.renderer.domElement.style.width = '100%';
    this.renderer.domElement.style.height = '100%';
    this.persp.aspect = w / h;
    this.persp.updateProjectionMatrix();
    this.updateOrtho();
    this.requestRender('resize');
  }

  dispose() {
    this.resizeObserver.disconnect();
    this.gizmo.dispose();
    this.controls.dispose();
    for (const l of this.layers()) l.dispose();
    this.boxes.dispose();
    this.renderer.dispose();
  }
}
