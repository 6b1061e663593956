// Decodes the stream's Frame messages (proto/flowclip.fbs) without
// per-particle allocations: positions are dequantized and colours looked up
// straight into the float buffers of a ParticleTarget (the viewport's
// BufferGeometry attributes), which grow by doubling; the frame's header,
// counts and instance records go into objects reused from frame to frame.
// Colours are written only from the first particle whose kind or phase
// differs from the previous frame's (same buffer, same palette), and the
// target is told so (commit's colorsFrom): a frame whose kinds and phases are
// unchanged, as in a one-phase scene without temporary particles however the
// simulation reorders them, rewrites and uploads no colour.
import { ControlLayer, Frame, Instance, Layer, Points, Stats, Vec3 } from '@wire';

/** Where decoded particles go: xyz positions and rgb colours, 3 floats per particle. */
export interface ParticleTarget {
  /** Buffers with room for at least n particles (the target grows them, keeping none of the old values). */
  reserve(n: number): { positions: Float32Array; colors: Float32Array };
  /**
   * The first n particles of the buffers returned by reserve() are the new
   * frame; the colours of particles before `colorsFrom` (default 0) are
   * those of the previous commit (nothing to upload for them).
   */
  commit(n: number, colorsFrom?: number): void;
}

/** A ParticleTarget of plain growable arrays (no viewport: tests, benchmarks). */
export class ArrayParticleTarget implements ParticleTarget {
  positions = new Float32Array(0);
  colors = new Float32Array(0);
  count = 0;
  reserve(n: number) {
    if (this.positions.length < 3 * n) {
      let cap = Math.max(1024, this.positions.length / 3);
      while (cap < n) cap *= 2;
      this.positions = new Float32Array(3 * cap);
      this.colors = new Float32Array(3 * cap);
    }
    return this;
  }
  commit(n: number, _colorsFrom = 0) {
    this.count = n;
  }
}

export interface InstanceInfo {
  name: string;
  template: string;
  active: boolean;
  templateFrame: number;
  phase: number;
  /** Template space → world as a column-major 4×4 (three.js Matrix4.elements); 2D matrices are lifted. */
  matrix: Float64Array;
  templateMin: [number, number, number];
  templateMax: [number, number, number];
  falloffWidth: number;
  fidelity: number;
  controlled: number;
}

export interface FrameInfo {
  sessionId: string;
  frame: number;
  time: number;
  dimension: 2 | 3;
  domainMin: [number, number, number];
  domainMax: [number, number, number];
  layers: number;
  /** Liquid and temporary particles decoded into `target`. */
  count: number;
  /** Boundary particles decoded into `boundaryTarget` (Layer.Boundary), control points (Layer.Control), repulsion points (Layer.Repulsion). */
  boundaryCount: number;
  controlCount: number;
  repulsionCount: number;
  liquid: number;
  temporary: number;
  boundary: number;
  wallMs: number;
  controlMs: number;
  /** Instance records, instanceCount of them valid (the array is a pool). */
  instances: InstanceInfo[];
  instanceCount: number;
  /** Wall time of the last decode, ms. */
  decodeMs: number;
  /** Wire bytes of the last frame message. */
  bytes: number;
}

export const enum Kind {
  Liquid = 0,
  Temporary = 1,
  Boundary = 2,
}

const Q = 1 / 65535;

/** What a target's colour buffer holds, so that colours still valid are neither rewritten nor uploaded. */
class ColorState {
  /** The buffer last written, with the palette version it was written with. */
  private colors: Float32Array | null = null;
  private palette = -1;
  /** Particles [0, valid) of it hold the colours of the last frame written. */
  private valid = 0;
  /** Lowest particle written since the last commit (a frame that threw in between included). */
  private dirty = Infinity;

  /** Particles before the returned index still hold valid colours in `colors` (0 after a new buffer or palette). */
  reusable(colors: Float32Array, palette: number, n: number): number {
    return colors === this.colors && palette === this.palette ? Math.min(this.valid, n) : 0;
  }

  /** Colours [from, n) were written into `colors`; [0, n) now valid (0: none kept for the next frame). */
  wrote(colors: Float32Array, palette: number, from: number, n: number, keep = true) {
    this.colors = colors;
    this.palette = palette;
    this.valid = keep ? n : 0;
    this.dirty = Math.min(this.dirty, from);
  }

