// The control stage (Schoentgen et al. 2020 [SPDM20], section 4): one file because its
// per-substep loops share the instance state and the vectorised sums.
// GCC 12 warns that the AVX-512 reductions and rsqrt14 read an uninitialised
// operand: it is _mm512_undefined_ps, by design, so the warning is false.
// The pragmas precede the includes, where the intrinsics are parsed.
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include "control/control.h"
#include "core/kernel_sums.h"
#include <omp.h>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <type_traits>
#if defined(__AVX512F__)
#include <immintrin.h>
#endif

namespace fc {

namespace {
using Clock = std::chrono::steady_clock;
// Below this many items a light loop (a few flops per item) runs on one
// thread: forking the team costs more than the work.
constexpr long kParallelMin = 2048;
double msSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// World AABB of an affine image of a box.
template <int D>
AABB<D> imageBox(const Affine<D>& map, const AABB<D>& box) {
  AABB<D> out;
  out.min.setConstant(std::numeric_limits<Real>::max());
  out.max.setConstant(-std::numeric_limits<Real>::max());
  for (int corner = 0; corner < (1 << D); ++corner) {
    Vec<D> p;
    for (int d = 0; d < D; ++d) p[d] = (corner >> d) & 1 ? box.max[d] : box.min[d];
    const Vec<D> q = map.point(p);
    out.min = out.min.cwiseMin(q);
    out.max = out.max.cwiseMax(q);
  }
  return out;
}

// The sums of equations (2), (4) and (5) at a liquid particle at y
// (template space): over the control particles near it, A = α m/ρ0,
// C = (1 − α) m/ρ0, V = v_j; over the repulsion particles near it,
// R = m/ρ0 · n_k. velocity is Σ C W (V − u), formed at the end from Σ C W V
// and Σ C W (= rate).
template <int D>
struct ControlSums {
  Vec<D> attraction = Vec<D>::Zero(), velocity = Vec<D>::Zero();
  Real rate = 0;
};

// What the sums read, one array per field: per control particle its
// position per axis, A, C and V per axis; per repulsion particle its
// position and R per axis. Kept apart, so that neither sum loads or adds
// the other kind's zeros.
template <int D>
struct ControlFields {
  static constexpr int kCount = 2 * D + 2;
  static constexpr int X = 0, A = D, C = D + 1, V = D + 2;
  std::array<const Real*, kCount> field;
};
template <int D>
struct RepulsionFields {
  static constexpr int kCount = 2 * D;
  static constexpr int X = 0, R = D;
  std::array<const Real*, kCount> field;
};

// The static points of `grid` within h of the box [lo, hi] (one grid cell's
// particles), their F fields (the first D: position per axis, in the grid's
// order) copied into `out`: contiguous, so that each of the cell's particles
// then scans one short array sixteen at a time instead of 3^(D-1) rows of
// cells with their ragged ends. The box's neighbours only: about 3/4 of the
// 3^D cells' volume. Returns the count. `out` has room for every point plus
// one register per field.
template <int D, int F>
size_t nearPoints(const NeighborhoodSearch<D>& grid, const std::array<const Real*, F>& in, const Vec<D>& lo,
                  const Vec<D>& hi, Real h, const std::array<Real*, F>& out) {
  const Real h2 = h * h;
  size_t m = 0;
  const Vec<D> centre = Real(0.5) * (lo + hi);
  if constexpr (kVectorSums) {
#if defined(__AVX512F__)
    __m512 lov[D], hiv[D];
    for (int d = 0; d < D; ++d) {
      lov[d] = _mm512_set1_ps(lo[d]);
      hiv[d] = _mm512_set1_ps(hi[d]);
    }
    const __m512 h2v = _mm512_set1_ps(h2), zero = _mm512_setzero_ps();
    grid.forEachStaticRange(centre, h, [&](uint32_t b, uint32_t e) {
      for (uint32_t k = b; k < e; k += 16) {
        const __mmask16 live = e - k >= 16 ? __mmask16(0xFFFF) : __mmask16((1u << (e - k)) - 1);
        __m512 d2 = zero;
        for (int d = 0; d < D; ++d) {
          const __m512 x = _mm512_maskz_loadu_ps(live, in[d] + k);
          const __m512 out = _mm512_max_ps(_mm512_max_ps(_mm512_sub_ps(lov[d], x), _mm512_sub_ps(x, hiv[d])), zero);
          d2 = _mm512_fmadd_ps(out, out, d2);
        }
        const __mmask16 keep = _mm512_mask_cmp_ps_mask(live, d2, h2v, _CMP_LT_OQ);
        if (!keep) continue;
        for (int f = 0; f < F; ++f)
          _mm512_storeu_ps(out[f] + m, _mm512_maskz_compress_ps(keep, _mm512_maskz_loadu_ps(live, in[f] + k)));
        m += size_t(__builtin_popcount(keep));
      }
    });
#endif
  } else {
    grid.forEachStaticRange(centre, h, [&](uint32_t b, uint32_t e) {
      for (uint32_t k = b; k < e; ++k) {
        Real d2 = 0;
        for (int d = 0; d < D; ++d) {
          const Real x = in[d][k];
          const Real o = std::max({lo[d] - x, x - hi[d], Real(0)});
          d2 += o * o;
        }
        if (!(d2 < h2)) continue;
        for (int f = 0; f < F; ++f) out[f][m] = in[f][k];
        ++m;
      }
    });
  }
  return m;
}

// Σ_k w_k W(‖x_k − p‖, h) over `count` points gathered by nearPoints
// (fields: position per axis, then w).
template <int D>
Real poly6SumNear(const std::array<const Real*, D + 1>& in, size_t count, const Poly6<D>& kernel, const Vec<D>& p) {
  Poly6Accumulator<D> sum(kernel, p);
  sum.add(in.data(), in[D], 0, count);
  return sum.total();
}

// w_r as applied: 0 when the instance's repulsion layer is off.
Real repulsionWeight(const InstanceParams& p) {
  return p.repulsion ? Real(p.repulsionWeight) * kAccelerationScale : Real(0);
}

// The cells of `grid` holding at least one of its static points (ascending).
template <int D>
void occupiedCells(const NeighborhoodSearch<D>& grid, std::vector<uint32_t>& out) {
  out.clear();
  const uint32_t* start = grid.staticCellStart();
  for (size_t c = 0; c < grid.cellCount(); ++c)
    if (start[c] < start[c + 1]) out.push_back(uint32_t(c));
}

// Per-thread scratch of at least `values` Reals, grown (never shrunk):
// allocation happens at the first frames only.
void reserveScratch(std::vector<std::vector<Real>>& perThread, size_t values) {
  perThread.resize(size_t(omp_get_max_threads()));
  for (auto& buf : perThread)
    if (buf.size() < values) buf.resize(values);
}

// Equations (2) and (4) over `count` control particles gathered by
// nearPoints; the repulsion sum is left 0.
template <int D>
ControlSums<D> controlSums(const ControlFields<D>& in, size_t count, const Poly6<D>& kernel, const Vec<D>& y,
                           const Vec<D>& u, Real dMin) {
  using F = ControlFields<D>;
  const Real h2 = kernel.radius() * kernel.radius(), kc = kernel.coefficient();
  ControlSums<D> out;
  Vec<D> velocityWeighted = Vec<D>::Zero();
  if constexpr (kVectorSums) {
#if defined(__AVX512F__)
    __m512 yv[D], att[D], vel[D];
    for (int d = 0; d < D; ++d) {
      yv[d] = _mm512_set1_ps(y[d]);
      att[d] = vel[d] = _mm512_setzero_ps();
    }
    __m512 rate = _mm512_setzero_ps();
    const __m512 h2v = _mm512_set1_ps(h2), invDMinV = _mm512_set1_ps(1 / dMin);
    for (size_t k = 0; k < count; k += 16) {
      const __mmask16 live = count - k >= 16 ? __mmask16(0xFFFF) : __mmask16((1u << (count - k)) - 1);
      __m512 r[D];
      __m512 d2 = _mm512_setzero_ps();
      for (int d = 0; d < D; ++d) {
        r[d] = _mm512_sub_ps(_mm512_maskz_loadu_ps(live, in.field[F::X + d] + k), yv[d]);
        d2 = _mm512_fmadd_ps(r[d], r[d], d2);
      }
      const __mmask16 hit = _mm512_mask_cmp_ps_mask(live, d2, h2v, _CMP_LT_OQ);
      if (!hit) continue;
      const __m512 t = _mm512_maskz_sub_ps(hit, h2v, d2);
      const __m512 w = _mm512_mul_ps(_mm512_mul_ps(t, t), t);  // 0 off the hits
      // 1 / max(d, d_min) = min(1/d, 1/d_min), from the reciprocal square
      // root estimate (relative error < 2^-14, ample for the pull's
      // direction and weight).
      // At d = 0 the estimate is +inf and min gives 1/d_min.
      const __m512 inv = _mm512_min_ps(_mm512_rsqrt14_ps(d2), invDMinV);
      const __m512 pull = _mm512_mul_ps(_mm512_mul_ps(_mm512_maskz_loadu_ps(hit, in.field[F::A] + k), w), inv);
      const __m512 covered = _mm512_mul_ps(_mm512_maskz_loadu_ps(hit, in.field[F::C] + k), w);
      for (int d = 0; d < D; ++d) {
        att[d] = _mm512_fmadd_ps(pull, r[d], att[d]);
        vel[d] = _mm512_fmadd_ps(covered, _mm512_maskz_loadu_ps(hit, in.field[F::V + d] + k), vel[d]);
      }
      rate = _mm512_add_ps(rate, covered);
    }
    for (int d = 0; d < D; ++d) {
      out.attraction[d] = _mm512_reduce_add_ps(att[d]);
      velocityWeighted[d] = _mm512_reduce_add_ps(vel[d]);
    }
    out.rate = _mm512_reduce_add_ps(rate);
#endif
  } else {
    for (size_t k = 0; k < count; ++k) {
      Vec<D> r;
      for (int d = 0; d < D; ++d) r[d] = in.field[F::X + d][k] - y[d];
      const Real d2 = r.squaredNorm();
      if (!(d2 < h2)) continue;
      const Real t = h2 - d2;
      const Real w = t * t * t;
      out.attraction += (in.field[F::A][k] * w / std::max(std::sqrt(d2), dMin)) * r;
      const Real covered = in.field[F::C][k] * w;
      for (int d = 0; d < D; ++d) velocityWeighted[d] += covered * in.field[F::V + d][k];
      out.rate += covered;
    }
  }
  out.attraction *= kc;
  out.rate *= kc;
  out.velocity = kc * velocityWeighted - out.rate * u;
  return out;
}

// Σ_k R_k W(y − x_k, h_T) of equation (5) over `count` repulsion particles
// gathered by nearPoints.
template <int D>
Vec<D> repulsionSum(const RepulsionFields<D>& in, size_t count, const Poly6<D>& kernel, const Vec<D>& y) {
  using F = RepulsionFields<D>;
  const Real h2 = kernel.radius() * kernel.radius();
  Vec<D> out = Vec<D>::Zero();
  if constexpr (kVectorSums) {
#if defined(__AVX512F__)
    __m512 yv[D], rep[D];
    for (int d = 0; d < D; ++d) {
      yv[d] = _mm512_set1_ps(y[d]);
      rep[d] = _mm512_setzero_ps();
    }
    const __m512 h2v = _mm512_set1_ps(h2);
    for (size_t k = 0; k < count; k += 16) {
      const __mmask16 live = count - k >= 16 ? __mmask16(0xFFFF) : __mmask16((1u << (count - k)) - 1);
      __m512 d2 = _mm512_setzero_ps();
      for (int d = 0; d < D; ++d) {
        const __m512 r = _mm512_sub_ps(_mm512_maskz_loadu_ps(live, in.field[F::X + d] + k), yv[d]);
        d2 = _mm512_fmadd_ps(r, r, d2);
      }
      const __mmask16 hit = _mm512_mask_cmp_ps_mask(live, d2, h2v, _CMP_LT_OQ);
      if (!hit) continue;
      const __m512 t = _mm512_maskz_sub_ps(hit, h2v, d2);
      const __m512 w = _mm512_mul_ps(_mm512_mul_ps(t, t), t);  // 0 off the hits
      for (int d = 0; d < D; ++d)
        rep[d] = _mm512_fmadd_ps(w, _mm512_maskz_loadu_ps(hit, in.field[F::R + d] + k), rep[d]);
    }
    for (int d = 0; d < D; ++d) out[d] = _mm512_reduce_add_ps(rep[d]);
#endif
  } else {
    for (size_t k = 0; k < count; ++k) {
      Real d2 = 0;
      for (int d = 0; d < D; ++d) d2 += (in.field[F::X + d][k] - y[d]) * (in.field[F::X + d][k] - y[d]);
      if (!(d2 < h2)) continue;
      const Real t = h2 - d2;
      const Real w = t * t * t;
      for (int d = 0; d < D; ++d) out[d] += w * in.field[F::R + d][k];
    }
  }
  return kernel.coefficient() * out;
}

template <int D>
void checkBound(const std::vector<BoundInstance<D>>& instances) {
  for (size_t i = 0; i < instances.size(); ++i) {
    const auto& b = instances[i];
    if (!b.accel || !b.accel->source) throw std::invalid_argument("instance " + std::to_string(i) + " is not bound");
    if (b.spec.transform.keys.empty())
      throw std::invalid_argument("instance '" + b.spec.name + "' has no transform key");
    if (!(b.accel->supportRadius > 0))
      throw std::invalid_argument("instance '" + b.spec.name + "': template without support radius");
  }
}
}  // namespace

template <int D>
Control<D>::Control(std::vector<BoundInstance<D>> instances, const ControlSettings& settings)
    : instances_(std::move(instances)), settings_(settings) {
  checkBound(instances_);
  state_.resize(instances_.size());
}

template <int D>
void Control<D>::setInstances(std::vector<BoundInstance<D>> instances) {
  checkBound(instances);
  instances_ = std::move(instances);
  state_.assign(instances_.size(), State{});
  forcesDue_ = true;
  measureFidelity_ = true;
}

template <int D>
void Control<D>::init(Simulation<D>& sim) {
  clearParticleMemory();
  temporaries_ = size_t(std::count(sim.fluid.kind.begin(), sim.fluid.kind.end(), uint8_t(ParticleKind::Temporary)));
}

template <int D>
void Control<D>::clearParticleMemory() {
  std::fill(controlAcc_.begin(), controlAcc_.end(), Vec<D>::Zero());
  std::fill(framesOutside_.begin(), framesOutside_.end(), 0u);
  std::fill(touched_.begin(), touched_.end(), uint8_t(0));
  controlled_.clear();
  for (State& s : state_) {
    s.liquid.clear();
    s.y.clear();
    s.fade.clear();
  }
  forcesDue_ = true;
  measureFidelity_ = true;
}

template <int D>
void Control<D>::archiveState(StateArchive& a) {
  // The forces and gathered lists are recomputed at the next frame's start;
  // what carries over is each temporary particle's time outside the boxes.
  if (a.loading()) clearParticleMemory();
  a.io(framesOutside_);
  a.io(temporaries_);
}

template <int D>
void Control<D>::prepare(size_t i, double time) {
  const BoundInstance<D>& inst = instances_[i];
  const Template<D>& tpl = inst.templ();
  State& s = state_[i];
  s.frame = inst.spec.time.frameAt(time, tpl.header.frameRate, tpl.frameCount());
  const TransformTrack<D>& track = inst.spec.transform;
  const Vec<D> c = inst.centre();
  s.toWorld = track.templateToWorld(time, c);
  s.toTemplate = s.toWorld.inverse();
  s.volumeScale = std::abs(s.toWorld.determinant());
  const Real hT = inst.accel->supportRadius;
  s.kernel.setRadius(hT);
  // A world length w spans w / ‖L e_d‖ template units along template axis d.
  const Real width = Real(inst.spec.params.falloffWidth);
  s.decay = Real(inst.spec.params.falloffDecay);
  s.region = tpl.region();
  const AABB<D>& region = s.region;
  for (int d = 0; d < D; ++d) {
    const Real stretch = s.toWorld.linear.col(d).norm();
    s.falloff[d] = width / stretch;
    const Real grow = std::max(s.falloff[d], hT);
    s.gatherBox.min[d] = region.min[d] - grow;
    s.gatherBox.max[d] = region.max[d] + grow;
  }
  s.worldBox = imageBox<D>(s.toWorld, s.gatherBox);
  s.regionWorldBox = imageBox<D>(s.toWorld, s.region);
  s.velocityFactor = Real(inst.spec.time.velocityFactor());
  // A keyframed instance carries its liquid: world velocity G x + g of the
  // carried point at x (central difference of the track, in double).
  s.velocityGradient.setZero();
  s.velocityOffset.setZero();
  if (track.animated()) {
    Eigen::Matrix<double, D, D> g;
    Eigen::Matrix<double, D, 1> o;
    track.velocityMap(time, g, o);
    s.velocityGradient = g.template cast<Real>();
    s.velocityOffset = o.template cast<Real>();
  }
}

template <int D>
void Control<D>::selectActive(double time) {
  for (size_t i = 0; i < instances_.size(); ++i) {
    const Template<D>& tpl = instances_[i].templ();
    State& s = state_[i];
    s.on = tpl.frameCount() > 0 && instances_[i].spec.time.active(time, tpl.duration());
    if (s.on) prepare(i, time);
    else {
      s.fidelity = -1;
      s.liquid.clear();
    }
  }
}

template <int D>
Real Control<D>::bandCoordinate(size_t i, const Vec<D>& y) const {
  const State& s = state_[i];
  const AABB<D>& region = s.region;
  Real frac2 = 0;
  for (int d = 0; d < D; ++d) {
    const Real out = std::max({region.min[d] - y[d], y[d] - region.max[d], Real(0)});
    if (out <= 0) continue;
    if (!(s.falloff[d] > 0)) return 0;
    const Real f = out / s.falloff[d];
    frac2 += f * f;
  }
  return frac2 >= 1 ? Real(0) : Real(1) - std::sqrt(frac2);
}

template <int D>
bool Control<D>::insideBox(size_t i, const Vec<D>& y) const {
  return state_[i].region.contains(y);
}

template <int D>
bool Control<D>::insideAnyInstance(const Vec<D>& xWorld) const {
  for (size_t i = 0; i < instances_.size(); ++i) {
    if (!state_[i].on) continue;
    if (bandCoordinate(i, state_[i].toTemplate.point(xWorld)) > 0) return true;
  }
  return false;
}

// Control only visits the liquid inside an instance's box and band: a grid
// query over the world AABB of that region.
template <int D>
void Control<D>::gather(size_t i, const Simulation<D>& sim) {
  State& s = state_[i];
  std::vector<uint32_t>& candidates = candidates_;
  // The grid is the last substep's: a particle has moved less than one cell
  // since, so the box grown by a cell finds every particle now inside it
  // (the exact test below uses today's positions).
  sim.search.dynamicInBox(s.worldBox.grown(sim.search.radius()), candidates);
  // Transform and fade the candidates, then keep them in cell order, in
  // parallel when there are many: each thread its own block of
  // candidates, written after the blocks before it (the result does not
  // depend on the thread count).
  const long nc = long(candidates.size());
  candidateY_.resize(size_t(nc));
  candidateFade_.resize(size_t(nc));
  keptBefore_.assign(size_t(omp_get_max_threads()) + 1, 0);
  const int phase = instances_[i].spec.phase;
  const bool linearFade = s.decay == 1;  // the default γ: no pow in the band
#pragma omp parallel if (nc >= 1024)
  {
    const int t = omp_get_thread_num(), threads = omp_get_num_threads();
    const long b = nc * t / threads, e = nc * (t + 1) / threads;
    size_t kept = 0;
    for (long k = b; k < e; ++k) {
      const uint32_t p = candidates[k];
      candidateFade_[k] = -1;  // not gathered
      if (sim.fluid.phase[p] != phase) continue;
      const Vec<D> y = s.toTemplate.point(sim.fluid.x[p]);
      if (!s.gatherBox.contains(y)) continue;
      const Real f = bandCoordinate(i, y);
      candidateY_[k] = y;
      // Inside the box t = 1: no pow for most of the liquid.
      candidateFade_[k] = f >= 1 ? Real(1) : f > 0 ? (linearFade ? f : std::pow(f, s.decay)) : Real(0);
      ++kept;
    }
    keptBefore_[size_t(t) + 1] = kept;
#pragma omp barrier
#pragma omp single
    {
      for (int u = 0; u < threads; ++u) keptBefore_[size_t(u) + 1] += keptBefore_[size_t(u)];
      const size_t total = keptBefore_[size_t(threads)];
      s.liquid.resize(total);
      s.y.resize(total);
      s.fade.resize(total);
    }
    size_t w = keptBefore_[size_t(t)];
    for (long k = b; k < e; ++k) {
      if (candidateFade_[k] < 0) continue;
      s.liquid[w] = candidates[k];
      s.y[w] = candidateY_[k];
      s.fade[w] = candidateFade_[k];
      ++w;
    }
  }
}

// α_j = 1 − min(Σ_i (m_i/ρ_i) W(x_j − x_i, h), 1): equation (3) in [SPDM20],
// with the liquid's volumes mapped into template space. Also builds two of
// the grids the force sums walk: the gathered liquid (localGrid_) and the
// frame's control particles (controlGrid_), on the same cells.
template <int D>
void Control<D>::computeCoverage(size_t i, const Simulation<D>& sim) {
  State& s = state_[i];
  const auto gridsHeld = instances_[i].accel->frame(s.frame);  // keeps a streamed frame while it is read
  const TemplateFrameGrids<D>& grids = *gridsHeld;
  const auto& xc = grids.controlPositions();
  const long nc = long(xc.size());
  s.alpha.assign(size_t(nc), Real(1));
  const Real hT = s.kernel.radius();
  // Built even when empty: the force sums walk its cells.
  localGrid_.setGrid(s.gatherBox, hT);
  localGrid_.setStaticPoints(s.y);
  // Built per evaluation: the template frame changes every time.
  controlGrid_.setGrid(s.gatherBox, hT);
  controlGrid_.setStaticPoints(xc);
  if (s.liquid.empty() || nc == 0) return;
  const Real invScale = Real(1) / s.volumeScale;
  const uint32_t* order = localGrid_.staticOrder();
  const long n = long(s.liquid.size());
  sortedVolume_.resize(size_t(n));
#pragma omp parallel for schedule(static) if (n >= kParallelMin)
  for (long k = 0; k < n; ++k) {
    const uint32_t p = s.liquid[order[k]];
    sortedVolume_[size_t(k)] = sim.fluid.mass[p] / sim.fluid.density[p];
  }
  std::array<const Real*, D + 1> liquidFields;
  for (int d = 0; d < D; ++d) liquidFields[d] = localGrid_.staticSorted(d);
  liquidFields[D] = sortedVolume_.data();
  // The control particles one cell of controlGrid_ at a time: they share
  // the liquid around.
  occupiedCells(controlGrid_, occupiedCells_);
  const uint32_t* cellStart = controlGrid_.staticCellStart();
  const uint32_t* pointOrder = controlGrid_.staticOrder();
  const size_t stride = size_t(n) + 16;  // + one register: the packing stores whole ones
  reserveScratch(nearPoints_, stride * (D + 1));
  const long cells = long(occupiedCells_.size());
  // Guided, not dynamic in chunks of a few cells: a few hundred cells a
  // frame, and every chunk taken is an atomic on one shared counter that
  // both threads bounce between their caches (measured slower: see
  // docs/performance.md). Each cell writes only its own particles: the
  // result does not depend on the schedule.
#pragma omp parallel for schedule(guided)
  for (long ci = 0; ci < cells; ++ci) {
    const uint32_t c = occupiedCells_[size_t(ci)];
    const uint32_t b = cellStart[c], e = cellStart[c + 1];
    Vec<D> lo = Vec<D>::Constant(std::numeric_limits<Real>::max()), hi = -lo;
    for (uint32_t k = b; k < e; ++k) {
      lo = lo.cwiseMin(xc[pointOrder[k]]);
      hi = hi.cwiseMax(xc[pointOrder[k]]);
    }
    Real* buf = nearPoints_[size_t(omp_get_thread_num())].data();
    std::array<Real*, D + 1> nearOut;
    std::array<const Real*, D + 1> near;
    for (int f = 0; f <= D; ++f) near[f] = nearOut[f] = buf + size_t(f) * stride;
    const size_t count = nearPoints<D, D + 1>(localGrid_, liquidFields, lo, hi, hT, nearOut);
    for (uint32_t k = b; k < e; ++k) {
      const uint32_t q = pointOrder[k];
      const Real sum = poly6SumNear<D>(near, count, s.kernel, xc[q]);
      s.alpha[q] = Real(1) - std::min(sum * invScale, Real(1));
    }
  }
}

template <int D>
void Control<D>::addInstanceForces(size_t i, Simulation<D>& sim, Real applyFor) {
  State& s = state_[i];
  const BoundInstance<D>& inst = instances_[i];
  const auto gridsHeld = inst.accel->frame(s.frame);  // keeps a streamed frame while it is read
  const TemplateFrameGrids<D>& grids = *gridsHeld;
  const auto& xc = grids.controlPositions();
  const auto& vc = grids.controlVelocities();
  const auto& mc = grids.controlMasses();
  const Real invRho0 = Real(1) / Real(inst.templ().header.restDensity);
  const long nc = long(xc.size());
  const Mat<D> linv = s.toTemplate.linear;
  const bool moving = inst.spec.transform.animated();
  const InstanceParams& p = inst.spec.params;
  const Real wa = Real(p.attractionWeight) * kAccelerationScale;
  const Real wv = Real(p.velocityWeight) * kRateScale;
  const Real wr = repulsionWeight(p);
  // The sums' fields, in controlGrid_'s order (computeCoverage built it)
  // and in repulsionGrid_'s.
  const uint32_t* order = controlGrid_.staticOrder();
  forceA_.resize(size_t(nc));
  forceC_.resize(size_t(nc));
  for (auto& v : forceV_) v.resize(size_t(nc));
#pragma omp parallel for schedule(static) if (nc >= kParallelMin)
  for (long k = 0; k < nc; ++k) {
    const uint32_t q = order[k];
    const Real volume = mc[q] * invRho0;
    forceA_[k] = s.alpha[q] * volume;
    forceC_[k] = (Real(1) - s.alpha[q]) * volume;
    // v_j as the liquid should follow it: played at `speed`, negated when
    // reversed (paper §3.5), plus the instance's own motion, in template
    // space.
    Vec<D> v = s.velocityFactor * vc[q];
    if (moving) v += linv * (s.velocityGradient * s.toWorld.point(xc[q]) + s.velocityOffset);
    for (int d = 0; d < D; ++d) forceV_[d][k] = v[d];
  }
  using CF = ControlFields<D>;
  using RF = RepulsionFields<D>;
  CF controlFields;
  controlFields.field[CF::A] = forceA_.data();
  controlFields.field[CF::C] = forceC_.data();
  for (int d = 0; d < D; ++d) {
    controlFields.field[CF::X + d] = controlGrid_.staticSorted(d);
    controlFields.field[CF::V + d] = forceV_[d].data();
  }
  const auto& xr = grids.repulsionPositions();
  const size_t nr = wr > 0 ? xr.size() : 0;
  RF repulsionFields;
  if (nr > 0) {
    repulsionGrid_.setGrid(s.gatherBox, s.kernel.radius());
    repulsionGrid_.setStaticPoints(xr);
    const auto& repN = grids.repulsionNormals();
    const auto& repSrc = grids.repulsionSources();
    const uint32_t* rorder = repulsionGrid_.staticOrder();
    for (auto& v : forceR_) v.resize(nr);
    for (size_t k = 0; k < nr; ++k) {
      const uint32_t r = rorder[k];
      const Real volume = mc[repSrc[r]] * invRho0;
      for (int d = 0; d < D; ++d) forceR_[d][k] = volume * repN[r][d];
    }
    for (int d = 0; d < D; ++d) {
      repulsionFields.field[RF::X + d] = repulsionGrid_.staticSorted(d);
      repulsionFields.field[RF::R + d] = forceR_[d].data();
    }
  }
  const Real maxRate = applyFor > 0 ? Real(1) / applyFor : std::numeric_limits<Real>::max();
  const Real hT = s.kernel.radius();
  // Attraction and repulsion are held for the whole application (a frame by
  // default), whatever the particle does meanwhile: beyond ½ |a| T² = h_T
  // they would carry it past every control particle they were computed
  // from. Capped there (template space; at most 2 h_T / T of velocity per
  // application). The paper's 2D default weights stay below the cap: with
  // sums of at most 1 their pull is (0.2 + 0.1) · kAccelerationScale = 90
  // m/s², the cap 2 h_T / T² = 173 m/s² for the shipped 2D templates (h_T =
  // 0.024 m) at 60 frames/s. Without it, weights inside their declared range
  // (attraction 7.9, repulsion 18.8) launched the 2D drop scene's pool at
  // 21 m/s in the first frame (Stability.FiftyRandomInstancesOnTheDropScene).
  const Real maxPull = applyFor > 0 ? 2 * hT / (applyFor * applyFor) : std::numeric_limits<Real>::max();
  // Eq. (2)'s direction (x_j − x)/d is undefined when a liquid particle sits
  // on a control particle (lattices coincide often): below h/16 the pull
  // fades linearly to zero instead of pointing at rounding noise.
  const Real dMin = hT / 16;
  const Mat<D> l = s.toWorld.linear;
  const auto& kernel = s.kernel;
  const long n = long(s.liquid.size());
  // The liquid one cell of localGrid_ (built on s.y, the same cells as
  // controlGrid_ and repulsionGrid_) at a time: its particles share the
  // control and repulsion particles around.
  occupiedCells(localGrid_, occupiedCells_);
  const uint32_t* cellStart = localGrid_.staticCellStart();
  const uint32_t* liquidOrder = localGrid_.staticOrder();
  // + one register per field: the packing stores whole ones.
  const size_t controlStride = size_t(nc) + 16, repulsionStride = nr + 16;
  const size_t repulsionAt = controlStride * CF::kCount;
  reserveScratch(nearPoints_, repulsionAt + repulsionStride * RF::kCount);
  const long cells = long(occupiedCells_.size());
  // Guided: see computeCoverage.
#pragma omp parallel for schedule(guided)
  for (long ci = 0; ci < cells; ++ci) {
    const uint32_t c = occupiedCells_[size_t(ci)];
    const uint32_t b = cellStart[c], e = cellStart[c + 1];
    Vec<D> lo = Vec<D>::Constant(std::numeric_limits<Real>::max()), hi = -lo;
    for (uint32_t k = b; k < e; ++k) {
      const uint32_t li = liquidOrder[k];
      if (!(s.fade[li] > 0)) continue;
      lo = lo.cwiseMin(s.y[li]);
      hi = hi.cwiseMax(s.y[li]);
    }
    if (!(lo[0] <= hi[0])) continue;  // none of the cell's liquid is controlled
    Real* buf = nearPoints_[size_t(omp_get_thread_num())].data();
    CF nearControl;
    RF nearRepulsion;
    std::array<Real*, CF::kCount> controlOut;
    std::array<Real*, RF::kCount> repulsionOut;
    for (int f = 0; f < CF::kCount; ++f) nearControl.field[f] = controlOut[f] = buf + size_t(f) * controlStride;
    for (int f = 0; f < RF::kCount; ++f)
      nearRepulsion.field[f] = repulsionOut[f] = buf + repulsionAt + size_t(f) * repulsionStride;
    const size_t controls = nearPoints<D, CF::kCount>(controlGrid_, controlFields.field, lo, hi, hT, controlOut);
    const size_t repulsions =
        nr > 0 ? nearPoints<D, RF::kCount>(repulsionGrid_, repulsionFields.field, lo, hi, hT, repulsionOut) : 0;
    for (uint32_t kk = b; kk < e; ++kk) {
      const uint32_t k = liquidOrder[kk];
      if (!(s.fade[k] > 0)) continue;
      const uint32_t idx = s.liquid[k];
      const Vec<D> y = s.y[k];
      const Vec<D> u = linv * sim.fluid.v[idx];
      // Equation (2) in [SPDM20]: towards uncovered control particles;
      // equation (4): towards their velocity, where covered; equation (5):
      // away from the repulsion layer (the stored normals point outwards).
      const ControlSums<D> sums = controlSums<D>(nearControl, controls, kernel, y, u, dMin);
      const Vec<D>& attraction = sums.attraction;
      const Vec<D>& velocity = sums.velocity;
      const Real rate = sums.rate;
      const Vec<D> repulsion =
          repulsions > 0 ? Vec<D>(-repulsionSum<D>(nearRepulsion, repulsions, kernel, y)) : Vec<D>::Zero();
      // Explicit relaxation overshoots once rate · Δt > 1: cap it there.
      const Real vRate = wv * rate;
      const Real vScale = vRate > maxRate ? maxRate / vRate : Real(1);
      Vec<D> pull = wa * attraction + wr * repulsion;
      const Real pullNorm = pull.norm();
      if (pullNorm > maxPull) pull *= maxPull / pullNorm;
      const Vec<D> a = pull + (wv * vScale) * velocity;
      controlAcc_[idx] += s.fade[k] * (l * a);
    }
  }
  for (long k = 0; k < n; ++k) {
    const uint32_t idx = s.liquid[k];
    if (s.fade[k] > 0 && !touched_[idx]) {
      touched_[idx] = 1;
      controlled_.push_back(idx);
    }
  }
}

// Occupancy IoU between the template frame and the controlled liquid inside
// the instance box, on a grid of cells about one particle spacing wide, in
// template space. Not in the paper: a measure of reproduction for the
// accuracy study.
template <int D>
double Control<D>::measureFidelity(size_t i) {
  const State& s = state_[i];
  const BoundInstance<D>& inst = instances_[i];
  const AABB<D>& region = s.region;
  const auto gridsHeld = inst.accel->frame(s.frame);  // keeps a streamed frame while it is read
  const TemplateFrameGrids<D>& grids = *gridsHeld;
  Real radius = Real(inst.templ().header.particleRadius);
  if (!(radius > 0)) radius = s.kernel.radius() / 4;
  const Real cell = Real(settings_.fidelityCell) * radius;
  VecI<D> dims;
  size_t cells = 1;
  for (int d = 0; d < D; ++d) {
    dims[d] = std::max(1, int(std::ceil((region.max[d] - region.min[d]) / cell)));
    cells *= size_t(dims[d]);
  }
  if (cells > (size_t(1) << 28)) return -1;
  occupancy_.assign(cells, 0);
  const Real perCell = Real(1) / cell;
  auto cellOf = [&](const Vec<D>& y) {
    size_t l = 0;
    for (int d = D - 1; d >= 0; --d) {
      const int c = std::clamp(int((y[d] - region.min[d]) * perCell), 0, dims[d] - 1);
      l = l * size_t(dims[d]) + size_t(c);
    }
    return l;
  };
  // The cells of the control particles, then of the liquid, in parallel
  // (the arithmetic); marked in one thread (a byte each).
  const auto& xc = grids.controlPositions();
  const long nc = long(xc.size()), total = nc + long(s.y.size());
  constexpr uint32_t kOutside = ~uint32_t(0);
  fidelityCells_.resize(size_t(total));
#pragma omp parallel for schedule(static) if (total >= kParallelMin)
  for (long k = 0; k < total; ++k) {
    const Vec<D>& y = k < nc ? xc[size_t(k)] : s.y[size_t(k - nc)];
    fidelityCells_[size_t(k)] = region.contains(y) ? uint32_t(cellOf(y)) : kOutside;
  }
  for (long k = 0; k < total; ++k)
    if (fidelityCells_[size_t(k)] != kOutside) occupancy_[fidelityCells_[size_t(k)]] |= k < nc ? 1 : 2;
  size_t both = 0, any = 0;
  for (uint8_t o : occupancy_) {
    both += o == 3;
    any += o != 0;
  }
  return any ? double(both) / double(any) : -1.0;
}

template <int D>
void Control<D>::computeForces(Simulation<D>& sim, Real applyFor) {
  for (uint32_t p : controlled_) {
    controlAcc_[p].setZero();
    touched_[p] = 0;
  }
  controlled_.clear();
  for (size_t i = 0; i < instances_.size(); ++i) {
    if (!state_[i].on) continue;
    gather(i, sim);
    computeCoverage(i, sim);
    addInstanceForces(i, sim, applyFor);
    if (measureFidelity_) state_[i].fidelity = measureFidelity(i);
  }
  measureFidelity_ = false;
}

template <int D>
void Control<D>::beginFrame(Simulation<D>& sim, FrameStats& fs) {
  const auto t0 = Clock::now();
  seeded_ = removed_ = 0;
  selectActive(sim.time() + timeOffset_);
  forcesDue_ = true;
  measureFidelity_ = true;
  updateTemporaryParticles(sim, fs);
  controlMs_ = msSince(t0);
}

template <int D>
void Control<D>::addAccelerations(Simulation<D>& sim) {
  const bool everySubstep = settings_.forcesEverySubstep;
  const auto t0 = Clock::now();
  if (forcesDue_ || everySubstep) {
    if (everySubstep && !forcesDue_) selectActive(sim.time() + timeOffset_);
    const Real applyFor = everySubstep ? Real(sim.setup().settings.dtMax) : Real(sim.frameDuration());
    computeForces(sim, applyFor);
    forcesDue_ = false;
  }
  const long m = long(controlled_.size());
  const long n = long(sim.fluid.size());
  if (4 * m >= n && controlAcc_.size() == size_t(n)) {
    // Most of the liquid is controlled (blade3d: all of it): one pass over
    // every particle's accelerations (0 where uncontrolled) streams, where
    // the indexed one below measured twice the time.
    Real* a = sim.fluid.a.data()->data();
    const Real* c = controlAcc_.data()->data();
    const long values = n * D;
#pragma omp simd
    for (long k = 0; k < values; ++k) a[k] += c[k];
  } else {
    // Every substep: worth a team from a thousand particles on.
#pragma omp parallel for schedule(static) if (m >= 1024)
    for (long k = 0; k < m; ++k) sim.fluid.a[controlled_[k]] += controlAcc_[controlled_[k]];
  }
  controlMs_ += msSince(t0);
}

template <int D>
void Control<D>::endFrame(Simulation<D>& sim, FrameStats& fs) {
  fs.instances.resize(instances_.size());
  for (size_t i = 0; i < instances_.size(); ++i) {
    const State& s = state_[i];
    InstanceFrameStats& is = fs.instances[i];
    is.name = instances_[i].spec.name;
    is.active = s.on;
    is.templateFrame = s.on ? int(s.frame) : -1;
    is.fidelity = s.on ? s.fidelity : -1;
    is.controlled = 0;
    is.controlParticles = is.repulsionParticles = 0;
    if (!s.on) continue;
    for (Real f : s.fade) is.controlled += f > 0;
    const auto gridsHeld = instances_[i].accel->frame(s.frame);  // keeps a streamed frame while it is read
    const auto& grids = *gridsHeld;
    is.controlParticles = grids.controlCount();
    if (instances_[i].spec.params.repulsion) is.repulsionParticles = grids.repulsionCount();
    fs.controlParticles += is.controlParticles;
    fs.repulsionParticles += is.repulsionParticles;
  }
  fs.controlledParticles = controlled_.size();
  fs.seededParticles = seeded_;
  fs.removedParticles = removed_;
  fs.fadedParticles = faded_;
  // A frame-start refresh its first substep reused is the simulation's
  // (FrameStats counts it there).
  fs.controlMs = std::max(0.0, controlMs_ - sim.reusedRefreshMs());
}

template <int D>
void Control<D>::reorder(const std::vector<uint32_t>& perm) {
  auto& acc = accScratch_;
  auto& outside = outsideScratch_;
  auto& touched = touchedScratch_;
  acc.resize(perm.size());
  outside.resize(perm.size());
  touched.resize(perm.size());
  inverse_.resize(perm.size());
  for (size_t k = 0; k < perm.size(); ++k) {
    acc[k] = controlAcc_[perm[k]];
    outside[k] = framesOutside_[perm[k]];
    touched[k] = touched_[perm[k]];
    inverse_[perm[k]] = uint32_t(k);
  }
  controlAcc_.swap(acc);
  framesOutside_.swap(outside);
  touched_.swap(touched);
  for (uint32_t& p : controlled_) p = inverse_[p];
  for (State& s : state_)
    for (uint32_t& p : s.liquid) p = inverse_[p];
}

template <int D>
void Control<D>::resize(size_t n) {
  controlAcc_.resize(n, Vec<D>::Zero());
  framesOutside_.resize(n, 0);
  touched_.resize(n, 0);
  // Particles past n are gone: drop them from the lists.
  std::erase_if(controlled_, [n](uint32_t p) { return p >= n; });
  for (State& s : state_) {
    size_t w = 0;
    for (size_t k = 0; k < s.liquid.size(); ++k) {
      if (s.liquid[k] >= n) continue;
      s.liquid[w] = s.liquid[k];
      s.y[w] = s.y[k];
      s.fade[w] = s.fade[k];
      ++w;
    }
    s.liquid.resize(w);
    s.y.resize(w);
    s.fade.resize(w);
  }
}

FC_INSTANTIATE_DIMS(Control)

}  // namespace fc
