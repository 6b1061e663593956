// The instance time map (server/control/instance.h, TimeMap) as the timeline
// needs it, and what each timeline drag does to it. Pure functions: no DOM,
// no editor; the values they return are always valid for the server (crop
// within the template, at least one template frame long, speed untouched).
import type { InstanceJson, TemplateInfo } from '../net/types';
import type { InstanceValues } from '../commands/SetInstanceValuesCommand';

/** An instance's time map with the template's duration filled in. */
export interface Timing {
  /** Scene time it starts, s. */
  start: number;
  /** Template times of the crop window, s (end: crop_end, or the template's duration). */
  begin: number;
  end: number;
  /** Template seconds per scene second (> 0). */
  speed: number;
  reverse: boolean;
  /** The template's duration, s (its last frame's time). */
  duration: number;
  /** The template's frames per second (its frame is the shortest crop). */
  templateFrameRate: number;
}

/** The timing of `inst`, or null while its template is unknown (not listed yet, or missing). */
export function timingOf(inst: InstanceJson, template: TemplateInfo | undefined): Timing | null {
  if (!template || typeof template.duration !== 'number' || !(template.duration > 0)) return null;
  const duration = template.duration;
  const cropEnd = inst.crop_end;
  return {
    start: inst.start ?? 0,
    begin: inst.crop_begin ?? 0,
    end: typeof cropEnd === 'number' && cropEnd >= 0 ? cropEnd : duration,
    speed: inst.speed ?? 1,
    reverse: inst.reverse ?? false,
    duration,
    templateFrameRate: template.frame_rate && template.frame_rate > 0 ? template.frame_rate : 60,
  };
}

/** Scene time the instance ends (it is active over [start, sceneEnd]). */
export function sceneEnd(t: Timing): number {
  return t.start + (t.end - t.begin) / t.speed;
}

/** The timing after applying instance values (a drag's preview). */
export function withValues(t: Timing, v: InstanceValues): Timing {
  const n = { ...t };
  if (typeof v['start'] === 'number') n.start = v['start'];
  if (typeof v['crop_begin'] === 'number') n.begin = v['crop_begin'];
  if (typeof v['crop_end'] === 'number') n.end = v['crop_end'];
  return n;
}

/**
 * What a drag edits: the track's body (start), or the edge the user grabbed:
 * `left` is the track's left end (where it starts in scene time), `right` its
 * right end.
 */
export type DragPart = 'body' | 'left' | 'right';

/** The instance keys a drag of `part` changes (for the undo's old values). */
export function keysOf(part: DragPart, reverse: boolean): string[] {
  if (part === 'body') return ['start'];
  // A reversed instance plays crop_end first (at its left end) and crop_begin last.
  if (part === 'left') return [reverse ? 'crop_end' : 'crop_begin', 'start'];
  return [reverse ? 'crop_begin' : 'crop_end'];
}

const snap = (x: number, rate: number) => Math.round(x * rate) / rate;
const clamp = (x: number, lo: number, hi: number) => Math.min(hi, Math.max(lo, x));

/**
 * The instance values after dragging `part` of an instance whose timing was
 * `t0` when the drag began by `dScene` scene seconds (positive: to the right).
 *
 * Edges are what the user sees: the right end moves the scene time the
 * instance ends (start stays), the left end moves the scene time it starts
 * (its end stays). For a forward instance that is crop_end (right) and
 * crop_begin plus start (left); a reversed one plays its crop window from
 * crop_end down to crop_begin, so its right end is crop_begin and its left
 * end crop_end (plus start). Template times snap to template frames (the
 * server plays the nearest recorded frame anyway), the body's start to scene
 * frames. Nothing is dragged before scene time 0 (nothing plays there)
 * unless the instance was already there. The crop never leaves the template
 * and keeps at least one template frame.
 */
export function dragValues(part: DragPart, t0: Timing, dScene: number, sceneFrameRate: number): InstanceValues {
  const minLength = 1 / t0.templateFrameRate;
  const earliest = Math.min(0, t0.start);
  if (part === 'body') return { start: Math.max(earliest, snap(t0.start + dScene, sceneFrameRate)) };
  const tDelta = dScene * t0.speed; // template seconds under the pointer's move
  if (part === 'right') {
    if (!t0.reverse) return { crop_end: clamp(snap(t0.end + tDelta, t0.templateFrameRate), t0.begin + minLength, t0.duration) };
    return { crop_begin: clamp(snap(t0.begin - tDelta, t0.templateFrameRate), 0, t0.end - minLength) };
  }
  // Left end: the scene end stays where it was; start follows the new length.
  const fixedEnd = sceneEnd(t0);
  const longest = (fixedEnd - earliest) * t0.speed; // template seconds that fit after `earliest`
  if (!t0.reverse) {
    const begin = clamp(snap(t0.begin + tDelta, t0.templateFrameRate), Math.max(0, t0.end - longest), t0.end - minLength);
    return { crop_begin: begin, start: fixedEnd - (t0.end - begin) / t0.speed };
  }
  const end = clamp(snap(t0.end - tDelta, t0.templateFrameRate), t0.begin + minLength, Math.min(t0.duration, t0.begin + longest));
  return { crop_end: end, start: fixedEnd - (end - t0.begin) / t0.speed };
}

const NICE = [1, 2, 5];

/**
 * Ruler steps in whole frames at `pxPerFrame`: major ticks at least `minPx`
 * apart (frames: 1, 2, 5 × 10^k frames; seconds: 1, 2, 5 × 10^k seconds that
 * are whole frames at `frameRate`, else whole frames), minor ticks a divisor
 * of it at least 6 px apart (every frame when there is room).
 */
export function frameTickStep(pxPerFrame: number, frameRate: number, minPx: number, units: 'frames' | 'seconds'): { major: number; minor: number } {
  let major = 0;
  if (units === 'seconds') {
    outer: for (let k = -3; k <= 6; k++) {
      for (const m of NICE) {
        const frames = m * 10 ** k * frameRate;
        if (frames < 1 - 1e-9 || Math.abs(frames - Math.round(frames)) > 1e-6) continue;
        if (Math.round(frames) * pxPerFrame >= minPx) {
          major = Math.round(frames);
          break outer;
        }
      }
    }
  }
  if (major === 0) {
    outer: for (let k = 0; k <= 8; k++) {
      for (const m of NICE) {
        if (m * 10 ** k * pxPerFrame >= minPx) {
          major = m * 10 ** k;
          break outer;
        }
      }
    }
  }
  if (major === 0) major = 1e9;
  let minor = major;
  for (const d of [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000, 5000, 10000]) {
    if (d < major && major % d === 0 && d * pxPerFrame >= 6) {
      minor = d;
      break;
    }
  }
  return { major, minor };
}