  /** colorsFrom for the target's commit(n). */
  committed(n: number): number {
    const from = Math.min(this.dirty, n);
    this.dirty = Infinity;
    return from;
  }
}

export class FrameDecoder {
  /** Liquid and temporary particles. */
  target: ParticleTarget = new ArrayParticleTarget();
  /** Boundary particles (kind 2 at the end of Frame.particles; Layer.Boundary). */
  boundaryTarget: ParticleTarget = new ArrayParticleTarget();
  /** Control particles, coloured by α: green (α≈0, covered) → magenta (α≈1, uncovered), both visible on the dark background. */
  controlTarget: ParticleTarget = new ArrayParticleTarget();
  /** Repulsion particles (red). */
  repulsionTarget: ParticleTarget = new ArrayParticleTarget();
  readonly info: FrameInfo = {
    sessionId: '',
    frame: -1,
    time: 0,
    dimension: 2,
    domainMin: [0, 0, 0],
    domainMax: [1, 1, 1],
    layers: 0,
    count: 0,
    boundaryCount: 0,
    controlCount: 0,
    repulsionCount: 0,
    liquid: 0,
    temporary: 0,
    boundary: 0,
    wallMs: 0,
    controlMs: 0,
    instances: [],
    instanceCount: 0,
    decodeMs: 0,
    bytes: 0,
  };

  /** Linear RGB per scene phase (256 × 3); phases without a colour use the liquid colour. */
  readonly phaseColors = new Float32Array(256 * 3);
  readonly temporaryColor = new Float32Array(3);
  readonly boundaryColor = new Float32Array(3);
  readonly controlColor = new Float32Array([0.2, 0.85, 0.3]);
  readonly uncoveredColor = new Float32Array([1.0, 0.35, 0.9]);
  readonly repulsionColor = new Float32Array([1.0, 0.2, 0.2]);
  /**
   * Colour liquid particles by speed (frames that carry Layer.Speed): a ramp
   * from dark blue (at rest) through the liquid's light blue to white at
   * `speedScale` m/s and above. The scale follows the frames' largest speed
   * with a slow decay, so that colours do not flicker from frame to frame.
   */
  colorBySpeed = false;
  speedScale = 0;
  private readonly speedRamp = new Float32Array(256 * 3);

  // Flatbuffers accessors reused for every frame.
  private readonly points = new Points();
  private readonly stats = new Stats();
  private readonly vec = new Vec3();
  private readonly inst = new Instance();
  private readonly control = new ControlLayer();

  // Colour reuse: bumped by setColors / invalidateColors; each target's state;
  // the kinds and phases the liquid colours were computed from.
  private paletteVersion = 0;
  private readonly liquidColors = new ColorState();
  private readonly boundaryColors = new ColorState();
  private readonly repulsionColors = new ColorState();
  private lastKind = new Uint8Array(0);
  private lastPhase = new Uint8Array(0);

  constructor() {
    this.setColors([0.45, 0.7, 1.0], [], [1.0, 0.62, 0.25], [0.55, 0.55, 0.6]);
    const stops = [[0.05, 0.12, 0.45], [0.45, 0.7, 1.0], [1, 1, 1]];
    for (let k = 0; k < 256; k++) {
      const u = k / 255, seg = u < 0.5 ? 0 : 1, w = u < 0.5 ? u * 2 : (u - 0.5) * 2;
      for (let c = 0; c < 3; c++) this.speedRamp[3 * k + c] = stops[seg]![c]! + (stops[seg + 1]![c]! - stops[seg]![c]!) * w;
    }
  }

  /** Colours as linear RGB: liquid default, per-phase overrides, temporary, boundary. */
  setColors(liquid: ArrayLike<number>, phases: (ArrayLike<number> | null)[], temporary: ArrayLike<number>, boundary: ArrayLike<number>) {
    for (let p = 0; p < 256; p++) {
      const c = phases[p] ?? liquid;
      this.phaseColors[3 * p] = c[0]!;
      this.phaseColors[3 * p + 1] = c[1]!;
      this.phaseColors[3 * p + 2] = c[2]!;
    }
    this.temporaryColor.set([temporary[0]!, temporary[1]!, temporary[2]!]);
    this.boundaryColor.set([boundary[0]!, boundary[1]!, boundary[2]!]);
    this.invalidateColors();
  }

