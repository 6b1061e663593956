// An instance's transform track on the client, evaluated as the server does
// (server/control/instance.h, TransformTrack): keys in increasing scene time;
// between keys translation and scale are linear, rotation is slerp (3D) or
// the angle interpolated (2D); reflection switches at the later key; outside
// the first and last key the nearest key holds. The inspector shows, and the
// gizmo edits, the value at the playhead.
//
//   x_world = R · S · F · (x_template − c) + t      (c: the template region's centre)
//
// 3D rotation: Euler degrees, intrinsic XYZ (R = Rx · Ry · Rz), three.js's
// default order.
import * as THREE from 'three';
import type { TransformKey } from '../net/types';

/** A key with every field written out for the dimension. */
export interface FullKey {
  time: number;
  translation: number[];
  /** Degrees: [angle] in 2D, [x, y, z] in 3D. */
  rotation: number[];
  scale: number[];
  reflect: boolean[];
}

export function fullKey(k: TransformKey, dim: 2 | 3, fallbackTranslation: number[]): FullKey {
  const rot = k.rotation === undefined ? [] : typeof k.rotation === 'number' ? [k.rotation] : k.rotation;
  const scale = k.scale === undefined ? [] : typeof k.scale === 'number' ? new Array(dim).fill(k.scale) : k.scale;
  const nr = dim === 2 ? 1 : 3;
  return {
    time: k.time ?? 0,
    translation: Array.from({ length: dim }, (_, d) => k.translation?.[d] ?? fallbackTranslation[d] ?? 0),
    rotation: Array.from({ length: nr }, (_, d) => rot[d] ?? 0),
    scale: Array.from({ length: dim }, (_, d) => scale[d] ?? 1),
    reflect: Array.from({ length: dim }, (_, d) => k.reflect?.[d] ?? false),
  };
}

/** The wire form of a key (rotation a number in 2D, as the server writes it). */
export function toWire(k: FullKey, dim: 2 | 3): TransformKey {
  return {
    time: k.time,
    translation: k.translation.slice(0, dim),
    rotation: dim === 2 ? k.rotation[0]! : k.rotation.slice(0, 3),
    scale: k.scale.slice(0, dim),
    reflect: k.reflect.slice(0, dim),
  };
}

const qa = new THREE.Quaternion(), qb = new THREE.Quaternion();
const ea = new THREE.Euler(), eb = new THREE.Euler();
const DEG = Math.PI / 180;

function slerpEuler(a: number[], b: number[], u: number): number[] {
  qa.setFromEuler(ea.set(a[0]! * DEG, a[1]! * DEG, a[2]! * DEG, 'XYZ'));
  qb.setFromEuler(eb.set(b[0]! * DEG, b[1]! * DEG, b[2]! * DEG, 'XYZ'));
  qa.slerp(qb, u);
  ea.setFromQuaternion(qa, 'XYZ');
  return [ea.x / DEG, ea.y / DEG, ea.z / DEG];
}

/**
 * The transform at scene time `time`. An empty track is the template where
 * it was recorded: translation = the region centre `centre`, no rotation.
 */
export function evaluateTrack(track: TransformKey[] | undefined, time: number, dim: 2 | 3, centre: number[]): FullKey {
  const keys = (track ?? []).map((k) => fullKey(k, dim, centre));
  if (keys.length === 0) return { ...fullKey({ translation: centre }, dim, centre), time };
  if (keys.length === 1 || time <= keys[0]!.time) return { ...keys[0]!, time };
  const last = keys[keys.length - 1]!;
  if (time >= last.time) return { ...last, time };
  let i = 0;
  while (i + 1 < keys.length && keys[i + 1]!.time <= time) i++;
  const a = keys[i]!, b = keys[i + 1]!;
  const u = b.time > a.time ? (time - a.time) / (b.time - a.time) : 0;
  // At a key its stored values, as written (slerp would re-derive equivalent angles).
  if (u <= 0) return { ...a, time };
  const lerp = (x: number[], y: number[]) => x.map((v, d) => v + (y[d]! - v) * u);
  return {
    time,
    translation: lerp(a.translation, b.translation),
    rotation: dim === 2 ? lerp(a.rotation, b.rotation) : slerpEuler(a.rotation, b.rotation, u),
    scale: lerp(a.scale, b.scale),
    reflect: u >= 1 ? b.reflect.slice() : a.reflect.slice(),
  };
}

/** Index of the key within `tolerance` s of `time`, or -1. */
export function keyIndexAt(track: TransformKey[] | undefined, time: number, tolerance: number): number {
  const keys = track ?? [];
  let best = -1, bestDist = Infinity;
  keys.forEach((k, i) => {
    const d = Math.abs((k.time ?? 0) - time);
    if (d <= tolerance && d < bestDist) {
      best = i;
      bestDist = d;
    }
  });
  return best;
}

/**
 * The track after changing the transform at the playhead (`time`): a track of
 * at most one key is edited in place (a static instance stays static); an
 * animated track gets the key at the playhead changed, or a new key there
 * (auto-key) holding the interpolated value with the change applied.
 */
export function editTrackAt(
  track: TransformKey[] | undefined,
  time: number,
  tolerance: number,
  dim: 2 | 3,
  centre: number[],
  change: (k: FullKey) => void,
): TransformKey[] {
  const keys = (track ?? []).map((k) => fullKey(k, dim, centre));
  if (keys.length <= 1) {
    const k = keys[0] ?? { ...fullKey({ translation: centre }, dim, centre), time: 0 };
    change(k);
    return [toWire(k, dim)];
  }
  const i = keyIndexAt(track, time, tolerance);
  if (i >= 0) {
    change(keys[i]!);
  } else {
    const k = evaluateTrack(track, time, dim, centre);
    change(k);
    keys.push(k);
    keys.sort((a, b) => a.time - b.time);
  }
  return keys.map((k) => toWire(k, dim));
}

