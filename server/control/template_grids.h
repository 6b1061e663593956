#pragma once
// Acceleration structures a template gets when it is loaded (paper §3.3, §4):
// per frame, a uniform grid over the control particles (the paper's "local
// bucket" for control particles) and the frame's repulsion layer with its own
// grid (the second local bucket).
//
// The control particles themselves are NOT copied: a TemplateFrameGrids
// refers to the TemplateFrame it was built from, so the Template must outlive
// the grids and must not be modified after build (build() from a shared_ptr
// keeps the template alive). The grids do hold a cell-sorted copy of the
// positions (that is how NeighborhoodSearch scans a cell row).
//
// Orientation convention — read before writing the repulsion force:
// `repulsionNormals()[k]` is the OUTWARD unit normal, −∇ρ/‖∇ρ‖ (it points
// from the liquid towards the repulsion particle). The paper (§3.3) defines
// n_k as the normalised density gradient itself (pointing into the liquid)
// and eq. 5 sums w_r n_k W: the force that pushes liquid back towards the
// template surface is therefore  f_r(x) = −w_r Σ_k normal_k W(‖x − x_k‖, h).
#include "control/template.h"
#include "core/aabb.h"
#include "core/neighborhood_search.h"
#include <cassert>
#include <memory>
#include <vector>

namespace fc {

struct RepulsionOptions {
  // Candidates closer than a·h to any control particle are discarded
  // (paper §3.3: "the distance threshold used is set to a·h, with a = 0.9").
  Real a = Real(0.9);
  // A control particle seeds no candidate when ‖∇ρ_k‖ <= gradientEpsilon ·
  // Σ_j m_j‖∇W(x_k − x_j)‖, i.e. when the neighbour contributions cancel to
  // rounding level (interior lattice particles, isolated particles): its
  // direction would be noise. This is not the paper's "threshold that is hard
  // to find" (which would cut real surface particles): at 1e-3 it only skips
  // gradients that are zero up to float rounding or nearly so.
  Real gradientEpsilon = Real(1e-3);
  // Thinning: a kept candidate closer than thinDistance to an earlier kept
  // candidate (control-particle index order, so the result is deterministic)
  // is dropped. < 0: half the template's particle radius, r/2 (h/8 when the
  // header has none); 0: no thinning (the paper does not thin and reports a
  // denser layer as smoother, so we only merge near-duplicates). At r/2,
  // flat and convex surfaces lose nothing (on a lattice disk neighbouring
  // candidates are >= 0.84r apart, on flat faces 2r); what is merged are the
  // candidates that converge in concave regions (inner corners), so that a
  // corner does not sum the repulsion force of several coincident particles.
  Real thinDistance = Real(-1);
};

struct RepulsionStats {
  size_t interiorSkipped = 0;   // negligible gradient: no candidate
  size_t candidates = 0;        // candidates seeded
  size_t nearControl = 0;       // discarded: within a·h of a control particle
  size_t thinned = 0;           // discarded by thinning
  size_t kept = 0;
};

template <int D>
class TemplateFrameGrids {
 public:
  // Builds both grids and the repulsion layer of `frame` for support radius
  // h. `parallel`: use OpenMP inside the frame (false when the caller already
  // runs frames in parallel). Throws std::invalid_argument on h <= 0,
  // non-finite positions, or mismatched array sizes.
  void build(const TemplateFrame<D>& frame, Real h, const RepulsionOptions& options, bool parallel = true);

  Real supportRadius() const { return h_; }

  // ---- control particles (the template frame's data, not copies) ----
  size_t controlCount() const { return frame_ ? frame_->size() : 0; }
  const std::vector<Vec<D>>& controlPositions() const { return frame_->x; }
  const std::vector<Vec<D>>& controlVelocities() const { return frame_->v; }
  const std::vector<Real>& controlMasses() const { return frame_->mass; }
  const TemplateFrame<D>& frame() const { return *frame_; }
  // Bounding box of the control particles (empty box for an empty frame).
  const AABB<D>& controlBounds() const { return controlBounds_; }

  // f(uint32_t j, const Vec<D>& xj) for every control particle j with
  // ‖xj − p‖ <= r. Requires r <= h (the cell size). j indexes
  // controlPositions()/Velocities()/Masses().
  template <class F>
  void forEachControlNear(const Vec<D>& p, Real r, F&& f) const {
    assert(r <= h_ * Real(1.000001));
    if (controlBuilt_) controlGrid_.forEachStaticNear(p, r, f);
  }

  // The grid itself, for vectorised loops over its cell-sorted storage
  // (null when the frame has no control particle).
  const NeighborhoodSearch<D>* controlGrid() const { return controlBuilt_ ? &controlGrid_ : nullptr; }