  /** The next frame rewrites every colour (after changing a colour array such as repulsionColor in place). */
  invalidateColors() {
    this.paletteVersion++;
  }

  /** Decodes `frame` into the target and `info`. Throws on a malformed frame (nothing committed). */
  decode(frame: Frame, bytes: number): FrameInfo {
    const t0 = performance.now();
    const info = this.info;
    const dim = frame.dimension() === 3 ? 3 : 2;
    info.sessionId = frame.sessionId() ?? '';
    info.frame = frame.frame();
    info.time = frame.time();
    info.dimension = dim;
    info.layers = frame.layers();
    info.bytes = bytes;
    readVec(frame.domainMin(this.vec), info.domainMin);
    readVec(frame.domainMax(this.vec), info.domainMax);

    const pts = frame.particles(this.points);
    const n = pts ? pts.count() : 0;
    const kinds = frame.kindArray();
    const phases = frame.phaseArray();
    // Boundary particles follow the liquid ones: split at the first of the trailing kind-2 run.
    let nl = n;
    if (kinds && kinds.length >= n) while (nl > 0 && kinds[nl - 1] === Kind.Boundary) nl--;
    const { positions, colors } = this.target.reserve(nl);
    const b = this.boundaryTarget.reserve(n - nl);
    if (n > 0 && pts) {
      this.dequantize(pts, n, dim, 0, nl, positions, `frame ${info.frame}: particles`);
      this.dequantize(pts, n, dim, nl, n - nl, b.positions, `frame ${info.frame}: particles`);
    }
    if (this.colorBySpeed && info.layers & Layer.Speed) {
      // Speeds change every frame: every colour is written, none kept.
      this.colorize(0, nl, kinds, phases, colors);
      this.colorizeSpeed(frame, nl, kinds, colors);
      this.liquidColors.wrote(colors, this.paletteVersion, 0, nl, false);
    } else {
      this.colorizeLiquid(nl, kinds, phases, colors);
    }
    const bFrom = this.boundaryColors.reusable(b.colors, this.paletteVersion, n - nl);
    fillColor(b.colors, bFrom, n - nl, this.boundaryColor);
    this.boundaryColors.wrote(b.colors, this.paletteVersion, bFrom, n - nl);

    // Control points with α, repulsion points (optional layers).
    let nc = 0, nr = 0;
    const ctl = info.layers & Layer.Control ? frame.control(this.control) : null;
    const cpts = ctl ? ctl.points(this.points) : null;
    if (cpts) {
      nc = cpts.count();
      const alpha = ctl!.alphaArray();
      const c = this.controlTarget.reserve(nc);
      this.dequantize(cpts, nc, dim, 0, nc, c.positions, `frame ${info.frame}: control`);
      const g = this.controlColor, u = this.uncoveredColor;
      const haveAlpha = alpha !== null && alpha.length >= nc;
      for (let i = 0, o = 0; i < nc; i++, o += 3) {
        const a = haveAlpha ? alpha![i]! / 255 : 0; // α = 0 (covered): green; α = 1: magenta
        c.colors[o] = g[0]! + (u[0]! - g[0]!) * a;
        c.colors[o + 1] = g[1]! + (u[1]! - g[1]!) * a;
        c.colors[o + 2] = g[2]! + (u[2]! - g[2]!) * a;
      }
    }
    const rpts = info.layers & Layer.Repulsion ? frame.repulsion(this.points) : null;
    if (rpts) {
      nr = rpts.count();
      const r = this.repulsionTarget.reserve(nr);
      this.dequantize(rpts, nr, dim, 0, nr, r.positions, `frame ${info.frame}: repulsion`);
      const from = this.repulsionColors.reusable(r.colors, this.paletteVersion, nr);
      fillColor(r.colors, from, nr, this.repulsionColor);
      this.repulsionColors.wrote(r.colors, this.paletteVersion, from, nr);
    }
    this.target.commit(nl, this.liquidColors.committed(nl));
    this.boundaryTarget.commit(n - nl, this.boundaryColors.committed(n - nl));
    this.controlTarget.commit(nc);
    this.repulsionTarget.commit(nr, this.repulsionColors.committed(nr));
    info.count = nl;
    info.boundaryCount = n - nl;
    info.controlCount = nc;
    info.repulsionCount = nr;

    const st = frame.stats(this.stats);
    info.liquid = st ? st.liquidParticles() : 0;
    info.temporary = st ? st.temporaryParticles() : 0;
    info.boundary = st ? st.boundaryParticles() : 0;
    info.wallMs = st ? st.wallMs() : 0;
    info.controlMs = st ? st.controlMs() : 0;

    this.readInstances(frame, dim);
    info.decodeMs = performance.now() - t0;
    return info;
  }

