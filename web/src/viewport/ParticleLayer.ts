// The particles of the streamed frames as one THREE.Points. It is the frame
// decoder's ParticleTarget: the decoder writes positions and colours straight
// into this geometry's attribute arrays; they grow by doubling (a new
// geometry, the old one's GPU buffers freed), and only the frame's range is
// uploaded (setDrawRange, addUpdateRange, needsUpdate): all its positions,
// and the colours from the first one the decoder changed (none when the
// particles' kinds and phases are those of the previous frame). An empty
// range uploads nothing (WebGL2's bufferSubData reads a length of 0 as "to the
// end of the array", so a range of 0 would upload the whole capacity).
//
// Points are discs of the particles' world diameter in both cameras. Colours
// are sRGB and written to the framebuffer as they are, so a liquid particle
// of a 2D scene shows exactly the phase colour (tests sample it from
// screenshots).
import * as THREE from 'three';
import type { ParticleTarget } from '../net/FrameDecoder';

const vertexShader = /* glsl */ `
uniform float pointScale;   // framebuffer pixels per metre (orthographic) or per metre at distance 1 (perspective)
uniform float radius;       // m
uniform float perspective;  // 1 or 0
varying vec3 vColor;
void main() {
  vec4 mv = modelViewMatrix * vec4(position, 1.0);
  gl_Position = projectionMatrix * mv;
  float px = 2.0 * radius * pointScale;
  if (perspective > 0.5) px /= max(-mv.z, 1e-4);
  gl_PointSize = max(px, 2.0);
  vColor = color;
}`;

// Discs; in perspective (3D) shaded as spheres lit from the viewer's upper
// left, so that depth reads; orthographic (2D) discs are flat.
const fragmentShader = /* glsl */ `
uniform float perspective;
varying vec3 vColor;
void main() {
  vec2 d = gl_PointCoord - vec2(0.5);
  float r2 = dot(d, d);
  if (r2 > 0.25) discard;
  float shade = 1.0;
  if (perspective > 0.5) {
    vec3 n = vec3(2.0 * d.x, -2.0 * d.y, sqrt(max(1.0 - 4.0 * r2, 0.0)));
    shade = 0.45 + 0.55 * max(dot(n, normalize(vec3(-0.4, 0.5, 0.77))), 0.0);
  }
  gl_FragColor = vec4(vColor * shade, 1.0);
}`;

export class ParticleLayer implements ParticleTarget {
  readonly points: THREE.Points<THREE.BufferGeometry, THREE.ShaderMaterial>;
  readonly material: THREE.ShaderMaterial;
  private geometry: THREE.BufferGeometry;
  private position!: THREE.BufferAttribute;
  private color!: THREE.BufferAttribute;
  private capacity = 0;
  // Upload bookkeeping, reset when three.js uploads the attribute: an upload
  // is pending (needsUpdate set), and the lowest particle whose colour changed.
  private positionPending = false;
  private colorPending = false;
  private colorDirtyFrom = Infinity;
  count = 0;

  constructor(name = 'particles') {
    this.material = new THREE.ShaderMaterial({
      vertexShader,
      fragmentShader,
      vertexColors: true,
      uniforms: {
        pointScale: { value: 100 },
        radius: { value: 0.005 },
        perspective: { value: 0 },
      },
    });
    this.geometry = this.makeGeometry(0);
    this.points = new THREE.Points(this.geometry, this.material);
    this.points.frustumCulled = false;
    this.points.name = name;
  }

  reserve(n: number) {
    if (n > this.capacity) {
      let cap = Math.max(4096, this.capacity);
      while (cap < n) cap *= 2;
      const old = this.geometry;
      this.geometry = this.makeGeometry(cap);
      this.points.geometry = this.geometry;
      old.dispose();
    }
    return { positions: this.position.array as Float32Array, colors: this.color.array as Float32Array };
  }

  /** The first n particles are the new frame; the colours of those before `colorsFrom` are unchanged since the last commit. */
  commit(n: number, colorsFrom = 0) {
    this.count = n;
    this.geometry.setDrawRange(0, n);
    this.positionPending = markRange(this.position, 0, n, this.positionPending);
    // Colours to upload: from the lowest particle any commit changed since the last upload.
    this.colorDirtyFrom = Math.min(this.colorDirtyFrom, colorsFrom);
    this.colorPending = markRange(this.color, Math.min(this.colorDirtyFrom, n), n, this.colorPending);
  }

  setRadius(r: number) {
    this.material.uniforms['radius']!.value = r;
  }

  /** Called before each render with the camera that draws. */
  updateScale(camera: THREE.Camera, drawingBufferHeight: number) {
    const u = this.material.uniforms;
    if (camera instanceof THREE.OrthographicCamera) {
      u['pointScale']!.value = (drawingBufferHeight * camera.zoom) / (camera.top - camera.bottom);
      u['perspective']!.value = 0;
    } else if (camera instanceof THREE.PerspectiveCamera) {
      u['pointScale']!.value = drawingBufferHeight / (2 * Math.tan(THREE.MathUtils.degToRad(camera.fov) / 2));
      u['perspective']!.value = 1;
    }
  }

  private makeGeometry(cap: number): THREE.BufferGeometry {
    const g = new THREE.BufferGeometry();
    this.capacity = cap;
    this.position = new THREE.BufferAttribute(new Float32Array(3 * cap), 3).setUsage(THREE.DynamicDrawUsage);
    this.color = new THREE.BufferAttribute(new Float32Array(3 * cap), 3).setUsage(THREE.DynamicDrawUsage);
    const position = this.position, color = this.color;
    position.onUpload(() => {
      if (this.position === position) this.positionPending = false;
    });
    color.onUpload(() => {
      if (this.color !== color) return;
      this.colorPending = false;
      this.colorDirtyFrom = Infinity;
    });
    // A new buffer is uploaded whole when first drawn.
    this.positionPending = this.colorPending = false;
    this.colorDirtyFrom = Infinity;
    g.setAttribute('position', this.position);
    g.setAttribute('color', this.color);
    g.setDrawRange(0, 0);
    return g;
  }

  dispose() {
    this.geometry.dispose();
    this.material.dispose();
  }
}

/**
 * Marks particles [from, to) of `a` for upload, replacing earlier marks (which
 * cover at most what is still pending); returns whether an upload is pending.
 * An empty range marks nothing, unless an upload is already pending
 * (needsUpdate cannot be withdrawn, and a pending upload without a range
 * would send the whole array): then it keeps one particle.
 */
function markRange(a: THREE.BufferAttribute, from: number, to: number, pending: boolean): boolean {
  a.clearUpdateRanges();
  if (to > from) {
    a.addUpdateRange(3 * from, 3 * (to - from));
    a.needsUpdate = true;
    return true;
  }
  if (pending) a.addUpdateRange(0, Math.min(3, a.array.length));
  return pending;
}