  // ---- repulsion layer ----
  size_t repulsionCount() const { return repX_.size(); }
  const std::vector<Vec<D>>& repulsionPositions() const { return repX_; }
  // Outward unit normals −∇ρ/‖∇ρ‖ (see the convention at the top of the file).
  const std::vector<Vec<D>>& repulsionNormals() const { return repN_; }
  // Index of the control particle that seeded each repulsion particle.
  const std::vector<uint32_t>& repulsionSources() const { return repSource_; }
  const AABB<D>& repulsionBounds() const { return repulsionBounds_; }
  const RepulsionStats& stats() const { return stats_; }

  // f(uint32_t k, const Vec<D>& xk) for every repulsion particle k with
  // ‖xk − p‖ <= r, r <= h.
  template <class F>
  void forEachRepulsionNear(const Vec<D>& p, Real r, F&& f) const {
    assert(r <= h_ * Real(1.000001));
    if (repulsionBuilt_) repulsionGrid_.forEachStaticNear(p, r, f);
  }

  // Bytes owned by this object (grids and repulsion arrays; the template's
  // own particle data is not counted). The grid part is computed from
  // NeighborhoodSearch's static-point layout: one uint32 per cell (+1) and,
  // per point, D sorted coordinates, its index and its cell (uint32 each).
  size_t memoryBytes() const;

  // Control density gradient ∇ρ_k = Σ_j m_j ∇W_poly6(x_k − x_j) at control
  // particle k, from the grid (exposed for tests and tools).
  Vec<D> densityGradient(size_t k) const;

 private:
  static size_t gridBytes(const NeighborhoodSearch<D>& g, size_t points, bool built);

  const TemplateFrame<D>* frame_ = nullptr;
  Real h_ = 0;
  AABB<D> controlBounds_, repulsionBounds_;
  NeighborhoodSearch<D> controlGrid_, repulsionGrid_;
  bool controlBuilt_ = false, repulsionBuilt_ = false;
  std::vector<Vec<D>> repX_, repN_;
  std::vector<uint32_t> repSource_;
  RepulsionStats stats_;
};

// Everything a loaded template needs at control time, one entry per frame:
// built for every frame at load, or, for a streamed template, built from
// its frame source when a frame is first asked for and kept in a cache of
// at most `cacheBytes` (the least recently used frames that nobody holds
// are dropped first).
template <int D>
struct TemplateAccel {
  std::vector<TemplateFrameGrids<D>> frames;  // every frame (empty when streamed)
  double buildSeconds = 0;       // wall time of build()
  Real supportRadius = 0;        // h used (the template header's supportRadius)
  RepulsionOptions options;      // with thinDistance resolved to the value used
  const Template<D>* source = nullptr;
  std::shared_ptr<const Template<D>> owner;  // set by the shared_ptr overload

  // Frames are built in parallel (OpenMP over frames when there are at least
  // twice as many frames as threads, otherwise frame by frame with OpenMP
  // inside each frame). Throws std::invalid_argument when the header has no
  // positive supportRadius or a frame is malformed (message names the frame).
  static TemplateAccel build(const Template<D>& tpl, const RepulsionOptions& options = {});
  static TemplateAccel build(std::shared_ptr<const Template<D>> tpl, const RepulsionOptions& options = {});
  // Streamed: `tpl` holds the header (and streamedFrames), `source` the frames.
  static TemplateAccel streamed(std::shared_ptr<const Template<D>> tpl,
                                std::shared_ptr<const TemplateFrameSource<D>> source, size_t cacheBytes,
                                const RepulsionOptions& options = {});

  // What a frame takes per control particle, decoded with its grids: the
  // particle, its place in the control grid, and room for the repulsion
  // layer and the cells (TemplateDatabase streams what would not fit).
  static constexpr size_t kBytesPerParticleFrame =
      2 * sizeof(Vec<D>) + sizeof(Real) + 1 + D * sizeof(Real) + 2 * sizeof(uint32_t) + 16;

  bool isStreamed() const { return stream_ != nullptr; }
  size_t frameCount() const { return stream_ ? stream_->frameCount() : frames.size(); }
  // Frame i's grids, valid while the pointer and this accelerator are held
  // (a streamed frame is read and built here when it is not in the cache: a
  // TemplateError or std::invalid_argument then says why). Thread-safe.
  std::shared_ptr<const TemplateFrameGrids<D>> frame(size_t i) const;
  size_t particleFrames() const;            // Σ control particles over frames
  size_t repulsionParticleFrames() const;   // Σ repulsion particles over the built frames
  double msPerMillionParticleFrames() const;
  size_t memoryBytes() const;               // grids + repulsion layer, all built frames (and their particles, streamed)
  static size_t templateBytes(const Template<D>& tpl);  // the particle data itself

  // A streamed template's cache.
  struct CacheStats {
    size_t cacheBytes = 0;      // the budget
    size_t residentFrames = 0, residentBytes = 0, peakBytes = 0;
    size_t loads = 0, hits = 0;  // frames read and built; requests answered from the cache
    double loadSeconds = 0;      // reading, decoding and building them
  };
  CacheStats cacheStats() const;

 private:
  struct Cache;
  std::shared_ptr<const TemplateFrameSource<D>> stream_;
  std::shared_ptr<Cache> cache_;
};

}  // namespace fc