  /** Points `first`..`first+count` of `pts` (n in all) → xyz floats at positions[0..). Throws if q is short. */
  private dequantize(pts: Points, n: number, dim: 2 | 3, first: number, count: number, positions: Float32Array, what: string) {
    if (count <= 0) return;
    const q = pts.qArray();
    if (!q || q.length < n * dim) throw new Error(`${what}: ${n} points but ${q ? q.length : 0} coordinates`);
    const bmin = pts.boxMin(this.vec);
    const x0 = bmin ? bmin.x() : 0, y0 = bmin ? bmin.y() : 0, z0 = bmin ? bmin.z() : 0;
    const bmax = pts.boxMax(this.vec);
    const sx = ((bmax ? bmax.x() : 0) - x0) * Q;
    const sy = ((bmax ? bmax.y() : 0) - y0) * Q;
    const sz = ((bmax ? bmax.z() : 0) - z0) * Q;
    if (dim === 3) {
      for (let i = 0, j = 3 * first, o = 0; i < count; i++, j += 3, o += 3) {
        positions[o] = x0 + q[j]! * sx;
        positions[o + 1] = y0 + q[j + 1]! * sy;
        positions[o + 2] = z0 + q[j + 2]! * sz;
      }
    } else {
      for (let i = 0, j = 2 * first, o = 0; i < count; i++, j += 2, o += 3) {
        positions[o] = x0 + q[j]! * sx;
        positions[o + 1] = y0 + q[j + 1]! * sy;
        positions[o + 2] = 0;
      }
    }
  }

  /**
   * Liquid colours: particles whose kind and phase equal the previous frame's
   * (same buffer, same palette) keep their colour; from the first that
   * differs on, every colour is looked up again.
   */
  private colorizeLiquid(n: number, kinds: Uint8Array | null, phases: Uint8Array | null, colors: Float32Array) {
    const state = this.liquidColors;
    const complete = kinds !== null && kinds.length >= n && phases !== null && phases.length >= n;
    let from = 0;
    if (complete) {
      const reusable = state.reusable(colors, this.paletteVersion, n);
      if (reusable > 0) from = firstDifference(phases!, this.lastPhase, firstDifference(kinds!, this.lastKind, reusable));
      if (this.lastKind.length < n) {
        let cap = Math.max(4096, this.lastKind.length);
        while (cap < n) cap *= 2;
        this.lastKind = new Uint8Array(cap);
        this.lastPhase = new Uint8Array(cap);
        from = 0;
      }
      this.lastKind.set(kinds!.subarray(from, n), from);
      this.lastPhase.set(phases!.subarray(from, n), from);
    }
    this.colorize(from, n, kinds, phases, colors);
    // Without kinds and phases nothing is kept: the next frame looks every colour up again.
    state.wrote(colors, this.paletteVersion, from, n, complete);
  }

  private colorize(from: number, n: number, kinds: Uint8Array | null, phases: Uint8Array | null, colors: Float32Array) {
    const pc = this.phaseColors, tc = this.temporaryColor, bc = this.boundaryColor;
    const haveKinds = kinds !== null && kinds.length >= n;
    const havePhases = phases !== null && phases.length >= n;
    for (let i = from, o = 3 * from; i < n; i++, o += 3) {
      const kind = haveKinds ? kinds![i]! : Kind.Liquid;
      if (kind === Kind.Liquid) {
        const p = havePhases ? 3 * phases![i]! : 0;
        colors[o] = pc[p]!;
        colors[o + 1] = pc[p + 1]!;
        colors[o + 2] = pc[p + 2]!;
      } else if (kind === Kind.Temporary) {
        colors[o] = tc[0]!;
        colors[o + 1] = tc[1]!;
        colors[o + 2] = tc[2]!;
      } else {
        colors[o] = bc[0]!;
        colors[o + 1] = bc[1]!;
        colors[o + 2] = bc[2]!;
      }
    }
  }

