// Wire boxes: the domain (tank interior) and, per template instance, its box
// (the template's capture region mapped by the instance's world matrix) and
// its falloff box (the box grown by falloff_width world metres along the
// instance's own axes). An instance that steers no liquid is drawn in the
// warning colour, dashed.
import * as THREE from 'three';

/** One instance box to draw (the viewport evaluates them from the document, or takes a frame's). */
export interface BoxInfo {
  name: string;
  active: boolean;
  /** Template space → world, column-major 4×4. */
  matrix: ArrayLike<number>;
  templateMin: ArrayLike<number>;
  templateMax: ArrayLike<number>;
  falloffWidth: number;
  warning: boolean;
}

/** Edges of the unit cube [0, 1]³. */
function unitBoxGeometry(): THREE.BufferGeometry {
  const c = [
    [0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
    [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1],
  ];
  const edges = [0, 1, 1, 2, 2, 3, 3, 0, 4, 5, 5, 6, 6, 7, 7, 4, 0, 4, 1, 5, 2, 6, 3, 7];
  const pos = new Float32Array(edges.length * 3);
  edges.forEach((v, i) => pos.set(c[v]!, 3 * i));
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(pos, 3));
  return g;
}

const EPS = 1e-6;

export class Boxes {
  readonly group = new THREE.Group();
  readonly domain: THREE.LineSegments;
  private readonly unit = unitBoxGeometry();
  private readonly activeMat = new THREE.LineBasicMaterial({ color: 0xffb347 });
  private readonly inactiveMat = new THREE.LineBasicMaterial({ color: 0x8a8f98 });
  private readonly activeFalloffMat = new THREE.LineBasicMaterial({ color: 0xffb347, transparent: true, opacity: 0.35 });
  private readonly inactiveFalloffMat = new THREE.LineBasicMaterial({ color: 0x8a8f98, transparent: true, opacity: 0.3 });
  private readonly warningMat = new THREE.LineDashedMaterial({ color: 0xff6b6b, dashSize: 0.02, gapSize: 0.012 });
  private readonly boxes: THREE.LineSegments[] = [];
  private readonly falloffs: THREE.LineSegments[] = [];
  private readonly m = new THREE.Matrix4();
  private readonly local = new THREE.Matrix4();

  constructor() {
    this.domain = new THREE.LineSegments(this.unit, new THREE.LineBasicMaterial({ color: 0x5d6673 }));
    this.domain.name = 'domain';
    this.domain.matrixAutoUpdate = false;
    this.group.add(this.domain);
    this.group.name = 'boxes';
  }

  setDomain(min: ArrayLike<number>, max: ArrayLike<number>) {
    const x0 = min[0] ?? 0, y0 = min[1] ?? 0, z0 = min[2] ?? 0, x1 = max[0] ?? 0, y1 = max[1] ?? 0, z1 = max[2] ?? 0;
    this.domain.matrix.makeScale(Math.max(x1 - x0, EPS), Math.max(y1 - y0, EPS), Math.max(z1 - z0, EPS)).setPosition(x0, y0, z0);
    this.domain.matrixWorldNeedsUpdate = true;
  }

  /** The drawn boxes, by instance (tests and picking read them). */
  readonly shown: BoxInfo[] = [];

  update(list: BoxInfo[], dim: 2 | 3) {
    this.shown.length = 0;
    this.shown.push(...list);
    while (this.boxes.length < list.length) {
      const box = new THREE.LineSegments(this.unit, this.activeMat);
      const falloff = new THREE.LineSegments(this.unit, this.activeFalloffMat);
      box.matrixAutoUpdate = falloff.matrixAutoUpdate = false;
      this.boxes.push(box);
      this.falloffs.push(falloff);
      this.group.add(box, falloff);
    }
    for (let k = 0; k < this.boxes.length; k++) {
      const box = this.boxes[k]!, falloff = this.falloffs[k]!;
      const inst = k < list.length ? list[k]! : null;
      box.visible = falloff.visible = inst !== null;
      if (!inst) continue;
      box.name = `instance:${inst.name}`;
      falloff.name = `falloff:${inst.name}`;
      box.material = inst.warning ? this.warningMat : inst.active ? this.activeMat : this.inactiveMat;
      falloff.material = inst.active ? this.activeFalloffMat : this.inactiveFalloffMat;
      this.place(box, inst, dim, 0);
      if (inst.warning) box.computeLineDistances();
      this.place(falloff, inst, dim, inst.falloffWidth);
      falloff.visible = inst.falloffWidth > 0;
    }
  }

  /** M · T(min − g) · S(max − min + 2g), g = grow / |column| per axis (template units). */
  private place(obj: THREE.Object3D, inst: BoxInfo, dim: 2 | 3, grow: number) {
    this.m.fromArray(inst.matrix);
    const e = this.m.elements;
    const g = [0, 0, 0];
    for (let a = 0; a < dim; a++) {
      const len = Math.hypot(e[4 * a]!, e[4 * a + 1]!, e[4 * a + 2]!);
      g[a] = len > EPS ? grow / len : 0;
    }
    const mn = [inst.templateMin[0] ?? 0, inst.templateMin[1] ?? 0, inst.templateMin[2] ?? 0];
    const mx = [inst.templateMax[0] ?? 0, inst.templateMax[1] ?? 0, inst.templateMax[2] ?? 0];
    this.local
      .makeScale(
        Math.max(mx[0]! - mn[0]! + 2 * g[0]!, EPS),
        Math.max(mx[1]! - mn[1]! + 2 * g[1]!, EPS),
        Math.max(mx[2]! - mn[2]! + 2 * g[2]!, EPS),
      )
      .setPosition(mn[0]! - g[0]!, mn[1]! - g[1]!, mn[2]! - g[2]!);
    obj.matrix.multiplyMatrices(this.m, this.local);
    obj.matrixWorldNeedsUpdate = true;
  }

  dispose() {
    this.unit.dispose();
    for (const m of [this.activeMat, this.inactiveMat, this.activeFalloffMat, this.inactiveFalloffMat, this.warningMat]) m.dispose();
    (this.domain.material as THREE.Material).dispose();
  }
}
