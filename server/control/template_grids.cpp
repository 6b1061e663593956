#include "control/template_grids.h"
#include "core/kernels.h"
#include "core/capacity_bytes.h"
#include <omp.h>
#include <chrono>
#include <cmath>
#include <exception>
#include <list>
#include <mutex>
#include <unordered_map>
#include <stdexcept>
#include <string>

namespace fc {

template <int D>
void TemplateFrameGrids<D>::build(const TemplateFrame<D>& frame, Real h, const RepulsionOptions& opt, bool parallel) {
  if (!(h > 0) || !std::isfinite(double(h)))
    throw std::invalid_argument("template support radius h must be positive, got " + std::to_string(double(h)));
  const size_t n = frame.x.size();
  if (frame.mass.size() != n)
    throw std::invalid_argument("frame has " + std::to_string(n) + " positions but " +
                                std::to_string(frame.mass.size()) + " masses");
  if (!frame.v.empty() && frame.v.size() != n)
    throw std::invalid_argument("frame has " + std::to_string(n) + " positions but " +
                                std::to_string(frame.v.size()) + " velocities");
  frame_ = &frame;
  h_ = h;
  controlBounds_ = AABB<D>();
  repulsionBounds_ = AABB<D>();
  controlBuilt_ = repulsionBuilt_ = false;
  repX_.clear();
  repN_.clear();
  repSource_.clear();
  stats_ = {};
  controlGrid_ = NeighborhoodSearch<D>();
  repulsionGrid_ = NeighborhoodSearch<D>();
  if (n == 0) return;  // nothing to grid, no repulsion layer

  for (size_t i = 0; i < n; ++i) {
    if (!frame.x[i].allFinite())
      throw std::invalid_argument("control particle " + std::to_string(i) + " has a non-finite position");
    controlBounds_.extend(frame.x[i]);
  }

  // Local bucket of control particles: cells of size h over the frame's box
  // grown by h (NeighborhoodSearch adds one more spare cell per side).
  const AABB<D> gridBox = controlBounds_.grown(h);
  controlGrid_.setGrid(gridBox, h);
  controlGrid_.setStaticPoints(frame.x);
  controlBuilt_ = true;

  // Repulsion candidates (paper §3.3, Fig. 4). The control density gradient
  // uses Poly6: the paper's control kernel W is Poly6 (Müller et al. 2003 [MCG03]),
  // stated with eq. 3 (coverage α_j) and reused by eqs. 2, 4 and 5 ("the same
  // kernel used for both attraction and velocity forces"); the paper does not
  // name a kernel for the gradient itself, so we stay with the control kernel:
  //   ∇ρ_k = Σ_j m_j ∇W_poly6(x_k − x_j, h).
  // ∇ρ points into the liquid; the candidate is x_k − h ∇ρ_k/‖∇ρ_k‖.
  const Real a2h2 = (opt.a * h) * (opt.a * h);
  std::vector<Vec<D>> candX(n), candN(n);
  std::vector<uint8_t> state(n, 0);  // 0 interior, 1 near control, 2 candidate kept
  const Poly6<D> W(h);
  const Real eps = opt.gradientEpsilon;
  const Real aH = opt.a * h;
#pragma omp parallel if (parallel)
  {
    std::vector<Vec<D>> nb;  // neighbours of x_k, reused for the a·h test
#pragma omp for schedule(dynamic, 256)
    for (size_t k = 0; k < n; ++k) {
      const Vec<D> xk = frame.x[k];
      Vec<D> g = Vec<D>::Zero();
      Real scale = 0;
      nb.clear();
      controlGrid_.forEachStaticNear(xk, h, [&](uint32_t j, const Vec<D>& xj) {
        const Vec<D> gj = frame.mass[j] * W.gradW(xk - xj);
        g += gj;
        scale += gj.norm();
        nb.push_back(xj);
      });
      const Real gn = g.norm();
      if (!(gn > eps * scale) || !(gn > 0)) continue;  // interior or isolated: no direction
      const Vec<D> nk = -g / gn;                       // outward
      const Vec<D> c = xk + h * nk;
      // Within a·h of any control particle? Most candidates (interior ones)
      // are rejected by a neighbour of x_k; otherwise ask the grid.
      bool near = false;
      for (const auto& xj : nb)
        if ((xj - c).squaredNorm() < a2h2) {
          near = true;
          break;
        }
      if (!near)
        controlGrid_.forEachStaticNear(c, aH, [&](uint32_t, const Vec<D>& xj) {
          if ((xj - c).squaredNorm() < a2h2) near = true;
        });
      candX[k] = c;
      candN[k] = nk;
      state[k] = near ? 1 : 2;
    }
  }
  for (size_t k = 0; k < n; ++k) {
    if (state[k] == 0) {
      ++stats_.interiorSkipped;
      continue;
    }
    ++stats_.candidates;
    if (state[k] == 1) {
      ++stats_.nearControl;
      continue;
    }
    repX_.push_back(candX[k]);
    repN_.push_back(candN[k]);
    repSource_.push_back(uint32_t(k));
  }
  candX = {};
  candN = {};

  auto buildRepulsionGrid = [&] {
    repulsionBounds_ = AABB<D>();
    for (const auto& p : repX_) repulsionBounds_.extend(p);
    repulsionGrid_ = NeighborhoodSearch<D>();
    repulsionBuilt_ = !repX_.empty();
    if (repulsionBuilt_) {
      // Every repulsion particle is within h of a control particle, so the
      // control box grown by h contains them; use the same cell layout.
      repulsionGrid_.setGrid(gridBox, h);
      repulsionGrid_.setStaticPoints(repX_);
    }
  };
  buildRepulsionGrid();

  // Thinning (optional, see RepulsionOptions::thinDistance): greedy in
  // control-particle order, keep a candidate unless an earlier kept one is
  // closer than thinDistance.
  const Real thin = std::min(opt.thinDistance, h);
  if (thin > 0 && repX_.size() > 1) {
    const size_t m = repX_.size();
    std::vector<uint8_t> removed(m, 0);
    for (size_t k = 0; k < m; ++k) {
      if (removed[k]) continue;
      repulsionGrid_.forEachStaticNear(repX_[k], thin, [&](uint32_t j, const Vec<D>& xj) {
        if (j > k && (xj - repX_[k]).squaredNorm() < thin * thin) removed[j] = 1;
      });
    }
    size_t w = 0;
    for (size_t k = 0; k < m; ++k) {
      if (removed[k]) continue;
      repX_[w] = repX_[k];
      repN_[w] = repN_[k];
      repSource_[w] = repSource_[k];
      ++w;
    }
    stats_.thinned = m - w;
    if (w != m) {
      repX_.resize(w);
      repN_.resize(w);
      repSource_.resize(w);
      buildRepulsionGrid();
    }
  }
  repX_.shrink_to_fit();
  repN_.shrink_to_fit();
  repSource_.shrink_to_fit();
  stats_.kept = repX_.size();
}

template <int D>
Vec<D> TemplateFrameGrids<D>::densityGradient(size_t k) const {
  const Poly6<D> W(h_);
  const Vec<D> xk = frame_->x[k];
  Vec<D> g = Vec<D>::Zero();
  forEachControlNear(xk, h_, [&](uint32_t j, const Vec<D>& xj) { g += frame_->mass[j] * W.gradW(xk - xj); });
  return g;
}

template <int D>
size_t TemplateFrameGrids<D>::gridBytes(const NeighborhoodSearch<D>& g, size_t points, bool built) {
  if (!built) return 0;
  return (g.cellCount() + 1) * sizeof(uint32_t) + points * (D * sizeof(Real) + 2 * sizeof(uint32_t));
}

template <int D>
size_t TemplateFrameGrids<D>::memoryBytes() const {
  return sizeof(*this) + gridBytes(controlGrid_, controlCount(), controlBuilt_) +
         gridBytes(repulsionGrid_, repX_.size(), repulsionBuilt_) +
         capacityBytes(repX_) + capacityBytes(repN_) + capacityBytes(repSource_);
}

template <int D>
TemplateAccel<D> TemplateAccel<D>::build(const Template<D>& tpl, const RepulsionOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  TemplateAccel<D> acc;
  acc.source = &tpl;
  acc.supportRadius = Real(tpl.header.supportRadius);
  if (!(acc.supportRadius > 0))
    throw std::invalid_argument("template '" + tpl.header.name +
                                "': header supportRadius must be positive to build its repulsion layer");
  acc.options = options;
  if (acc.options.thinDistance < 0)
    acc.options.thinDistance =
        tpl.header.particleRadius > 0 ? Real(0.5 * tpl.header.particleRadius) : acc.supportRadius / Real(8);

  const size_t nf = tpl.frames.size();
  acc.frames.resize(nf);
  const bool overFrames = nf >= size_t(2 * omp_get_max_threads());
  std::vector<std::string> errors(nf);
  bool failed = false;
#pragma omp parallel for schedule(dynamic, 1) if (overFrames) reduction(|| : failed)
  for (size_t f = 0; f < nf; ++f) {
    try {
      acc.frames[f].build(tpl.frames[f], acc.supportRadius, acc.options, !overFrames);
    } catch (const std::exception& e) {
      errors[f] = e.what();
      failed = true;
    }
  }
  if (failed)
    for (size_t f = 0; f < nf; ++f)
      if (!errors[f].empty())
        throw std::invalid_argument("template '" + tpl.header.name + "' frame " + std::to_string(f) + ": " +
                                    errors[f]);
  acc.buildSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return acc;
}

template <int D>
TemplateAccel<D> TemplateAccel<D>::build(std::shared_ptr<const Template<D>> tpl, const RepulsionOptions& options) {
  if (!tpl) throw std::invalid_argument("no template to build acceleration structures for");
  TemplateAccel<D> acc = build(*tpl, options);
  acc.owner = std::move(tpl);
  return acc;
}

// A streamed frame: its particles and the grids built on them.
template <int D>
struct StreamedFrame {
  TemplateFrame<D> data;
  TemplateFrameGrids<D> grids;  // refers to data
  size_t bytes = 0;
};

template <int D>
struct TemplateAccel<D>::Cache {
  std::mutex mutex;
  std::unordered_map<size_t, std::shared_ptr<StreamedFrame<D>>> frames;
  std::list<size_t> recent;  // most recently used first
  CacheStats stats;
};

template <int D>
TemplateAccel<D> TemplateAccel<D>::streamed(std::shared_ptr<const Template<D>> tpl,
                                            std::shared_ptr<const TemplateFrameSource<D>> source, size_t cacheBytes,
                                            const RepulsionOptions& options) {
  if (!tpl || !source) throw std::invalid_argument("no template to stream");
  TemplateAccel<D> acc;
  acc.source = tpl.get();
  acc.owner = std::move(tpl);
  acc.supportRadius = Real(acc.source->header.supportRadius);
  if (!(acc.supportRadius > 0))
    throw std::invalid_argument("template '" + acc.source->header.name +
                                "': header supportRadius must be positive to build its repulsion layer");
  acc.options = options;
  if (acc.options.thinDistance < 0)
    acc.options.thinDistance = acc.source->header.particleRadius > 0 ? Real(0.5 * acc.source->header.particleRadius)
                                                                     : acc.supportRadius / Real(8);
  acc.stream_ = std::move(source);
  acc.cache_ = std::make_shared<Cache>();
  acc.cache_->stats.cacheBytes = cacheBytes;
  return acc;
}

template <int D>
std::shared_ptr<const TemplateFrameGrids<D>> TemplateAccel<D>::frame(size_t i) const {
  // Resident frames live as long as the accelerator: a pointer that owns nothing.
  if (!stream_) return std::shared_ptr<const TemplateFrameGrids<D>>(std::shared_ptr<const void>(), &frames.at(i));
  Cache& c = *cache_;
  const auto found = [&]() -> std::shared_ptr<const TemplateFrameGrids<D>> {
    const auto it = c.frames.find(i);
    if (it == c.frames.end()) return nullptr;
    ++c.stats.hits;
    c.recent.remove(i);
    c.recent.push_front(i);
    return std::shared_ptr<const TemplateFrameGrids<D>>(it->second, &it->second->grids);
  };
  {
    std::lock_guard<std::mutex> lock(c.mutex);
    if (auto hit = found()) return hit;
  }
  // Read and built outside the lock: other frames stay available meanwhile
  // (two threads may build the same frame once each; the first one kept wins).
  const auto t0 = std::chrono::steady_clock::now();
  auto built = std::make_shared<StreamedFrame<D>>();
  built->data = stream_->readFrame(i);
  try {
    built->grids.build(built->data, supportRadius, options, !omp_in_parallel());
  } catch (const std::exception& e) {
    throw std::invalid_argument("template '" + source->header.name + "' frame " + std::to_string(i) + ": " + e.what());
  }
  built->bytes = built->grids.memoryBytes() + capacityBytes(built->data.x) + capacityBytes(built->data.v) +
                 capacityBytes(built->data.mass) + capacityBytes(built->data.phase);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::lock_guard<std::mutex> lock(c.mutex);
  c.stats.loadSeconds += seconds;
  ++c.stats.loads;
  if (auto hit = found()) return hit;
  c.frames.emplace(i, built);
  c.recent.push_front(i);
  c.stats.residentBytes += built->bytes;
  // Over budget: drop the least recently used frames nobody holds (a frame
  // in use stays, so a budget smaller than the frames in use is exceeded).
  for (auto it = c.recent.end(); c.stats.residentBytes > c.stats.cacheBytes && it != c.recent.begin();) {
    --it;
    auto f = c.frames.find(*it);
    if (*it == i || f->second.use_count() > 1) continue;
    c.stats.residentBytes -= f->second->bytes;
    c.frames.erase(f);
    it = c.recent.erase(it);
  }
  c.stats.residentFrames = c.frames.size();
  c.stats.peakBytes = std::max(c.stats.peakBytes, c.stats.residentBytes);
  return std::shared_ptr<const TemplateFrameGrids<D>>(built, &built->grids);
}

template <int D>
typename TemplateAccel<D>::CacheStats TemplateAccel<D>::cacheStats() const {
  if (!cache_) return {};
  std::lock_guard<std::mutex> lock(cache_->mutex);
  CacheStats s = cache_->stats;
  s.residentFrames = cache_->frames.size();
  return s;
}

template <int D>
size_t TemplateAccel<D>::particleFrames() const {
  size_t s = 0;
  if (stream_) {
    for (size_t f = 0; f < stream_->frameCount(); ++f) s += stream_->frameParticles(f);
    return s;
  }
  for (const auto& f : frames) s += f.controlCount();
  return s;
}

template <int D>
size_t TemplateAccel<D>::repulsionParticleFrames() const {
  size_t s = 0;
  for (const auto& f : frames) s += f.repulsionCount();
  if (cache_) {
    std::lock_guard<std::mutex> lock(cache_->mutex);
    for (const auto& [index, f] : cache_->frames) s += f->grids.repulsionCount();
  }
  return s;
}

template <int D>
double TemplateAccel<D>::msPerMillionParticleFrames() const {
  const size_t pf = particleFrames();
  return pf ? buildSeconds * 1e3 / (double(pf) * 1e-6) : 0.0;
}

template <int D>
size_t TemplateAccel<D>::memoryBytes() const {
  size_t s = sizeof(*this);
  for (const auto& f : frames) s += f.memoryBytes();
  return s + cacheStats().residentBytes;
}

template <int D>
size_t TemplateAccel<D>::templateBytes(const Template<D>& tpl) {
  size_t s = sizeof(tpl) + tpl.header.recipe.capacity() + capacityBytes(tpl.frames);
  for (const auto& f : tpl.frames)
    s += capacityBytes(f.x) + capacityBytes(f.v) + capacityBytes(f.mass) + capacityBytes(f.phase);
  return s;
}

FC_INSTANTIATE_DIMS(TemplateFrameGrids)
template struct TemplateAccel<2>;
template struct TemplateAccel<3>;

}  // namespace fc