  /** Liquid (not temporary) particles by |v| (Frame.speed, q / 255 · speed_max). */
  private colorizeSpeed(frame: Frame, n: number, kinds: Uint8Array | null, colors: Float32Array) {
    const q = frame.speedArray();
    if (!q || q.length < n) return;
    const max = frame.speedMax();
    this.speedScale = Math.max(max, this.speedScale * 0.97, 1e-6);
    const k = (max / this.speedScale), ramp = this.speedRamp;
    const haveKinds = kinds !== null && kinds.length >= n;
    for (let i = 0, o = 0; i < n; i++, o += 3) {
      if (haveKinds && kinds![i] !== Kind.Liquid) continue;
      const r = 3 * Math.min(255, Math.round(q[i]! * k));
      colors[o] = ramp[r]!;
      colors[o + 1] = ramp[r + 1]!;
      colors[o + 2] = ramp[r + 2]!;
    }
  }

  private readInstances(frame: Frame, dim: 2 | 3) {
    const info = this.info;
    const count = frame.instancesLength();
    const pool = info.instances;
    while (pool.length < count) {
      pool.push({
        name: '', template: '', active: false, templateFrame: -1, phase: 0,
        matrix: new Float64Array(16), templateMin: [0, 0, 0], templateMax: [0, 0, 0],
        falloffWidth: 0, fidelity: -1, controlled: 0,
      });
    }
    for (let k = 0; k < count; k++) {
      const rec = frame.instances(k, this.inst)!;
      const out = pool[k]!;
      out.name = rec.name() ?? '';
      out.template = rec.templateName() ?? '';
      out.active = rec.active();
      out.templateFrame = rec.templateFrame();
      out.phase = rec.phase();
      out.falloffWidth = rec.falloffWidth();
      out.fidelity = rec.fidelity();
      out.controlled = rec.controlled();
      readVec(rec.templateMin(this.vec), out.templateMin);
      readVec(rec.templateMax(this.vec), out.templateMax);
      readWorldMatrix(rec, dim, out.matrix);
    }
    info.instanceCount = count;
  }
}

/** Index of the first i < n with a[i] ≠ b[i], else n (4 bytes at a time where both are aligned). */
function firstDifference(a: Uint8Array, b: Uint8Array, n: number): number {
  let i = 0;
  if (n >= 64 && (a.byteOffset & 3) === 0 && (b.byteOffset & 3) === 0) {
    const words = n >> 2;
    const a32 = new Uint32Array(a.buffer, a.byteOffset, words);
    const b32 = new Uint32Array(b.buffer, b.byteOffset, words);
    let k = 0;
    while (k < words && a32[k] === b32[k]) k++;
    i = k << 2;
  }
  while (i < n && a[i] === b[i]) i++;
  return i;
}

function fillColor(colors: Float32Array, from: number, n: number, c: Float32Array) {
  for (let i = from, o = 3 * from; i < n; i++, o += 3) {
    colors[o] = c[0]!;
    colors[o + 1] = c[1]!;
    colors[o + 2] = c[2]!;
  }
}

function readVec(v: Vec3 | null, out: [number, number, number]) {
  if (!v) {
    out[0] = out[1] = out[2] = 0;
    return;
  }
  out[0] = v.x();
  out[1] = v.y();
  out[2] = v.z();
}

/** Row-major 3×3 (2D) or 4×4 (3D) → column-major 4×4; identity when absent or malformed. */
function readWorldMatrix(rec: Instance, dim: 2 | 3, m: Float64Array) {
  m.fill(0);
  m[0] = m[5] = m[10] = m[15] = 1;
  const len = rec.worldMatrixLength();
  if (dim === 2 && len >= 9) {
    // [a b tx; c d ty; 0 0 1] → x' = a x + b y + tx, y' = c x + d y + ty, z' = z
    m[0] = rec.worldMatrix(0)!; m[4] = rec.worldMatrix(1)!; m[12] = rec.worldMatrix(2)!;
    m[1] = rec.worldMatrix(3)!; m[5] = rec.worldMatrix(4)!; m[13] = rec.worldMatrix(5)!;
  } else if (dim === 3 && len >= 16) {
    for (let r = 0; r < 4; r++) for (let c = 0; c < 4; c++) m[c * 4 + r] = rec.worldMatrix(r * 4 + c)!;
  }
}