/** The track with a key at `time` holding the value there (replacing a key within `tolerance`). */
export function addKeyAt(track: TransformKey[] | undefined, time: number, tolerance: number, dim: 2 | 3, centre: number[]): TransformKey[] {
  const keys = (track ?? []).map((k) => fullKey(k, dim, centre));
  const value = evaluateTrack(track, time, dim, centre);
  const i = keyIndexAt(track, time, tolerance);
  if (i >= 0) keys.splice(i, 1);
  if (keys.length === 0 && (track ?? []).length === 0) {
    // An empty track is "where recorded": keep that as a first key at 0 too.
    keys.push({ ...value, time: 0 });
  }
  if (!keys.some((k) => Math.abs(k.time - time) <= 1e-9)) keys.push(value);
  keys.sort((a, b) => a.time - b.time);
  return keys.map((k) => toWire(k, dim));
}

/** The track without the key within `tolerance` of `time` (unchanged if none). */
export function removeKeyAt(track: TransformKey[] | undefined, time: number, tolerance: number): TransformKey[] {
  const keys = (track ?? []).slice();
  const i = keyIndexAt(track, time, tolerance);
  if (i >= 0) keys.splice(i, 1);
  return keys;
}

/** The template-space → world matrix of a key (three.js, column-major), for the gizmo. */
export function keyMatrix(k: FullKey, dim: 2 | 3, centre: number[], out: THREE.Matrix4): THREE.Matrix4 {
  const pos = new THREE.Vector3(k.translation[0], k.translation[1], dim === 3 ? k.translation[2] : 0);
  const q = new THREE.Quaternion();
  if (dim === 2) q.setFromAxisAngle(new THREE.Vector3(0, 0, 1), k.rotation[0]! * DEG);
  else q.setFromEuler(new THREE.Euler(k.rotation[0]! * DEG, k.rotation[1]! * DEG, k.rotation[2]! * DEG, 'XYZ'));
  const s = new THREE.Vector3(
    k.scale[0]! * (k.reflect[0] ? -1 : 1),
    k.scale[1]! * (k.reflect[1] ? -1 : 1),
    dim === 3 ? k.scale[2]! * (k.reflect[2] ? -1 : 1) : 1,
  );
  out.compose(pos, q, s);
  const c = new THREE.Matrix4().makeTranslation(-centre[0]!, -centre[1]!, dim === 3 ? -centre[2]! : 0);
  return out.multiply(c);
}

/**
 * The track after changing the transform at `time` with auto-key off: a track
 * of at most one key is edited in place; an animated track moves as a whole
 * (every key gets the change made at `time`: translation and rotation offset,
 * scale ratio, reflection set), so its motion keeps its shape.
 */
export function offsetTrack(
  track: TransformKey[] | undefined,
  time: number,
  dim: 2 | 3,
  centre: number[],
  change: (k: FullKey) => void,
): TransformKey[] {
  const keys = (track ?? []).map((k) => fullKey(k, dim, centre));
  if (keys.length <= 1) return editTrackAt(track, time, 0, dim, centre, change);
  const before = evaluateTrack(track, time, dim, centre);
  const after: FullKey = structuredClone(before);
  change(after);
  const dt = after.translation.map((v, d) => v - before.translation[d]!);
  const dr = after.rotation.map((v, d) => v - before.rotation[d]!);
  const ds = after.scale.map((v, d) => (Math.abs(before.scale[d]!) > 1e-12 ? v / before.scale[d]! : 1));
  const reflectChanged = after.reflect.some((v, d) => v !== before.reflect[d]);
  const r = (v: number, digits: number) => Number(v.toFixed(digits));
  for (const k of keys) {
    k.translation = k.translation.map((v, d) => r(v + dt[d]!, 6));
    k.rotation = k.rotation.map((v, d) => r(v + dr[d]!, 4));
    k.scale = k.scale.map((v, d) => Math.max(1e-3, r(v * ds[d]!, 6)));
    if (reflectChanged) k.reflect = after.reflect.slice();
  }
  return keys.map((k) => toWire(k, dim));
}

/** Auto-key on: the key at the playhead (editTrackAt); off: the whole track (offsetTrack). */
export function editTrack(
  track: TransformKey[] | undefined,
  time: number,
  tolerance: number,
  dim: 2 | 3,
  centre: number[],
  change: (k: FullKey) => void,
  autoKey: boolean,
): TransformKey[] {
  return autoKey ? editTrackAt(track, time, tolerance, dim, centre, change) : offsetTrack(track, time, dim, centre, change);
}

/**
 * The track with key `index` moved to scene time `time`, kept strictly
 * between its neighbours (at least `gap` s from each) and at or after 0: the
 * keys keep their order, so a drag moves the same key throughout.
 */
export function moveKey(track: TransformKey[], index: number, time: number, gap: number): TransformKey[] {
  const keys = track.map((k) => ({ ...k }));
  const k = keys[index];
  if (!k) return keys;
  const lo = index > 0 ? (keys[index - 1]!.time ?? 0) + gap : Math.min(0, k.time ?? 0);
  const hi = index + 1 < keys.length ? (keys[index + 1]!.time ?? 0) - gap : Infinity;
  k.time = Math.min(hi, Math.max(lo, time));
  return keys;
}
